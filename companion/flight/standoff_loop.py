"""The flight closes the loop on the measured standoff (issue 26): measurements in, corrections out.

Glue between the telemetry (each logged row's forward rangefinder distance, the camera chain's estimate), the pure
``StandoffController`` and the vehicle (``standoff_shift.fly_moved_scan``). The supervisor calls ``step`` from its
loop; the telemetry recorder calls ``on_row`` for every row and writes the keys it returns into that row:
``standoff_offset_m`` (the scan's total shift out from the plan so far) on every row, ``standoff_correction`` (the
correction's record) on the first row after one.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

from companion.errors import CompanionError
from companion.flight import standoff_control as sc
from companion.flight.standoff_shift import NAV_COMMANDS, fly_moved_scan, shifted_items
from companion.mission import items as mi
from companion.records import StandoffEstimate

log = logging.getLogger(__name__)

STANDOFF_MATCH_M = 0.01  # a waypoint this near the planned standoff is "at the standoff" (the planner puts it there)


@dataclass(frozen=True)
class StandoffOptions:
    """``fly_mission(standoff=...)``: whether the flight corrects its standoff and how closely it holds it.
    ``floor_m`` None: the mission's ``min_distance_m``, else 60 % of the standoff."""

    correct: bool = True
    tolerance_m: float = 0.3
    floor_m: float | None = None
    hold_s: float = 3.0
    recover_s: float = 15.0


@dataclass(frozen=True)
class ScanLegs:
    """Which items a correction moves (``movable``: NAV_WAYPOINTs at the standoff) and which scan leg the vehicle
    flies when it heads for an item (``leg_of``: the item and the waypoint before it are both scan waypoints; a leg
    is named by the seq of the item it flies to)."""

    movable: frozenset[int]
    leg_of: Mapping[int, int]

    @classmethod
    def of(cls, plan, items: Sequence[mi.MissionItem], first_seq: int) -> ScanLegs:
        nav = [it for it in items[first_seq:] if it.command in NAV_COMMANDS]
        movable, leg_of = set(), {}
        prev_kind = None
        for item, wp in zip(nav, plan.waypoints, strict=False):
            at_standoff = abs(wp.out_m - plan.mission.standoff_m) <= STANDOFF_MATCH_M
            if item.command == mi.MAV_CMD_NAV_WAYPOINT and at_standoff and wp.kind in ("scan", "transit"):
                movable.add(item.seq)
            if wp.kind == "scan" and prev_kind == "scan":
                leg_of[item.seq] = item.seq
            prev_kind = wp.kind
        return cls(frozenset(movable), leg_of)


def settings_for(plan, options: StandoffOptions) -> sc.StandoffSettings:
    floor = options.floor_m if options.floor_m is not None else getattr(plan.mission, "min_distance_m", None)
    return sc.StandoffSettings(float(plan.mission.standoff_m), tolerance_m=options.tolerance_m, floor_m=floor,
                               hold_s=options.hold_s, recover_s=options.recover_s).check()


class StandoffLoop:
    """One flight's standoff loop. ``camera``: returns the camera chain's current estimate (``CullChain.standoff``)
    or None; ``clock``: the autopilot's time since boot (None before the first message)."""

    def __init__(self, plan, items: Sequence[mi.MissionItem], first_seq: int, options: StandoffOptions,
                 clock: Callable[[], float | None], camera: Callable[[], StandoffEstimate | None] | None = None):
        self.options = options
        self.frame = plan.frame
        self.first_seq = first_seq
        self.items = list(items)
        self.legs = ScanLegs.of(plan, items, first_seq)
        self.controller = sc.StandoffController(settings_for(plan, options))
        self.clock = clock
        self.camera = camera
        self._camera_t: float | None = None
        self._pending: dict | None = None
        self._said: set[tuple[str, int]] = set()
        self._disagreements_said = 0
        self._height = sc.HeightTracker()
        self.moved = 0  # successful moves of the scan

    def on_row(self, row: dict) -> dict:
        """A telemetry row (pose JSON): its forward range counts on a scan leg facing the wall. Returns the keys
        to add to the row."""
        leg = self.legs.leg_of.get(row.get("mission_item"))
        if leg is not None:
            m = sc.rangefinder_measurement(row.get("t_boot_s"), row.get("range_forward_m"), row.get("yaw_deg"),
                                           row.get("pitch_deg"), self.frame.yaw_facing_wall_deg)
            if m is not None and "rangefinder" not in self.controller.ignored:
                if self._height.follows_height(leg, row.get("alt_amsl_m"), row.get("range_forward_m")):
                    self.controller.ignore_source("rangefinder")
                    log.warning("the forward rangefinder's readings follow the vehicle's height on scan leg %s (%.2f "
                                "m now): it does not see the wall, and is ignored for the rest of the flight; check "
                                "its mounting and orientation parameter (e.g. ArduPilot's RNGFND1_ORIENT)", leg,
                                row.get("range_forward_m"))
                else:
                    self.controller.observe(m, leg)
        extra = {"standoff_offset_m": round(self.controller.offset_m, 3)}
        if self._pending is not None:
            extra["standoff_correction"], self._pending = self._pending, None
        return extra

    def _poll_camera(self, leg: int | None) -> None:
        est = self.camera() if self.camera is not None else None
        if est is None or est.time_s == self._camera_t or leg is None:
            return
        self._camera_t = est.time_s
        self.controller.observe(sc.Measurement(est.time_s, est.distance_m, est.sigma_m, "camera"), leg)

    def _say_once(self, key: str, leg: int, text: str) -> None:
        """Each kind of message once per leg: the first of its kind as a warning, later legs' as info."""
        if (key, leg) in self._said:
            return
        first = not any(k == key for k, _ in self._said)
        self._said.add((key, leg))
        log.log(logging.WARNING if first else logging.INFO, "%s", text)

    async def step(self, vehicle, current_seq: int) -> str | None:
        """Decide and act; returns the problem that ends the flight (the caller pauses and returns to launch)."""
        now = self.clock()
        if now is None:
            return None
        leg = self.legs.leg_of.get(current_seq)
        self._poll_camera(leg)
        d = self.controller.decide(now, leg)
        self._say_disagreement(leg)
        if d.action == sc.MEASURING and d.reason.startswith("the measurements spread"):
            self._say_once("spread", leg, f"standoff not corrected on scan leg {leg}: {d.reason}")
        if d.action == sc.NO_MEASUREMENT:
            self._say_once("unmeasured", leg, f"standoff not measured on scan leg {leg} ({d.reason}): flying the "
                                              f"GNSS position uncorrected")
        elif d.action == sc.CAPPED:
            self._say_once("capped", leg, f"standoff {d.measured.distance_m:.2f} m (plan "
                                          f"{self.controller.s.planned_m:.2f}): not corrected now ({d.reason})")
        elif d.action == sc.RECOVERED:
            log.warning("standoff back above the safety floor: %.2f m", d.measured.distance_m)
        elif d.action == sc.ABORT:
            return f"the standoff was below the safety floor and did not recover: {d.reason}"
        elif d.action in (sc.CORRECT, sc.TOO_CLOSE) and self.options.correct:
            return await self._move(vehicle, d, current_seq, leg)
        elif d.action == sc.TOO_CLOSE:  # not correcting, and below the safety floor: the flight ends
            m, s = d.measured, self.controller.s
            return (f"standoff measured {m.distance_m:.2f} +- {m.sigma_m:.2f} m ({m.source}), below the safety floor "
                    f"of {s.floor:.2f} m (plan {s.planned_m:.2f}): not correcting (--no-standoff-correction), so the "
                    "flight ends")
        elif d.action == sc.CORRECT:
            self._say_once("off", leg, f"standoff measured {d.measured.distance_m:.2f} m (plan "
                                       f"{self.controller.s.planned_m:.2f}): not correcting (--no-standoff-correction)")
        return None

    def _say_disagreement(self, leg: int | None) -> None:
        found = self.controller.disagreements
        if len(found) == self._disagreements_said or leg is None:
            return
        self._disagreements_said = len(found)
        last = found[-1]
        self._say_once("disagree", leg, (
            f"the forward rangefinder reads {last.rangefinder_m:.2f} m and the camera {last.camera_m:.2f} m on scan "
            f"leg {leg}: more than {self.controller.s.spread:.2f} m apart, so the nearer steers; check that the "
            "rangefinder faces the wall (its mounting and orientation parameter, e.g. ArduPilot's RNGFND1_ORIENT: a "
            "sensor that reads the height is not looking at the wall)"))

    async def _move(self, vehicle, d: sc.StandoffDecision, current_seq: int, leg: int) -> str | None:
        line = sc.correction_line(d, self.controller.s.planned_m)
        log.warning("%s", line)
        moved = shifted_items(self.items, self.legs.movable, current_seq, self.frame.out_enu, d.shift_out_m)
        try:
            await fly_moved_scan(vehicle, moved, current_seq, self.first_seq)
        except CompanionError as exc:
            return f"moving the scan {d.shift_out_m:+.2f} m out failed: {exc.problem}"
        self.items = moved
        self.moved += 1
        now = self.clock()
        correction = self.controller.applied(d, now if now is not None else d.measured.time_s, leg)
        self._pending = {**correction.as_json(), "line": line}
        return None

    def summary(self) -> sc.StandoffSummary:
        return self.controller.summary()

"""Is the scan at its planned distance from the wall? Decisions from measured standoffs (issue 26, "measure the wall").

The autopilot flies its GNSS estimate; a non-RTK receiver is off by a slowly varying bias of 1-2 m, so a scan
planned at 4 m can truly fly at 2.5 m while every log says 4. A forward rangefinder (DISTANCE_SENSOR, orientation
0) and the camera chain (``CullChain.standoff``) measure the true distance; this module decides what to do with
those measurements. It is pure (no I/O, no clock): the flight feeds it measurements stamped with the autopilot's
time and asks for a decision; ``standoff_loop.py`` acts on it.

Why the rules look like this:
  * only scan legs are judged (the caller passes a leg id, None elsewhere): take-off, transit and landing are not at
    the standoff, and the rangefinder misses the wall when the vehicle does not face it;
  * a correction needs ``hold_s`` of consistent measurement (every sample off on the same side, the median beyond
    the tolerance): one noisy reading, a passing tree or a window must not move the path; within the tolerance
    nothing is ever done, so a vehicle without bias flies exactly the plan;
  * below the safety floor the flight does not wait for the hold: it backs off at once and ends unless the
    measurement recovers within ``recover_s``;
  * no measurement is a decision of its own (``NO_MEASUREMENT``), never "on plan";
  * corrections are capped: one per leg, ``min_interval_s`` apart, at most ``max_correction_m`` each, and never
    bringing the expected true standoff below the floor;
  * a sensor can be wrong, and real ArduCopter SITL showed how: its simulated rangefinder, configured facing
    forward, reported the height above the ground, and the flight moved the scan 4 m towards the wall. So readings
    that spread by more than ``spread_m`` within the hold (a wall flown along stays at one distance) move nothing;
    when the rangefinder and the camera disagree by more than ``spread_m`` the nearer steers (it can only hold or
    back off); and without the camera confirming, the scan never moves in further than keeps the GNSS path
    ``floor + tolerance`` from the wall, so a wrong reading cannot bring the vehicle below the floor.
"""

from __future__ import annotations

import math
import statistics
from collections import deque
from dataclasses import dataclass, field
from enum import StrEnum

from companion.errors import CompanionError

RANGEFINDER_SIGMA_M = 0.03  # a laser rangefinder's noise (the simulator's: 2 cm; covariance 4 cm^2)
FACING_LIMIT_DEG = 15.0  # a rangefinder reading counts only when the vehicle faces the wall within this
DEFAULT_FLOOR_FRACTION = 0.6  # safety floor: 60 % of the planned standoff unless the mission sets min_distance_m


class StandoffAction(StrEnum):
    """What the controller decided (``StandoffDecision.action``). An enum so that the flight loop's branches compare
    members, not typed-out text; a StrEnum so that logs and messages print the same words."""

    ON_PLAN = "on plan"
    CORRECT = "correct"
    TOO_CLOSE = "too close"
    NO_MEASUREMENT = "no measurement"
    MEASURING = "measuring"  # measured, not yet for long enough (or not consistently) to act
    CAPPED = "capped"  # off the plan, but the correction cap says not now
    NOT_JUDGED = "not judged"  # not on a scan leg
    SETTLING = "settling"  # right after a correction: the vehicle is moving to the new path
    BACKING_OFF = "backing off"  # too close, moved out, waiting for the measurement to recover
    RECOVERED = "recovered"
    ABORT = "abort"  # too close and not recovered in time: the flight ends


# the module's names for the actions, as its callers and tests import them
ON_PLAN = StandoffAction.ON_PLAN
CORRECT = StandoffAction.CORRECT
TOO_CLOSE = StandoffAction.TOO_CLOSE
NO_MEASUREMENT = StandoffAction.NO_MEASUREMENT
MEASURING = StandoffAction.MEASURING
CAPPED = StandoffAction.CAPPED
NOT_JUDGED = StandoffAction.NOT_JUDGED
SETTLING = StandoffAction.SETTLING
BACKING_OFF = StandoffAction.BACKING_OFF
RECOVERED = StandoffAction.RECOVERED
ABORT = StandoffAction.ABORT


@dataclass(frozen=True)
class StandoffSettings:
    """The plan's standoff and how closely the flight holds it. ``floor_m`` None: 60 % of the standoff;
    ``max_correction_m`` None: the standoff itself (a bigger error is not a GNSS bias)."""

    planned_m: float
    tolerance_m: float = 0.3
    floor_m: float | None = None
    hold_s: float = 3.0
    settle_s: float = 2.0
    min_interval_s: float = 5.0
    max_correction_m: float | None = None
    recover_s: float = 15.0
    floor_hold_s: float = 0.5
    fresh_s: float = 1.0  # a rangefinder reading is current this long
    # the camera's estimate comes from the frame pairs of its last 5 s (keyframes/standoff.py) and arrives as late
    # as the chain runs behind the camera: current for longer, and only counted once its window is past a move
    camera_fresh_s: float = 10.0
    camera_window_s: float = 5.0
    spread_m: float | None = None  # readings further apart than this are not one wall distance (None: 2 x tolerance)

    @property
    def floor(self) -> float:
        return self.floor_m if self.floor_m is not None else DEFAULT_FLOOR_FRACTION * self.planned_m

    @property
    def max_correction(self) -> float:
        return self.max_correction_m if self.max_correction_m is not None else self.planned_m

    @property
    def spread(self) -> float:
        return self.spread_m if self.spread_m is not None else 2.0 * self.tolerance_m

    @property
    def max_unconfirmed_in(self) -> float:
        """How far in the scan may move on a measurement the camera does not confirm: the GNSS path stays
        ``floor + tolerance`` from the wall, so a wrong reading cannot take the vehicle below the floor."""
        return max(0.0, self.planned_m - self.floor - self.tolerance_m)

    def check(self) -> StandoffSettings:
        """Refuse settings no flight can hold; returns itself."""
        if not self.tolerance_m > 0:
            raise CompanionError(f"the standoff tolerance must be positive, got {self.tolerance_m} m",
                                 "give --standoff-tolerance in metres, e.g. 0.3")
        if not 0 < self.floor < self.planned_m - self.tolerance_m:
            raise CompanionError(
                f"the standoff floor {self.floor:g} m must be above 0 and below the planned standoff minus the "
                f"tolerance ({self.planned_m:g} - {self.tolerance_m:g} m)",
                "give --standoff-floor (or the mission's min_distance_m) below the standoff, e.g. 60 % of it")
        for name in ("hold_s", "recover_s", "fresh_s"):
            if not getattr(self, name) > 0:
                raise CompanionError(f"standoff {name} must be positive", f"give {name} in seconds")
        return self


@dataclass(frozen=True)
class Measurement:
    """A measured camera-to-wall distance (horizontal, along the wall's normal) at autopilot time ``time_s``."""

    time_s: float
    distance_m: float
    sigma_m: float
    source: str  # 'rangefinder', 'camera', or both joined by '+' when fused


@dataclass(frozen=True)
class StandoffDecision:
    action: StandoffAction
    measured: Measurement | None = None
    shift_out_m: float = 0.0  # CORRECT / TOO_CLOSE: move the remaining scan this far out (negative: in)
    reason: str = ""


@dataclass(frozen=True)
class StandoffCorrection:
    """One move of the remaining scan across the wall, for the log, the result and the summary."""

    time_s: float  # autopilot time of the decision
    leg: int
    kind: str  # 'correct' or 'back off'
    measured_m: float
    sigma_m: float
    source: str
    planned_m: float
    shift_out_m: float
    offset_out_m: float  # the scan's total shift out from the plan after this one

    def as_json(self) -> dict:
        return {k: (round(v, 3) if isinstance(v, float) else v) for k, v in self.__dict__.items()}


@dataclass(frozen=True)
class LegStandoff:
    leg: int
    median_m: float
    samples: int


@dataclass(frozen=True)
class StandoffSummary:
    """What the flight measured: the standoff per scan leg (median), legs without a measurement, the corrections."""

    planned_m: float
    tolerance_m: float
    floor_m: float
    sources: tuple[str, ...]
    legs: tuple[LegStandoff, ...]
    unmeasured_legs: tuple[int, ...]
    corrections: tuple[StandoffCorrection, ...]
    offset_out_m: float

    @property
    def measured(self) -> bool:
        return bool(self.legs)

    def as_json(self) -> dict:
        return {"planned_m": self.planned_m, "tolerance_m": self.tolerance_m, "floor_m": round(self.floor_m, 3),
                "sources": list(self.sources), "offset_out_m": round(self.offset_out_m, 3),
                "legs": [{"leg": g.leg, "median_m": round(g.median_m, 3), "samples": g.samples} for g in self.legs],
                "unmeasured_legs": list(self.unmeasured_legs),
                "corrections": [c.as_json() for c in self.corrections]}

    def line(self) -> str:
        """One line for a person: the measured standoff per leg and the corrections."""
        if not self.legs:
            return (f"standoff NOT measured (plan {self.planned_m:.2f} m): no rangefinder reading facing the wall "
                    "and no camera estimate on the scan legs; the distance flown is GNSS's")
        medians = [g.median_m for g in self.legs]
        moves = ", ".join(f"{c.shift_out_m:+.2f} m" + (" (backed off: below the floor)" if c.kind == "back off" else "")
                          for c in self.corrections) or "none"
        per_leg = ", ".join(f"{g.leg}: {g.median_m:.2f}" for g in self.legs)
        return (f"standoff measured on {len(self.legs)} scan legs by {'+'.join(self.sources)}: median "
                f"{statistics.median(medians):.2f} m (plan {self.planned_m:.2f} m; per leg, named by the item it "
                f"flies to: {per_leg}); corrections: {moves}"
                + (f"; {len(self.unmeasured_legs)} legs unmeasured" if self.unmeasured_legs else ""))


def correction_line(decision: StandoffDecision, planned_m: float) -> str:
    """The status line of one correction: ``standoff measured 2.52 +- 0.03 m (plan 4.00): moving the scan 1.48 m
    out``."""
    m = decision.measured
    direction = "out" if decision.shift_out_m >= 0 else "in"
    head = "TOO CLOSE: " if decision.action == TOO_CLOSE else ""
    return (f"{head}standoff measured {m.distance_m:.2f} +- {m.sigma_m:.2f} m (plan {planned_m:.2f}, {m.source}): "
            f"moving the scan {abs(decision.shift_out_m):.2f} m {direction}")


def fuse(samples: list[Measurement], time_s: float) -> Measurement | None:
    """Inverse-variance mean of the sources' latest samples (each source once)."""
    if not samples:
        return None
    weights = [1.0 / max(s.sigma_m, 1e-3) ** 2 for s in samples]
    total = sum(weights)
    distance = sum(w * s.distance_m for w, s in zip(weights, samples, strict=True)) / total
    return Measurement(time_s, distance, 1.0 / math.sqrt(total), "+".join(sorted(s.source for s in samples)))


@dataclass(frozen=True)
class Disagreement:
    """The rangefinder and the camera, both current, further apart than ``StandoffSettings.spread``."""

    time_s: float
    rangefinder_m: float
    camera_m: float


@dataclass
class _LegLog:
    """What the flight's summary reports per scan leg. Each sample is kept once, with its source, so that a source
    found not to see the wall (``StandoffController.ignore_source``) can be forgotten; the per-leg distances are
    derived from it (:meth:`distances_by_leg`) rather than stored a second time and kept in step."""

    by_source: dict[int, list[tuple[str, float]]] = field(default_factory=dict)
    seen: set[int] = field(default_factory=set)
    sources: set[str] = field(default_factory=set)

    def distances_by_leg(self) -> dict[int, list[float]]:
        """Leg -> its distances in the order measured; a leg whose every sample was forgotten is left out (it
        counts as unmeasured)."""
        return {leg: [d for _, d in kept] for leg, kept in self.by_source.items() if kept}


class StandoffController:
    """Feed ``observe(measurement, leg)`` (judged samples only), ask ``decide(now_s, leg)``; after acting on a
    CORRECT or TOO_CLOSE decision call ``applied``. ``offset_m``: the total shift out applied so far."""

    def __init__(self, settings: StandoffSettings):
        self.s = settings.check()
        self.offset_m = 0.0
        self.corrections: list[StandoffCorrection] = []
        self._latest: dict[str, Measurement] = {}
        self._history: deque[Measurement] = deque()
        self._settle_until = -math.inf
        self._last_correction_s = -math.inf
        self._corrected_legs: set[int] = set()
        self._recover_deadline: float | None = None
        self._log = _LegLog()
        self._newest_seen_s: float | None = None  # the newest measurement's time, whether it counted or not
        # the leg being flown when the scan was moved: the vehicle reaches the moved path only at that leg's end
        # (it flies a straight line to the moved waypoint), so what is measured on it is neither path
        self._moving_leg: int | None = None
        self.disagreements: list[Disagreement] = []
        self.ignored: set[str] = set()  # sources found not to see the wall (ignore_source)

    def observe(self, m: Measurement, leg: int) -> None:
        """One measurement taken on scan leg ``leg`` (facing the wall)."""
        if m.source in self.ignored:
            return
        self._log.sources.add(m.source)
        self._log.by_source.setdefault(leg, []).append((m.source, m.distance_m))
        self._newest_seen_s = max(m.time_s, self._newest_seen_s if self._newest_seen_s is not None else m.time_s)
        settled = self._settle_until + (self.s.camera_window_s if self._is_camera(m.source) else 0.0)
        if m.time_s < settled:
            return
        self._latest[m.source] = m
        ranged = self._latest.get("rangefinder")
        if self._is_camera(m.source) and ranged is not None and ranged.time_s >= m.time_s - self.s.fresh_s:
            return  # the rangefinder is current: the camera joins its next readings (fused), not the history alone
        fresh = [s for s in self._latest.values() if abs(m.time_s - s.time_s) <= self._fresh_limit(s.source)]
        self._history.append(self._combine(fresh, m.time_s))
        keep_from = m.time_s - self.s.hold_s - self.s.camera_fresh_s
        while self._history and self._history[0].time_s < keep_from:
            self._history.popleft()

    def ignore_source(self, source: str) -> None:
        """Stop counting ``source`` (a sensor found not to see the wall): its readings so far are forgotten, in
        the decisions and in the flight's summary."""
        self.ignored.add(source)
        self._log.sources.discard(source)
        for leg, kept in list(self._log.by_source.items()):
            self._log.by_source[leg] = [(src, d) for src, d in kept if src != source]
        self._latest.pop(source, None)
        self._history = deque(h for h in self._history if source not in h.source)

    def _combine(self, fresh: list[Measurement], time_s: float) -> Measurement:
        """The sources fused, unless the rangefinder and the camera disagree: then the nearer alone (recorded in
        ``disagreements``), which can hold the path or back it off but never pull it in on the farther reading."""
        ranged = [f for f in fresh if not self._is_camera(f.source)]
        seen = [f for f in fresh if self._is_camera(f.source)]
        if ranged and seen and abs(ranged[0].distance_m - seen[0].distance_m) > self.s.spread:
            self.disagreements.append(Disagreement(time_s, ranged[0].distance_m, seen[0].distance_m))
            nearer = min(ranged[0], seen[0], key=lambda f: f.distance_m)
            return Measurement(time_s, nearer.distance_m, nearer.sigma_m, nearer.source)
        return fuse(fresh, time_s)

    def _camera_confirms(self, distance_m: float, ref_s: float) -> bool:
        cam = next((f for f in self._latest.values() if self._is_camera(f.source)), None)
        return (cam is not None and ref_s - cam.time_s <= self.s.camera_fresh_s
                and abs(cam.distance_m - distance_m) <= self.s.spread)

    @staticmethod
    def _is_camera(source: str) -> bool:
        return "rangefinder" not in source

    def _fresh_limit(self, source: str) -> float:
        return self.s.camera_fresh_s if self._is_camera(source) else self.s.fresh_s

    def decide(self, now_s: float, leg: int | None) -> StandoffDecision:
        if self._recover_deadline is not None:
            return self._recovering(now_s)
        if leg is None:
            self._history.clear()
            return StandoffDecision(NOT_JUDGED)
        self._log.seen.add(leg)
        if self._moving_leg is not None:
            if leg == self._moving_leg:
                return StandoffDecision(SETTLING)
            self._arrived(now_s)
        if now_s < self._settle_until:
            return StandoffDecision(SETTLING)
        newest = max(self._history, key=lambda h: h.time_s, default=None)
        if newest is None:
            return StandoffDecision(NO_MEASUREMENT, reason="no rangefinder reading facing the wall and no camera "
                                                           "estimate in the last seconds")
        if now_s - newest.time_s > self._fresh_limit(newest.source):
            # measured, but too long ago to steer by: on a loaded companion the camera chain can run a minute behind
            # the camera; say so, or a pilot reads "not measured" on a wall the chain is measuring
            return StandoffDecision(NO_MEASUREMENT, reason=f"the newest measurement ({newest.source}, "
                                                           f"{newest.distance_m:.2f} m) is {now_s - newest.time_s:.0f} "
                                                           "s old: the camera chain is running behind the camera")
        ref = newest.time_s  # windows end at the newest measurement (the camera's arrive late)
        recent = sorted((h for h in self._history if h.time_s >= ref - self.s.hold_s), key=lambda h: h.time_s)
        too_close = self._too_close(ref, recent)
        if too_close is not None:
            return too_close
        return self._judge(ref, now_s, recent, leg)

    def _too_close(self, ref_s: float, recent: list[Measurement]) -> StandoffDecision | None:
        last = [h for h in recent if h.time_s >= ref_s - self.s.floor_hold_s]
        if not last or recent[0].time_s > ref_s - self.s.floor_hold_s:
            return None  # not yet measured for floor_hold_s
        if not all(h.distance_m < self.s.floor for h in last):
            return None
        median = statistics.median(h.distance_m for h in last)
        shift = min(self.s.planned_m - median, self.s.max_correction)
        return StandoffDecision(TOO_CLOSE, self._summary(last, ref_s), shift,
                                f"below the safety floor of {self.s.floor:.2f} m")

    def _judge(self, ref_s: float, now_s: float, recent: list[Measurement], leg: int) -> StandoffDecision:
        measured = self._summary(recent, ref_s)
        errors = [self.s.planned_m - h.distance_m for h in recent]
        error = statistics.median(errors)
        if abs(error) <= self.s.tolerance_m:
            return StandoffDecision(ON_PLAN, measured)
        if recent[0].time_s > ref_s - self.s.hold_s + min(0.25, self.s.hold_s / 4):
            return StandoffDecision(MEASURING, measured, reason=f"off the plan for less than {self.s.hold_s:g} s")
        half = self.s.tolerance_m / 2
        if not (all(e > half for e in errors) or all(e < -half for e in errors)):
            return StandoffDecision(MEASURING, measured, reason="the measurements disagree")
        spread = max(h.distance_m for h in recent) - min(h.distance_m for h in recent)
        if spread > self.s.spread:
            return StandoffDecision(MEASURING, measured, reason=(
                f"the measurements spread over {spread:.2f} m in {self.s.hold_s:g} s, and a wall flown along stays at "
                "one distance (relief, or a sensor that does not see the wall)"))
        if leg in self._corrected_legs:
            return StandoffDecision(CAPPED, measured, reason="one correction per scan leg")
        if now_s - self._last_correction_s < self.s.min_interval_s:
            return StandoffDecision(CAPPED, measured, reason=f"corrections at least {self.s.min_interval_s:g} s apart")
        cap = self.s.max_correction
        shift = max(-cap, min(cap, error))
        shift = max(-cap - self.offset_m, min(cap - self.offset_m, shift))  # the total move is capped too
        shift = max(shift, self.s.floor + self.s.tolerance_m - measured.distance_m)  # never in past the floor
        if shift < 0 and not self._camera_confirms(measured.distance_m, ref_s):
            shift = max(shift, -self.s.max_unconfirmed_in - self.offset_m)
            if abs(shift) <= self.s.tolerance_m / 2:
                return StandoffDecision(CAPPED, measured, reason=(
                    f"the scan is already moved {self.offset_m:+.2f} m; further in needs the camera to confirm the "
                    f"{measured.source} (at most {self.s.max_unconfirmed_in:.2f} m in without it)"))
        if abs(shift) <= self.s.tolerance_m / 2:
            return StandoffDecision(CAPPED, measured, reason=f"the scan is already moved {self.offset_m:+.2f} m, "
                                                             f"the most it may be ({cap:g} m)")
        return StandoffDecision(CORRECT, measured, shift)

    @staticmethod
    def _summary(samples: list[Measurement], now_s: float) -> Measurement:
        """The median distance of ``samples`` with the sigma of one of them (the median of several is no worse)."""
        median = statistics.median(h.distance_m for h in samples)
        return Measurement(now_s, median, min(h.sigma_m for h in samples), samples[-1].source)

    def _recovering(self, now_s: float) -> StandoffDecision:
        since = [h for h in self._history if h.time_s >= self._settle_until]
        newest = max(since, key=lambda h: h.time_s, default=None)
        recent = [h for h in since if newest is not None and h.time_s >= newest.time_s - self.s.floor_hold_s]
        if newest is not None and all(h.distance_m >= self.s.floor for h in recent):
            self._recover_deadline = None  # measured after the move (however late it arrived): back above the floor
            return StandoffDecision(RECOVERED, self._summary(recent, newest.time_s))
        if now_s > self._recover_deadline:
            self._recover_deadline = None
            last = self._summary(recent, now_s) if recent else None
            said = f"still {last.distance_m:.2f} m" if last else "no measurement since"
            if last is None and self._newest_seen_s is not None:
                said += f"; the newest is {now_s - self._newest_seen_s:.0f} s old (the camera chain running behind?)"
            return StandoffDecision(ABORT, last, reason=f"not back above the safety floor of {self.s.floor:.2f} m "
                                                        f"{self.s.recover_s:g} s after backing off ({said})")
        return StandoffDecision(BACKING_OFF)

    def _arrived(self, now_s: float) -> None:
        """The vehicle left the leg it was on when the scan moved: it is on the moved path now. Only what is
        measured from ``settle_s`` on counts (a camera estimate once its whole window is past this)."""
        self._moving_leg = None
        self._history.clear()
        self._latest.clear()
        self._settle_until = now_s + self.s.settle_s

    def applied(self, decision: StandoffDecision, now_s: float, leg: int) -> StandoffCorrection:
        """The vehicle flies the moved scan now: record it, forget the measurements of the old path. Nothing is
        judged again until it reaches the moved path (the end of this leg); backing off from too close, the
        measurements on the way out still tell whether it is back above the floor."""
        self.offset_m += decision.shift_out_m
        m = decision.measured
        correction = StandoffCorrection(now_s, leg, "back off" if decision.action == TOO_CLOSE else "correct",
                                        m.distance_m, m.sigma_m, m.source, self.s.planned_m, decision.shift_out_m,
                                        self.offset_m)
        self.corrections.append(correction)
        self._history.clear()
        self._latest.clear()
        self._settle_until = now_s + self.s.settle_s if decision.action == TOO_CLOSE else math.inf
        self._moving_leg = leg
        self._last_correction_s = now_s
        self._corrected_legs.add(leg)
        if decision.action == TOO_CLOSE:
            late = self.s.camera_window_s if self._is_camera(m.source) else 0.0  # the camera sees the move later
            self._recover_deadline = now_s + self.s.settle_s + self.s.recover_s + late
        return correction

    def summary(self) -> StandoffSummary:
        distances = self._log.distances_by_leg()
        legs = tuple(LegStandoff(leg, statistics.median(v), len(v)) for leg, v in sorted(distances.items()))
        unmeasured = tuple(sorted(self._log.seen - set(distances)))
        return StandoffSummary(self.s.planned_m, self.s.tolerance_m, self.s.floor, tuple(sorted(self._log.sources)),
                               legs, unmeasured, tuple(self.corrections), self.offset_m)


@dataclass
class HeightTracker:
    """Does the "forward" rangefinder read the height instead of the wall? On a scan leg that climbs or descends, a
    sensor that sees the wall reads about the same distance all along; one that sees the ground changes with the
    altitude. Real ArduCopter SITL's simulated rangefinder, configured facing forward (RNGFND1_ORIENT 0), measured
    along its downward beam and reported the height: the flight took it for the wall. ``follows_height`` once the
    vehicle has moved ``min_climb_m`` vertically on one leg and the range moved with it (within ``share``)."""

    min_climb_m: float = 1.5
    share: float = 0.3
    _start: dict[int, tuple[float, float]] = field(default_factory=dict)  # leg -> (altitude, range) first seen

    def follows_height(self, leg: int, altitude_m: float | None, range_m: float | None) -> bool:
        if altitude_m is None or range_m is None:
            return False
        alt0, range0 = self._start.setdefault(leg, (altitude_m, range_m))
        climb = altitude_m - alt0
        if abs(climb) < self.min_climb_m:
            return False
        return abs((range_m - range0) - climb) <= self.share * abs(climb)


def rangefinder_measurement(time_s: float | None, range_m: float | None, yaw_deg: float | None,
                            pitch_deg: float | None, facing_deg: float,
                            limit_deg: float = FACING_LIMIT_DEG) -> Measurement | None:
    """A forward rangefinder reading as the horizontal distance to the wall, or None: no reading, or the vehicle
    not facing the wall within ``limit_deg`` (the ray then meets the wall obliquely, or misses it)."""
    if time_s is None or range_m is None or yaw_deg is None:
        return None
    off = (yaw_deg - facing_deg + 180.0) % 360.0 - 180.0
    if abs(off) > limit_deg:
        return None
    tilt = math.radians(pitch_deg or 0.0)
    return Measurement(time_s, range_m * math.cos(math.radians(off)) * math.cos(tilt), RANGEFINDER_SIGMA_M,
                       "rangefinder")

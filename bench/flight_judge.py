"""Judge a flown scan from the companion's telemetry log: the figures issue 12 judges real firmware by.

Reads a ``companion fly ... --telemetry-log FILE`` log (MAVLink telemetry: GLOBAL_POSITION_INT position and
velocity, ATTITUDE yaw, mission progress, armed / in-air) and the mission file, plans the mission again and prints
per scan leg:

* heading: the largest difference between the vehicle's yaw and the wall-facing heading, over the whole leg
  except its first and last 2 % (where the vehicle turns onto the leg);
* speed: the median velocity along the leg over its middle 60 % (the vehicle accelerates and brakes at the
  ends), against the planned speed of that leg;
* track speed (printed, not judged): the rate of the position along the leg over the same middle (least-squares
  slope against the autopilot's time since boot). On real PX4 SIH the reported vertical velocity carried a slowly
  varying bias of up to 0.25 m/s against the vehicle's own altitude track, so the two can disagree there;
* standoff: the largest |horizontal distance to the wall plane - planned standoff| over the same samples as the
  heading;
* end short (printed, not judged): the planned end of the leg minus the furthest point reached on the same pass
  (negative: beyond it). PX4 accepts a waypoint within NAV_MC_ALT_RAD vertically and turns there. The logged
  altitude can sit a constant offset from the one the autopilot navigated by (PX4 SIH: up to 0.9 m), which makes
  down strips look short by that much and up strips long; the summary line takes the mean of the down and the up
  legs before the last (the offset cancels) and corrects the last leg with the offset that pair gives.

A sample belongs to a leg when its projection on the leg falls inside it, it is within ``--max-cross`` metres of
the leg measured in the wall's plane (along / up) and within ``--max-out`` metres (default 2) of the standoff
distance: generous, so a vehicle that drifts off the standoff is measured, not dropped, while the take-off climb or
the transit far out from the wall (which can pass the same along / up position) is not taken for a scan leg.
It also prints the mission items reached (the highest mission progress seen / the total) and whether the log
ends landed and disarmed.

Exit status: 0 when every judged figure is within its limit (heading 3 deg, speed 15 %, standoff 0.3 m, all items,
landed, disarmed), 1 otherwise. Works on any autopilot's log: nothing in it depends on the firmware.

    python bench/flight_judge.py missions/demo-facade.yaml /tmp/demo-telemetry.jsonl
"""

from __future__ import annotations

import argparse
import math
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from companion.flight import read_telemetry_log  # noqa: E402
from companion.mission import load_mission, plan_scan  # noqa: E402

MAX_YAW_ERROR_DEG = 3.0
MAX_SPEED_ERROR = 0.15
MAX_STANDOFF_ERROR_M = 0.3


@dataclass(frozen=True)
class LegFigures:
    """What one scan leg looked like in the telemetry (NaN where the leg has no samples)."""

    leg: int
    vertical: bool
    length_m: float
    planned_speed_m_s: float
    median_speed_m_s: float
    max_yaw_error_deg: float
    max_standoff_error_m: float
    samples: int  # samples on the leg (heading, standoff)
    core_samples: int  # of which in its middle (speed)
    track_speed_m_s: float = math.nan  # rate of the position along the leg over its middle (not judged)
    end_short_m: float = math.nan  # planned end minus the furthest point reached on the pass (not judged)
    descending: bool = False

    @property
    def speed_error(self) -> float:
        return abs(self.median_speed_m_s - self.planned_speed_m_s) / self.planned_speed_m_s

    @property
    def passed(self) -> bool:
        return (self.core_samples > 0 and self.max_yaw_error_deg <= MAX_YAW_ERROR_DEG
                and self.speed_error <= MAX_SPEED_ERROR and self.max_standoff_error_m <= MAX_STANDOFF_ERROR_M)


@dataclass(frozen=True)
class FlightFigures:
    legs: list[LegFigures]
    items_reached: int  # highest mission progress seen (mavsdk's "current"; = total once finished)
    items_total: int
    landed: bool | None  # the log's last in-air state is False
    disarmed: bool | None  # the log's last armed state is False

    @property
    def passed(self) -> bool:
        return (bool(self.legs) and all(leg.passed for leg in self.legs) and self.items_total > 0
                and self.items_reached >= self.items_total and bool(self.landed) and bool(self.disarmed))


def _wrap_deg(deg: np.ndarray) -> np.ndarray:
    return (deg + 180.0) % 360.0 - 180.0


def _usable(row: dict) -> bool:
    keys = ("lat", "lon", "alt_amsl_m", "yaw_deg", "vn_m_s", "ve_m_s", "vd_m_s")
    return all(row.get(k) is not None for k in keys) and bool(row.get("in_air"))


def _forward_passes(run: np.ndarray, s: np.ndarray, turn_m: float) -> list[np.ndarray]:
    """Split a run of consecutive samples where the vehicle turns back along the leg, and keep the pieces flown in
    the leg's direction. A turn is a move of more than ``turn_m`` against the current direction from the last
    extreme (a zigzag filter), so position noise and a settle hold at the end do not split the pass."""
    values = s[run]
    turns = [0]
    direction = 0  # +1 forward along the leg, -1 back, 0 not yet known (within turn_m of the start)
    extreme = 0  # index (into run) of the furthest point in the current direction
    for k in range(1, values.size):
        if direction == 0:
            if abs(values[k] - values[0]) > turn_m:  # the furthest point so far: all before were within turn_m
                direction, extreme = (1 if values[k] > values[0] else -1), k
        elif direction * (values[k] - values[extreme]) >= 0:
            extreme = k
        elif abs(values[k] - values[extreme]) > turn_m:  # moved back from the extreme: a turn
            turns.append(extreme)
            direction, extreme = -direction, k
    turns.append(values.size - 1)
    return [run[a:b + 1] for a, b in zip(turns[:-1], turns[1:], strict=True) if values[b] > values[a]]


def _first_pass(mask: np.ndarray, s: np.ndarray, length: float, turn_m: float = 0.5) -> np.ndarray:
    """Only the first pass in the leg's direction that covers at least half the leg: the scan. A later pass over the
    same stretch is something else: real ArduCopter climbed back up the last strip to the transit altitude after
    scanning it, leaving the leg in between (a gap in the samples); real PX4 turned back about 1 m before the
    strip's end (its altitude acceptance) and climbed back up the same strip with no gap, so a run of consecutive
    samples is also split where the vehicle turns back along the leg."""
    idx = np.flatnonzero(mask)
    if idx.size == 0:
        return mask
    runs = np.split(idx, np.flatnonzero(np.diff(idx) > 1) + 1)
    passes = [p for run in runs for p in _forward_passes(run, s, turn_m)]
    chosen = next((p for p in passes if np.ptp(s[p]) >= 0.5 * length), passes[0] if passes else runs[0])
    out = np.zeros_like(mask)
    out[chosen] = True
    return out


def leg_figures(plan, rows: list[dict], max_cross_m: float = 1.0, max_out_m: float = 2.0, core: float = 0.6,
                trim: float = 0.02) -> list[LegFigures]:
    """One ``LegFigures`` per scan leg of ``plan`` from telemetry ``rows`` (``read_telemetry_log``)."""
    frame = plan.frame
    wall_yaw = frame.yaw_facing_wall_deg
    standoff = plan.mission.standoff_m
    flying = [r for r in rows if _usable(r)]
    if flying:
        along, out, up = frame.geodetic_to_facade(np.array([r["lat"] for r in flying]),
                                                  np.array([r["lon"] for r in flying]),
                                                  np.array([r["alt_amsl_m"] for r in flying]))
        pos = np.column_stack([along, up])  # in the wall's plane
        out = np.asarray(out)
        de, dn = frame.along_enu
        vn, ve, vd = (np.array([r[k] for r in flying]) for k in ("vn_m_s", "ve_m_s", "vd_m_s"))
        vel = np.column_stack([ve * de + vn * dn, -vd])  # along, up
        yaw = np.array([r["yaw_deg"] for r in flying])
        t_boot = np.array([r["t_boot_s"] if r.get("t_boot_s") is not None else math.nan for r in flying])
    else:
        pos, out, vel, yaw, t_boot = np.zeros((0, 2)), np.zeros(0), np.zeros((0, 2)), np.zeros(0), np.zeros(0)
    legs = []
    for k, (i, j) in enumerate(plan.scan_legs):
        a = np.array([plan.waypoints[i].along_m, plan.waypoints[i].up_m])
        b = np.array([plan.waypoints[j].along_m, plan.waypoints[j].up_m])
        length = float(np.linalg.norm(b - a))
        u = (b - a) / length
        s = (pos - a) @ u
        cross = np.abs((pos - a) @ np.array([-u[1], u[0]]))
        near = (cross <= max_cross_m) & (np.abs(out - standoff) <= max_out_m) & (s >= trim * length)
        on_leg = _first_pass(near & (s <= (1.0 - trim) * length), s, length)
        reach = _first_pass(near & (s <= length + max_cross_m), s, length)  # to the end (and a little beyond)
        middle = on_leg & (np.abs(s - length / 2.0) <= core * length / 2.0)
        speeds = vel[middle] @ u
        timed = middle & np.isfinite(t_boot)
        track = (float(np.polyfit(t_boot[timed], s[timed], 1)[0])
                 if timed.sum() >= 3 and np.ptp(t_boot[timed]) > 0 else math.nan)
        legs.append(LegFigures(
            leg=k, vertical=abs(u[1]) > 0.9, length_m=length, planned_speed_m_s=plan.waypoints[j].speed_m_s,
            median_speed_m_s=float(np.median(speeds)) if speeds.size else math.nan,
            max_yaw_error_deg=float(np.abs(_wrap_deg(yaw[on_leg] - wall_yaw)).max()) if on_leg.any() else math.nan,
            max_standoff_error_m=float(np.abs(out[on_leg] - standoff).max()) if on_leg.any() else math.nan,
            samples=int(on_leg.sum()), core_samples=int(middle.sum()), track_speed_m_s=track,
            end_short_m=length - float(s[reach].max()) if reach.any() else math.nan, descending=bool(u[1] < -0.9)))
    return legs


@dataclass(frozen=True)
class StripEnds:
    """How far before their planned ends the vertical strips turned, with a constant altitude offset removed."""

    mean_short_m: float  # over the down and the up legs before the last, weighted equally
    altitude_offset_m: float  # logged altitude minus the one navigated by, as the down / up pair gives it
    last_short_m: float  # the last vertical leg, corrected by that offset


def strip_ends(legs: list[LegFigures]) -> StripEnds | None:
    """Down legs read ``short + offset``, up legs ``short - offset``: the pair gives both (None without one of
    each before the last vertical leg)."""
    vertical = [g for g in legs if g.vertical and math.isfinite(g.end_short_m)]
    if len(vertical) < 3:
        return None
    down = [g.end_short_m for g in vertical[:-1] if g.descending]
    up = [g.end_short_m for g in vertical[:-1] if not g.descending]
    if not down or not up:
        return None
    offset = (float(np.mean(down)) - float(np.mean(up))) / 2.0
    last = vertical[-1]
    return StripEnds(mean_short_m=(float(np.mean(down)) + float(np.mean(up))) / 2.0, altitude_offset_m=offset,
                     last_short_m=last.end_short_m - offset if last.descending else last.end_short_m + offset)


def flight_figures(plan, rows: list[dict], **kw) -> FlightFigures:
    """The judged figures of a whole flight: legs, items reached, and the final landed / disarmed state."""
    reached = max((r["mission_item"] for r in rows if r.get("mission_item") is not None), default=-1)
    total = max((r["mission_total"] for r in rows if r.get("mission_total") is not None), default=0)
    in_air = [r["in_air"] for r in rows if r.get("in_air") is not None]
    armed = [r["armed"] for r in rows if r.get("armed") is not None]
    landed = (not in_air[-1]) if in_air else None
    disarmed = (not armed[-1]) if armed else None
    if total > 0 and reached == total - 1 and landed and disarmed:
        # the last item (LAND) was being flown and the vehicle is down and disarmed: it is done. ArduCopter never
        # reports progress past it (its current item goes back to 1 after landing); mavsdk counts it only after
        # MISSION_ITEM_REACHED, which the log does not hold.
        reached = total
    return FlightFigures(legs=leg_figures(plan, rows, **kw), items_reached=reached, items_total=total,
                         landed=landed, disarmed=disarmed)


def report(fig: FlightFigures) -> str:
    lines = [f"{'leg':>3} {'dir':4} {'len m':>6} {'plan m/s':>8} {'flown m/s':>9} {'speed err':>9} "
             f"{'track m/s':>9} {'yaw err deg':>11} {'standoff err m':>14} {'end short m':>11} {'samples':>7}"]
    for g in fig.legs:
        lines.append(f"{g.leg:3d} {'vert' if g.vertical else 'horz':4} {g.length_m:6.2f} {g.planned_speed_m_s:8.3f} "
                     f"{g.median_speed_m_s:9.3f} {g.speed_error * 100:8.1f}% {g.track_speed_m_s:9.3f} "
                     f"{g.max_yaw_error_deg:11.2f} "
                     f"{g.max_standoff_error_m:14.3f} {g.end_short_m:11.2f} {g.samples:7d}"
                     f"{'' if g.passed else '  FAIL'}")
    legs = fig.legs
    if legs:
        worst = (max(g.speed_error for g in legs), max(g.max_yaw_error_deg for g in legs),
                 max(g.max_standoff_error_m for g in legs))
        lines.append(f"worst: speed error {worst[0] * 100:.1f} % (limit {MAX_SPEED_ERROR * 100:.0f} %), "
                     f"yaw error {worst[1]:.2f} deg (limit {MAX_YAW_ERROR_DEG:g}), "
                     f"standoff error {worst[2]:.3f} m (limit {MAX_STANDOFF_ERROR_M:g})")
    ends = strip_ends(legs)
    if ends is not None:
        lines.append(f"strip ends (not judged): {ends.mean_short_m:.2f} m short on average, last strip "
                     f"{ends.last_short_m:.2f} m (logged altitude offset {ends.altitude_offset_m:+.2f} m removed)")
    lines.append(f"items reached {fig.items_reached}/{fig.items_total}, landed {fig.landed}, "
                 f"disarmed {fig.disarmed}")
    lines.append("PASS" if fig.passed else "FAIL")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("mission", type=Path, help="the mission file that was flown")
    ap.add_argument("telemetry_log", type=Path, help="the file given to companion fly --telemetry-log")
    ap.add_argument("--max-cross", type=float, default=1.0,
                    help="metres from a leg, in the wall's plane, for a sample to count on it (default 1)")
    ap.add_argument("--max-out", type=float, default=2.0,
                    help="metres from the standoff distance for a sample to count on a leg (default 2)")
    ap.add_argument("--autopilot", choices=("px4", "ardupilot"), default="px4",
                    help="the firmware that flew it: the two fly different plans (PX4 flies the strips' bottoms "
                         "after its home window; default px4)")
    args = ap.parse_args(argv)
    plan = plan_scan(load_mission(args.mission)).for_autopilot(args.autopilot)
    print(f"{args.mission.name}: {len(plan.scan_legs)} scan legs, wall-facing heading "
          f"{plan.frame.yaw_facing_wall_deg:.2f} deg, standoff {plan.mission.standoff_m} m, "
          f"planned scan speed {plan.estimates.scan_speed_m_s:.3f} m/s; log {args.telemetry_log}")
    fig = flight_figures(plan, read_telemetry_log(args.telemetry_log), max_cross_m=args.max_cross,
                         max_out_m=args.max_out)
    print(report(fig))
    return 0 if fig.passed else 1


if __name__ == "__main__":
    sys.exit(main())

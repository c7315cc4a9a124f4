"""How a flown scan compares with its plan on the scan legs: heading against wall-facing, speed along each leg.

Works on the simulator's true poses (``--truth-log`` lines or ``SimVehicle.true_pose()`` dicts: NED metres from
home, velocities, yaw). Only the middle of each leg counts for speed (``core``: the vehicle accelerates and brakes
at its ends); the heading counts over the whole leg except the first and last 2 %. How far before its planned end
a leg turned (PX4 accepts a waypoint within NAV_MC_ALT_RAD vertically) is measured at the furthest point reached on
it: the end rows of the wall that the camera missed.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pymap3d

from companion.files import read_jsonl


@dataclass(frozen=True)
class LegReport:
    leg: int
    length_m: float
    vertical: bool
    planned_speed_m_s: float
    median_speed_m_s: float  # along the leg, in its middle
    max_yaw_error_deg: float  # against the wall-facing heading, anywhere on the leg
    samples: int
    end_short_m: float = math.nan  # how far before its planned end the vehicle turned off the leg (0: it got there)

    @property
    def speed_error(self) -> float:
        return abs(self.median_speed_m_s - self.planned_speed_m_s) / self.planned_speed_m_s


def read_truth_log(path: Path) -> list[dict]:
    return read_jsonl(path, skip_bad=False)


def _wrap(deg: float) -> float:
    return (deg + 180.0) % 360.0 - 180.0


def scan_leg_reports(plan, poses: Iterable[dict], core: float = 0.6, max_cross_m: float = 0.5) -> list[LegReport]:
    """One report per scan leg of ``plan`` from true ``poses`` (home = ``plan.home``)."""
    rows = [p for p in poses if p.get("in_air", True)]
    if not rows:
        return []
    pos = np.array([[p["north_m"], p["east_m"], p["down_m"]] for p in rows])
    vel = np.array([[p["vn_m_s"], p["ve_m_s"], p["vd_m_s"]] for p in rows])
    yaw = np.array([p["yaw_deg"] for p in rows])
    h = plan.home
    wall_yaw = plan.frame.yaw_facing_wall_deg
    out = []
    for k, (i, j) in enumerate(plan.scan_legs):
        a, b = (np.array(pymap3d.geodetic2ned(w.lat, w.lon, h.alt_amsl_m + w.rel_alt_m, h.lat, h.lon, h.alt_amsl_m))
                for w in (plan.waypoints[i], plan.waypoints[j]))
        d = b - a
        length = float(np.linalg.norm(d))
        u = d / length
        s = (pos - a) @ u
        cross = np.linalg.norm(pos - a - np.outer(s, u), axis=1)
        on_leg = (cross < max_cross_m) & (s > 0.02 * length) & (s < 0.98 * length)
        middle = on_leg & (np.abs(s - length / 2.0) <= core * length / 2.0)
        speeds = vel[middle] @ u
        errors = [abs(_wrap(y - wall_yaw)) for y in yaw[on_leg]]
        reach = s[(cross < max_cross_m) & (s > 0.02 * length)]  # a pass on beyond the end (an exit climb) is no loss
        out.append(LegReport(
            leg=k, length_m=length, vertical=abs(u[2]) > 0.9, planned_speed_m_s=plan.waypoints[j].speed_m_s,
            median_speed_m_s=float(np.median(speeds)) if len(speeds) else math.nan,
            max_yaw_error_deg=max(errors) if errors else math.nan, samples=int(middle.sum()),
            end_short_m=max(0.0, length - float(reach.max())) if reach.size else math.nan))
    return out


def worst(reports: Sequence[LegReport]) -> tuple[float, float]:
    """(largest relative speed error, largest heading error in degrees) over all legs; NaN if a leg was missed."""
    if not reports or any(r.samples == 0 for r in reports):
        return math.nan, math.nan
    return max(r.speed_error for r in reports), max(r.max_yaw_error_deg for r in reports)


@dataclass(frozen=True)
class LegStandoff:
    """The TRUE camera-to-wall distance while the vehicle flew one scan leg (the simulator's truth, not what its
    GNSS-biased telemetry says): median, least and most, over the samples whose true position lies on the leg
    seen face-on (within ``max_cross_m`` of it along and up the wall, whatever its distance)."""

    leg: int
    planned_m: float
    median_m: float
    min_m: float
    max_m: float
    samples: int

    @property
    def worst_error_m(self) -> float:
        """The largest distance from the plan on this leg (NaN when no sample lay on it)."""
        return max(abs(self.min_m - self.planned_m), abs(self.max_m - self.planned_m)) if self.samples else math.nan


def flown_standoff(plan, poses: Iterable[dict], max_cross_m: float = 0.5) -> list[LegStandoff]:
    """One :class:`LegStandoff` per scan leg of ``plan`` from true ``poses`` (``--truth-log`` lines). Which leg a
    sample is on is decided where the vehicle THOUGHT it was (the estimate's ``nav_*`` keys: it flies its
    estimate along the planned leg, a GNSS bias or not), in the wall's plane only (along, up: a standoff
    correction moves the path across the wall); its distance from the wall is the TRUE position's. Lines without
    the estimate (an older log) are matched by the true position."""
    rows = [p for p in poses if p.get("in_air", True) and p.get("lat") is not None]
    out: list[LegStandoff] = []
    if not rows:
        return out
    frame = plan.frame

    def facade(prefix: str):
        keys = [prefix + k for k in ("lat", "lon", "alt_amsl_m")]
        if prefix and not all(k in rows[0] for k in keys):
            keys = ["lat", "lon", "alt_amsl_m"]
        return (np.asarray(v, dtype=float) for v in frame.geodetic_to_facade(
            *(np.array([p[k] for p in rows], dtype=float) for k in keys)))

    _, dist, _ = facade("")
    along, _, up = facade("nav_")
    for k, (i, j) in enumerate(plan.scan_legs):
        a, b = plan.waypoints[i], plan.waypoints[j]
        pa, pb = np.array([a.along_m, a.up_m]), np.array([b.along_m, b.up_m])
        d = pb - pa
        length = float(np.linalg.norm(d))
        u = d / length
        rel = np.column_stack((along, up)) - pa
        s = rel @ u
        cross = np.abs(rel @ np.array([-u[1], u[0]]))
        on = (cross < max_cross_m) & (s > 0.02 * length) & (s < 0.98 * length) & (dist > 0.3 * a.out_m) \
            & (dist < 2.0 * a.out_m)
        ds = dist[on]
        out.append(LegStandoff(k, float(a.out_m), float(np.median(ds)) if ds.size else math.nan,
                               float(ds.min()) if ds.size else math.nan, float(ds.max()) if ds.size else math.nan,
                               int(on.sum())))
    return out

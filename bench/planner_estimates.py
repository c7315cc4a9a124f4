"""Planner figures for the example missions: estimates, standoff of every scan waypoint measured independently
(geodesy round trip), coverage check and planning time.

    python bench/planner_estimates.py [missions/*.yaml]
"""

from __future__ import annotations

import math
import sys
import time
from pathlib import Path

import pymap3d

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from companion.mission import load_mission, plan_scan  # noqa: E402


def standoff_errors(plan) -> list[float]:
    """|horizontal distance to the wall line - standoff| for each scan waypoint, from lat/lon alone."""
    s = plan.frame.origin
    lat2, lon2, _ = plan.frame.facade_to_geodetic(plan.frame.length_m, 0.0, 0.0)
    ee, en, _ = pymap3d.geodetic2enu(lat2, lon2, s.alt_amsl_m, s.lat, s.lon, s.alt_amsl_m)
    out = []
    for wp in plan.waypoints:
        if wp.kind != "scan":
            continue
        pe, pn, _ = pymap3d.geodetic2enu(wp.lat, wp.lon, s.alt_amsl_m, s.lat, s.lon, s.alt_amsl_m)
        out.append(abs(abs(ee * pn - en * pe) / math.hypot(ee, en) - plan.mission.standoff_m))
    return out


def main(paths: list[str]) -> int:
    paths = paths or sorted(str(p) for p in (ROOT / "missions").glob("*.yaml"))
    for path in paths:
        t0 = time.perf_counter()
        plan = plan_scan(load_mission(path))
        ms = 1000 * (time.perf_counter() - t0)
        e = plan.estimates
        err = standoff_errors(plan)
        print(
            f"{Path(path).name}: wall {plan.frame.length_m:.1f} x {plan.mission.facade.height_m:.0f} m, "
            f"standoff {plan.mission.standoff_m} m, {plan.mission.pattern}"
        )
        print(
            f"  footprint {e.footprint_width_m:.2f} x {e.footprint_height_m:.2f} m, GSD {e.gsd_mm_per_px:.3f} mm/px, "
            f"{e.strips} strips {e.strip_spacing_m:.2f} m apart (side overlap {e.side_overlap_achieved:.1%})"
        )
        print(
            f"  scan {e.scan_speed_m_s:.3f} m/s ({e.speed_limited_by}), blur {e.motion_blur_px:.2f} px, "
            f"{e.frames_per_keyframe:.1f} frames/keyframe, keyframe every {e.keyframe_spacing_m:.3f} m"
        )
        print(
            f"  path {e.path_length_m:.0f} m, flight {e.flight_time_s / 60:.1f} min, {e.expected_keyframes} keyframes, "
            f"{len(plan.waypoints)} waypoints, {len(plan.mavlink_items())} MAVLink items"
        )
        print(
            f"  scan waypoint standoff error: max {max(err) * 1000:.2f} mm over {len(err)} waypoints; "
            f"planned in {ms:.0f} ms"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

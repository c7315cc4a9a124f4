"""`companion plan`: plan a mission and write its exports;
`--refly MAPDIR` plans only the uncovered areas of a stitched map (``companion.mission.refly``)."""

from __future__ import annotations

import argparse
from pathlib import Path

from companion.mission.exports import flight_parameters_by_autopilot, render_outputs, write_outputs
from companion.mission.planner import ScanPlan, plan_scan
from companion.mission.refly import MIN_AREA_M2, MIN_AREA_SIZE_M, format_region, refly_to_dir
from companion.mission.spec import load_mission
from companion.resources import mission_argument, shipped_missions


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("plan", help="plan a facade scan and write mission exports + a review plot")
    p.add_argument("mission", type=mission_argument,
                   help=f"mission YAML, or a shipped mission's name ({', '.join(shipped_missions())})")
    p.add_argument("--out", type=Path, required=True, help="output directory")
    p.add_argument(
        "--refly",
        type=Path,
        metavar="MAPDIR",
        help="plan only the uncovered areas of this stitched map folder (companion stitch --out), same standoff "
        "and overlap",
    )
    p.add_argument(
        "--refly-min-size-m",
        type=float,
        default=MIN_AREA_SIZE_M,
        metavar="M",
        help=f"with --refly: leave out uncovered areas thinner than this (default {MIN_AREA_SIZE_M} m: slivers "
        "along the map's edges and seams); 0 (with --refly-min-area-m2 0) flies every area",
    )
    p.add_argument(
        "--refly-min-area-m2",
        type=float,
        default=MIN_AREA_M2,
        metavar="M2",
        help=f"with --refly: leave out uncovered areas smaller than this (default {MIN_AREA_M2} m2: a patch not "
        "worth strips)",
    )
    p.set_defaults(func=run_plan)


def format_estimates(plan: ScanPlan) -> str:
    e = plan.estimates
    plural = f"{e.strips} {plan.mission.pattern} strips {e.strip_spacing_m:.2f} m apart"
    lines = [
        f"mission {plan.mission.name}: wall {plan.frame.length_m:.1f} m x {plan.mission.facade.height_m:.1f} m, "
        f"standoff {plan.mission.standoff_m} m, heading to wall {plan.frame.yaw_facing_wall_deg:.1f} deg",
        f"  camera footprint {e.footprint_width_m:.2f} m x {e.footprint_height_m:.2f} m, "
        f"GSD {e.gsd_mm_per_px:.2f} mm/px",
        f"  {plural} (side overlap {e.side_overlap_achieved:.0%})",
        f"  scan speed {e.scan_speed_m_s:.2f} m/s (limited by {e.speed_limited_by}): "
        f"{e.frames_per_keyframe:.1f} frames per keyframe, motion blur {e.motion_blur_px:.2f} px",
        f"  path {e.path_length_m:.0f} m, flight time ~{e.flight_time_s / 60:.1f} min, "
        f"~{e.expected_keyframes} keyframes at {plan.mission.overlap:.0%} overlap",
    ]
    for autopilot, params in flight_parameters_by_autopilot(plan).items():
        if "error" in params:
            lines.append(f"  {autopilot}: cannot be flown as planned: {params['error']}")
        elif params:
            listed = ", ".join(f"{k}={v:g}" for k, v in params.items())
            lines.append(f"  {autopilot} flight parameters: {listed} (see docs/FLIGHT.md)")
    lines += _home_window_lines(plan)
    lines += [f"  warning: {w}" for w in plan.warnings]
    return "\n".join(lines)


def _home_window_lines(plan: ScanPlan) -> list[str]:
    """What the PX4 plan does about PX4 moving home's altitude (and every waypoint with it) for 120 s after take-off,
    and what ArduPilot, which keeps home where it armed, flies instead."""
    e, steady = plan.estimates, plan.steady_home
    if not plan.moving_home or steady is None:
        return []
    settle = plan.mission.margins.home_settle_s
    floor = f"{e.px4_window_floor_m:g} m above home"
    if e.px4_low_after_s <= 0:
        lines = [f"  px4: the whole flight stays {floor} or higher, clear of the ground whatever PX4 does with home's "
                 f"altitude in the {settle:g} s after take-off"]
    else:
        what = (f"then the strips' bottoms as {e.px4_bottom_band_rows} pass{'es' if e.px4_bottom_band_rows > 1 else ''}"
                f" along the wall" if e.px4_bottom_band_rows else "then the part below")
        wait = (f", after holding {e.px4_home_settle_hold_s:.0f} s at the last waypoint above"
                if e.px4_home_settle_hold_s > 0 else "")
        lines = [f"  px4: flies the scan down to {floor} first, {what}, from {e.px4_low_after_s:.0f} s after take-off"
                 f"{wait}: PX4 moves home's altitude, and every waypoint with it, for {settle:g} s after take-off "
                 f"(margins.home_settle_s; docs/FLIGHT.md)"]
    s = steady.estimates
    lines.append(f"  ardupilot (keeps home where it armed): the strips in plain order, path {s.path_length_m:.0f} m, "
                 f"flight time ~{s.flight_time_s / 60:.1f} min, ~{s.expected_keyframes} keyframes")
    return lines


def plan_to_dir(mission_path: Path, out: Path) -> tuple[ScanPlan, list[Path]]:
    plan = plan_scan(load_mission(mission_path))
    files = render_outputs(plan)  # everything rendered before anything is written
    return plan, write_outputs(files, out)


def run_plan(args: argparse.Namespace) -> int:
    if args.refly is not None:
        return run_refly(args)
    plan, written = plan_to_dir(args.mission, args.out)
    print(format_estimates(plan))
    print(f"wrote {len(written)} files to {args.out}")
    return 0


def run_refly(args: argparse.Namespace) -> int:
    refly, written = refly_to_dir(args.mission, args.refly, args.out, min_size_m=args.refly_min_size_m,
                                  min_area_m2=args.refly_min_area_m2)
    for line in (*refly.notes, *(f"left out: {s}" for s in refly.skipped)):
        print(f"  note: {line}")
    print(refly.message)
    if refly.plan is None:
        return 0
    for k, g in enumerate(refly.groups):
        print(f"  group {k + 1}: {len(g.areas)} area(s), frames over {format_region(g.region)}")
    print(format_estimates(refly.plan))
    print(f"wrote {len(written)} files to {args.out}")
    return 0

"""`companion demo`: the main job on the built-in default mission and model.

Plans the demo facade, starts the SITL rig (simulated vehicle + simulated camera), flies the scan through MAVSDK
while culling the live frames into a keyframe spool (depth mask + overlap gate), stitches the facade map, and
prints where everything is. It lives in sim/ because it starts the simulator; the steps are companion's.
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from companion.errors import CompanionError
from companion.mission import load_mission, plan_scan
from companion.mission.commands import format_estimates
from companion.mission.exports import render_outputs, write_outputs
from companion.resources import demo_mission, mission_argument
from companion.spool.layout import MANIFEST

# The simulated camera renders in real time (texture warp, docs/BENCHMARKS.md "Camera simulator"); 10 frames/s
# because the onboard chain processes about 3 per second on a 2-core machine today (it drops the rest).
DEFAULT_FPS = 10.0
DEFAULT_WIDTH_PX = 640
DEFAULT_OUT = Path("out/demo")
TRUTH_LOG = "truth.jsonl"  # the simulated vehicle's true pose, beside its log (out/demo/sim/)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo", help="full SITL facade scan on the built-in demo mission: plan, fly, cull, stitch")
    p.add_argument("--mission", type=mission_argument, default=None,
                   help="mission YAML or a shipped mission's name (default: the demo facade)")
    p.add_argument("--out", type=Path, default=DEFAULT_OUT, help=f"output directory (default: {DEFAULT_OUT})")
    p.add_argument("--speedup", type=float, default=1.0, help="simulated seconds per wall second (default 1)")
    p.add_argument("--fps", type=float, default=DEFAULT_FPS,
                   help=f"simulated camera frame rate in simulated time (default {DEFAULT_FPS:g}; the mission "
                        "camera's is 30)")
    p.add_argument("--width", type=int, default=DEFAULT_WIDTH_PX,
                   help=f"simulated camera working width in px (default {DEFAULT_WIDTH_PX})")
    p.add_argument("--seed", type=int, default=0, help="scene and simulator seed")
    p.add_argument("--model", type=Path, help="depth model .onnx (default: the shipped model)")
    p.add_argument("--no-mask", action="store_true", help="skip background removal")
    p.add_argument("--plan-only", action="store_true", help="only plan and write the mission exports")
    p.add_argument("--gnss-bias", type=_gnss_bias, default=None, metavar="E,N,U",
                   help="the simulated vehicle's GNSS is off by this much (metres east, north, up), as a non-RTK "
                        "receiver is for minutes: it flies and reports its estimate, the camera sees the truth "
                        "(a negative first value: --gnss-bias=-1.5,0,0)")
    p.add_argument("--gnss-drift", type=float, default=0.0, metavar="M_PER_MIN",
                   help="and the bias wanders by about this much per minute (seeded random walk)")
    p.add_argument("--rangefinder", action="store_true",
                   help="the simulated vehicle has a forward rangefinder (MAVLink DISTANCE_SENSOR)")
    p.set_defaults(func=run_demo)


def _gnss_bias(text: str) -> tuple[float, float, float]:
    try:
        east, north, up = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"--gnss-bias wants EAST,NORTH,UP in metres (e.g. 0,1.5,0), got {text!r}") from None
    return east, north, up


def sim_options_of(args: argparse.Namespace) -> dict:
    """The simulated vehicle's options the demo's flags ask for (none: the vehicle's GNSS is exact)."""
    options: dict = {}
    if args.gnss_bias is not None:
        options["gnss_bias"] = args.gnss_bias
    if args.gnss_drift:
        if args.gnss_drift < 0:
            raise CompanionError(f"--gnss-drift {args.gnss_drift:g} is negative", "give metres per minute, e.g. 0.5")
        options["gnss_drift"] = args.gnss_drift
    if args.rangefinder:
        options["rangefinder"] = True
    return options


def plan_for_camera(mission_path: Path, fps: float):
    """The scan planned for the frames the gate can get: the simulated camera delivers ``fps`` frames per second,
    so the planner's ``onboard_fps`` (frames processed per second) is at most that; its scan speed then keeps
    ``min_frames_per_keyframe`` of them between keyframes, as it would for a real camera at that rate."""
    mission = load_mission(mission_path)
    if fps < (mission.onboard_fps or mission.camera.fps):
        mission = mission.model_copy(update={"onboard_fps": fps})
    return plan_scan(mission)


@dataclass(frozen=True)
class DemoFlight:
    """What the SITL flight with live culling gave: the live scan's result, the simulated camera's counts and the
    TRUE standoff flown on the scan legs (the simulator's truth: what GNSS-biased telemetry cannot say)."""

    scan: object  # companion.onboard.live.LiveScanResult
    camera: dict
    standoff: dict | None = None  # true_standoff(...)


def true_standoff(plan, truth_log: Path) -> dict | None:
    """The true camera-to-wall distance on the scan legs, from the simulator's truth log: over all legs and over
    the legs after the first strip (a measured standoff can only be corrected once it has been measured)."""
    from sim.evaluate_scan import flown_standoff, read_truth_log

    if not truth_log.exists():
        return None
    legs = [leg for leg in flown_standoff(plan, read_truth_log(truth_log)) if leg.samples]
    if not legs:
        return None
    later = legs[1:] or legs
    return {
        "planned_m": legs[0].planned_m,
        "median_m": round(float(np.median([leg.median_m for leg in legs])), 3),
        "first_leg_median_m": round(legs[0].median_m, 3),
        "after_first_strip_min_m": round(min(leg.min_m for leg in later), 3),
        "after_first_strip_max_m": round(max(leg.max_m for leg in later), 3),
        "after_first_strip_worst_error_m": round(max(leg.worst_error_m for leg in later), 3),
        "legs": len(legs),
        "meaning": "the simulator's TRUE camera-to-wall distance on the scan legs (telemetry may say otherwise)",
    }


def standoff_line(standoff: dict) -> str:
    return (f"true standoff on the scan legs: median {standoff['median_m']:.2f} m (plan {standoff['planned_m']:.2f}); "
            f"after the first strip {standoff['after_first_strip_min_m']:.2f}-"
            f"{standoff['after_first_strip_max_m']:.2f} m")


def run_demo(args: argparse.Namespace) -> int:
    out: Path = args.out
    mission_path = args.mission or demo_mission()
    _check_demo_args(out, args.fps)
    sim_options_of(args)  # refused before anything is written
    plan = plan_for_camera(mission_path, args.fps)
    written = write_outputs(render_outputs(plan), out / "plan")
    print(format_estimates(plan))
    print(f"plan: {len(written)} files in {out / 'plan'}")
    if args.plan_only:
        return 0
    t0 = time.monotonic()
    print(f"flying the scan in SITL (speed-up {args.speedup:g}, camera {args.width} px @ {args.fps:g} fps)...")
    demo = fly_demo(plan, mission_path, args)
    _print_flight(plan, demo, args.fps)
    print("stitching the keyframes...")
    result = stitch_demo(out)
    report = demo_report(plan, demo, result, wall_time_s=time.monotonic() - t0)
    (out / "report.json").write_text(json.dumps(report, indent=1, default=str))
    print(f"map: {result.files.get('map') or result.files.get('tiles')}")
    print(f"preview with scale bar and re-fly areas: {result.files.get('preview')}")
    print(f"coverage: {100 * result.coverage_fraction:.1f} % ({len(result.uncovered)} uncovered area(s))")
    print(f"keyframe spool: {out / 'spool'}   telemetry log: {demo.scan.telemetry_log}")
    print(f"report: {out / 'report.json'}")
    return 0 if demo.scan.flight.completed else 1


def _check_demo_args(out: Path, fps: float) -> None:
    """Refuse before anything is written: a folder holding a run, a frame rate that is not one."""
    if (out / "spool" / MANIFEST).exists():
        raise CompanionError(
            f"{out} already holds a demo run", f"pass a new --out directory or remove {out} to start over"
        )
    if not fps > 0:
        raise CompanionError(f"--fps {fps:g} is not a frame rate", "give a positive rate, e.g. --fps 10")


def fly_demo(plan, mission_path: Path, args: argparse.Namespace, **fly_kwargs) -> DemoFlight:
    """Start the SITL rig, fly the plan culling the simulated camera's frames into ``out/spool``, stop the rig
    (``fly_kwargs`` go to the flight, e.g. ``standoff=StandoffOptions(correct=False)``)."""
    from companion.onboard.live import run_live_scan
    from sim.rig import SitlRig, sitl_profile_for

    out: Path = args.out
    with SitlRig(
        mission_path, log_dir=out / "sim", seed=args.seed, width_px=args.width, fps=args.fps, speedup=args.speedup,
        truth_log=out / "sim" / TRUTH_LOG, sim_options=sim_options_of(args),
    ) as rig:
        scan = run_live_scan(plan, rig.url, rig.capture, out / "spool", model=args.model, mask=not args.no_mask,
                             end_action=plan.mission.end_action, progress=True,
                             sitl_profile=sitl_profile_for(rig.autopilot),
                             **{k: v for k, v in fly_kwargs.items() if v is not None})
    camera = {"fps": args.fps, "width_px": args.width, "renderer": rig.renderer, **(rig.camera_counts() or {})}
    return DemoFlight(scan, camera, true_standoff(plan, out / "sim" / TRUTH_LOG))


def _print_flight(plan, demo: DemoFlight, fps: float) -> None:
    from companion.onboard.scan_flight import culling_summary

    flight, st = demo.scan.flight, demo.scan.stats
    print(
        f"flight: {'complete' if flight.completed else 'NOT complete'}, {flight.items_reached}/{flight.items_total} "
        f"items, {'landed' if flight.landed else 'NOT landed'}, {flight.duration_s:.0f} s"
    )
    print(culling_summary(st))
    expected = plan.estimates.expected_keyframes
    print(f"keyframes: {st.keyframes} against the planner's expected {expected} "
          f"({st.keyframes / expected:.2f}x)" if expected else f"keyframes: {st.keyframes} (planner expects none)")
    camera = demo.camera
    if "frames_dropped" in camera:
        print(f"camera: {camera['frames_sent']} frames sent at {fps:g} fps, {camera['frames_dropped']} dropped "
              f"(rendering behind simulated time)")
    if demo.scan.capture_error:
        print(f"capture error: {demo.scan.capture_error}")
    if flight.standoff is not None:
        print(flight.standoff.line())
    if demo.standoff:
        print(standoff_line(demo.standoff))


def stitch_demo(out: Path):
    from companion.spool.reader import load_spool
    from companion.stitch.worker import stitch

    return stitch(load_spool(out / "spool"), out / "map", progress=True)


def demo_report(plan, demo: DemoFlight, result, *, wall_time_s: float) -> dict:
    """``report.json``: the plan's estimates beside what the flight, the culling and the map achieved."""
    flight, st = demo.scan.flight, demo.scan.stats
    expected = plan.estimates.expected_keyframes
    return {
        "mission": plan.mission.name,
        "plan_estimates": plan.estimates.as_dict(),
        "flight": {
            "completed": flight.completed,
            "items_reached": flight.items_reached,
            "items_total": flight.items_total,
            "landed": flight.landed,
            "disarmed": flight.disarmed,
            "duration_s": round(flight.duration_s, 1),
            "link_losses": len(flight.link_losses),
            "standoff": flight.standoff.as_json() if flight.standoff is not None else None,
        },
        "camera": demo.camera,
        "true_standoff": demo.standoff,
        "culling": st.as_dict(),
        "keyframes": {
            "kept": st.keyframes,
            "planner_expected": expected,
            "ratio_to_expected": round(st.keyframes / expected, 3) if expected else None,
        },
        "map": {
            "files": result.files,
            "mm_per_px": result.mm_per_px,
            "wall_distance": result.report.get("wall_distance"),
            "placement": result.report.get("placement"),
            "coverage_fraction": round(result.coverage_fraction, 4),
            "uncovered_areas": len(result.uncovered),
        },
        "wall_time_s": round(wall_time_s, 1),
    }

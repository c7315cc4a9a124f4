"""`companion demo`: the main job on the built-in default mission and model.

Plans the demo facade, starts the SITL rig (simulated vehicle + simulated camera), flies the scan through MAVSDK
while culling the live frames into a keyframe spool (depth mask + overlap gate), stitches the facade map, and
prints where everything is.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from companion.errors import CompanionError
from companion.mission import load_mission, plan_scan
from companion.mission.commands import DEFAULT_MISSION, format_estimates
from companion.mission.exports import render_outputs, write_outputs


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo", help="full SITL facade scan on the built-in demo mission: plan, fly, cull, stitch")
    p.add_argument("--mission", type=Path, default=DEFAULT_MISSION, help="mission YAML (default: the demo facade)")
    p.add_argument("--out", type=Path, default=Path("out/demo"), help="output directory (default: out/demo)")
    p.add_argument("--speedup", type=float, default=1.0, help="simulated seconds per wall second (default 1)")
    # The simulated camera renders in real time (texture warp, docs/BENCHMARKS.md "Camera simulator"); 10 frames/s
    # because the onboard chain processes about 3 per second on a 2-core machine today (it drops the rest).
    p.add_argument("--fps", type=float, default=10.0,
                   help="simulated camera frame rate in simulated time (default 10; the mission camera's is 30)")
    p.add_argument("--width", type=int, default=640, help="simulated camera working width in px (default 640)")
    p.add_argument("--seed", type=int, default=0, help="scene and simulator seed")
    p.add_argument("--model", type=Path, help="depth model .onnx (default: the shipped model)")
    p.add_argument("--no-mask", action="store_true", help="skip background removal")
    p.add_argument("--plan-only", action="store_true", help="only plan and write the mission exports")
    p.set_defaults(func=run_demo)


def plan_for_camera(mission_path: Path, fps: float):
    """The scan planned for the frames the gate can get: the simulated camera delivers ``fps`` frames per second,
    so the planner's ``onboard_fps`` (frames processed per second) is at most that; its scan speed then keeps
    ``min_frames_per_keyframe`` of them between keyframes, as it would for a real camera at that rate."""
    mission = load_mission(mission_path)
    if fps < (mission.onboard_fps or mission.camera.fps):
        mission = mission.model_copy(update={"onboard_fps": fps})
    return plan_scan(mission)


def run_demo(args: argparse.Namespace) -> int:
    from companion.onboard.live import run_live_scan
    from companion.spool.layout import MANIFEST
    from companion.spool.reader import load_spool
    from companion.stitch.worker import stitch
    from sim.rig import SitlRig

    out: Path = args.out
    if (out / "spool" / MANIFEST).exists():
        raise CompanionError(
            f"{out} already holds a demo run", f"pass a new --out directory or remove {out} to start over"
        )
    if not args.fps > 0:
        raise CompanionError(f"--fps {args.fps:g} is not a frame rate", "give a positive rate, e.g. --fps 10")
    plan = plan_for_camera(args.mission, args.fps)
    written = write_outputs(render_outputs(plan), out / "plan")
    print(format_estimates(plan))
    print(f"plan: {len(written)} files in {out / 'plan'}")
    if args.plan_only:
        return 0
    t0 = time.monotonic()
    print(f"flying the scan in SITL (speed-up {args.speedup:g}, camera {args.width} px @ {args.fps:g} fps)...")
    with SitlRig(
        args.mission, log_dir=out / "sim", seed=args.seed, width_px=args.width, fps=args.fps, speedup=args.speedup
    ) as rig:
        scan = run_live_scan(
            plan,
            rig.url,
            rig.capture,
            out / "spool",
            model=args.model,
            mask=not args.no_mask,
            end_action=plan.mission.end_action,
            progress=True,
        )
    flight = scan.flight
    st = scan.stats
    print(
        f"flight: {'complete' if flight.completed else 'NOT complete'}, {flight.items_reached}/{flight.items_total} "
        f"items, {'landed' if flight.landed else 'NOT landed'}, {flight.duration_s:.0f} s"
    )
    print(
        f"culling: {st.frames_in} frames -> {st.keyframes} keyframes ({st.skipped_backlog} skipped for CPU, "
        f"{st.dropped_no_roi} without facade, {st.overlap_warnings} overlap warnings, {st.gaps} gaps)"
    )
    expected = plan.estimates.expected_keyframes
    print(f"keyframes: {st.keyframes} against the planner's expected {expected} "
          f"({st.keyframes / expected:.2f}x)" if expected else f"keyframes: {st.keyframes} (planner expects none)")
    camera = {"fps": args.fps, "width_px": args.width, "renderer": rig.renderer, **(rig.camera_counts() or {})}
    if "frames_dropped" in camera:
        print(f"camera: {camera['frames_sent']} frames sent at {args.fps:g} fps, {camera['frames_dropped']} dropped "
              f"(rendering behind simulated time)")
    if scan.capture_error:
        print(f"capture error: {scan.capture_error}")
    print("stitching the keyframes...")
    result = stitch(load_spool(out / "spool"), out / "map", progress=True)
    report = {
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
        },
        "camera": camera,
        "culling": st.as_dict(),
        "keyframes": {
            "kept": st.keyframes,
            "planner_expected": expected,
            "ratio_to_expected": round(st.keyframes / expected, 3) if expected else None,
        },
        "map": {
            "files": result.files,
            "mm_per_px": result.mm_per_px,
            "coverage_fraction": round(result.coverage_fraction, 4),
            "uncovered_areas": len(result.uncovered),
        },
        "wall_time_s": round(time.monotonic() - t0, 1),
    }
    (out / "report.json").write_text(json.dumps(report, indent=1, default=str))
    print(f"map: {result.files.get('map') or result.files.get('tiles')}")
    print(f"preview with scale bar and re-fly areas: {result.files.get('preview')}")
    print(f"coverage: {100 * result.coverage_fraction:.1f} % ({len(result.uncovered)} uncovered area(s))")
    print(f"keyframe spool: {out / 'spool'}   telemetry log: {scan.telemetry_log}")
    print(f"report: {out / 'report.json'}")
    return 0 if flight.completed else 1

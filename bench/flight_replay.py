"""A flown demo replayed: the scan scope over every camera frame of its telemetry, and its frames re-rendered for
`companion cull`.

    python bench/flight_replay.py TELEMETRY [--mission missions/demo-facade.yaml] [--fps 30]
                                  [--out DIR --width 640 --from S --to S --seed 0]

Issue 17's judged run (`companion demo --fps 30 --width 1280`) spools only keyframes, but its telemetry log
(``spool/telemetry.jsonl``) holds the whole flight. This walks it at the camera's rate (a frame every 1/fps s, the
pose interpolated by the chain's own ``TelemetryBuffer``) and says, per rule, which frames the chain would judge:
``before`` is the loose scope alone (``ScanScope.off_scan`` per frame), ``after`` the scope as the chain applies
it now (``ScanPhase``: a segment opens only on a frame of the planned scan). Printed: frames judged, the first
judged frame (time, distance out, footprint bottom on the wall plane), scan segments, and the frames only the old
rule judged.

With ``--out``, the frames of [--from, --to] s are rendered from the same poses (the simulator's warp renderer,
the camera on its stabilised gimbal as the live camera renders it) into a recording, so the chain can be replayed
on them with `companion cull DIR/frames --telemetry TELEMETRY --mission ...` by two checkouts side by side and
the spools compared with bench/keyframe_phases.py. The scene is the seeded simulator scene, not the judged run's
pixels (those were not kept); the poses are the flight's telemetry. Simulator figures.
"""

from __future__ import annotations

import argparse
import math
import shutil
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from companion.capture.telemetry import TelemetryBuffer  # noqa: E402
from companion.files import read_jsonl  # noqa: E402
from companion.keyframes.gate_scope import ScanPhase  # noqa: E402
from companion.mission import load_mission  # noqa: E402
from companion.onboard.setup import scan_scope  # noqa: E402
from companion.records import Pose  # noqa: E402


def flight_poses(telemetry: Path) -> TelemetryBuffer:
    buf = TelemetryBuffer(max_samples=1_000_000)  # the whole flight
    for row in read_jsonl(telemetry):
        pose = Pose.from_json(row)
        if pose is not None:
            buf.add(pose)
    return buf


def frame_times(buf: TelemetryBuffer, fps: float, t0: float | None = None, t1: float | None = None) -> np.ndarray:
    first, last = buf.first_time_s, buf.newest_time_s
    start = first if t0 is None else max(first, t0)
    stop = last if t1 is None else min(last, t1)
    return np.arange(math.ceil(start * fps), math.floor(stop * fps) + 1) / fps


def describe(scope, pose: Pose) -> str:
    corners = scope.footprint(pose)
    bottom = "-" if corners is None else f"{float(corners[:, 1].min()):.2f}"
    return f"out {scope.distance_m(pose):.2f} m, footprint bottom {bottom} m"


def scope_replay(buf: TelemetryBuffer, mission, fps: float) -> None:
    scope = scan_scope(mission)
    phase = ScanPhase(scope)
    times = frame_times(buf, fps)
    before, after = [], []
    for t in times:
        pose = buf.pose_at(float(t)).pose
        before.append(not scope.off_scan(pose))
        after.append(phase.step(pose).judged)
    before, after = np.array(before), np.array(after)
    print(f"{len(times)} camera frames at {fps:g} fps over {times[0]:.1f}-{times[-1]:.1f} s of telemetry; "
          f"scan extent {tuple(round(v, 2) for v in scope.extent)}, standoff {scope.standoff_m:g} m")
    for name, judged in (("before (loose scope per frame)", before), ("after (ScanPhase)", after)):
        idx = np.flatnonzero(judged)
        first = float(times[idx[0]]) if len(idx) else None
        runs = int(np.count_nonzero(np.diff(np.concatenate([[0], judged.astype(int)])) == 1))
        where = "" if first is None else f" at t {first:.2f} s ({describe(scope, buf.pose_at(first).pose)})"
        print(f"  {name}: {len(idx)} frames judged, {runs} judged stretch(es); first judged frame{where}")
    only = np.flatnonzero(before & ~after)
    print(f"  frames only the old rule judged: {len(only)}")
    for k in (only if len(only) <= 12 else np.concatenate([only[:6], only[-6:]])):
        t = float(times[k])
        print(f"    t {t:7.2f} s  {describe(scope, buf.pose_at(t).pose)}")
    if len(only) > 12:
        print(f"    ({len(only) - 12} more between them: the first six and the last six are listed)")


def render_frames(buf: TelemetryBuffer, mission, telemetry: Path, out: Path, *, fps: float, width: int,
                  t0: float | None, t1: float | None, seed: int) -> None:
    """The camera's frames (JPEG + ``times.csv``: the image folder `companion cull` reads) at the telemetry's
    poses; no depth or truth masks (the chain does not read them, and at 30 fps they would fill the disk)."""
    import cv2

    from companion.geo import FacadeFrame
    from companion.mission.geometry import wall_ends
    from sim.camera.live import camera_pose
    from sim.camera.recording import camera_from_mission
    from sim.camera.render import AutoExposure
    from sim.camera.scene import Scene
    from sim.camera.warp_render import make_renderer

    frame = FacadeFrame.from_wall(*wall_ends(mission))
    scene = Scene.build(frame.length_m, float(mission.facade.height_m), seed=seed)
    cam = camera_from_mission(mission, width)
    render = make_renderer("warp", scene, frame, cam, exposure_s=float(mission.camera.exposure_s), seed=seed)
    frames_dir = out / "frames"
    frames_dir.mkdir(parents=True, exist_ok=False)
    ae = AutoExposure(seed=seed)
    times = frame_times(buf, fps, t0, t1)
    cpu = time.process_time()
    lines = []
    for k, t in enumerate(times):
        p = buf.pose_at(float(t)).pose
        msg = {"lat": p.lat, "lon": p.lon, "alt_amsl_m": p.alt_amsl_m, "yaw_deg": p.yaw_deg,
               "gimbal_pitch_deg": p.gimbal_pitch_deg or 0.0, "gimbal_yaw_deg": p.gimbal_yaw_deg or 0.0}
        image = render.render(camera_pose(msg, frame), index=k, time_s=float(t), exposure=ae).image
        cv2.imwrite(str(frames_dir / f"{k:06d}.jpg"), image, [cv2.IMWRITE_JPEG_QUALITY, 92])
        lines.append(f"{k:06d}.jpg,{float(t)!r}\n")
    (frames_dir / "times.csv").write_text("".join(lines), encoding="utf-8")
    shutil.copyfile(telemetry, out / "telemetry.jsonl")
    print(f"rendered {len(times)} frames {cam.width}x{cam.height} of {times[0]:.2f}-{times[-1]:.2f} s into "
          f"{frames_dir} ({time.process_time() - cpu:.0f} s CPU)")


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("telemetry", type=Path, help="a flight's telemetry log (e.g. a demo's spool/telemetry.jsonl)")
    p.add_argument("--mission", type=Path, default=ROOT / "missions" / "demo-facade.yaml")
    p.add_argument("--fps", type=float, default=30.0, help="camera frame rate to replay at")
    p.add_argument("--out", type=Path, help="render the frames of [--from, --to] into this recording")
    p.add_argument("--width", type=int, default=640)
    p.add_argument("--from", dest="t0", type=float, default=None, help="first frame time (autopilot s)")
    p.add_argument("--to", dest="t1", type=float, default=None, help="last frame time (autopilot s)")
    p.add_argument("--seed", type=int, default=0, help="simulator scene seed")
    args = p.parse_args()
    mission = load_mission(args.mission)
    buf = flight_poses(args.telemetry)
    scope_replay(buf, mission, args.fps)
    if args.out is not None:
        render_frames(buf, mission, args.telemetry, args.out, fps=args.fps, width=args.width, t0=args.t0,
                      t1=args.t1, seed=args.seed)
    return 0


if __name__ == "__main__":
    sys.exit(main())

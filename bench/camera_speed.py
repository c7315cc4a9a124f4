"""Render speed of the simulated camera at several working resolutions, both renderers side by side in one run
(the per-pixel ray caster and the texture warp), and the fast recording generator.

    python bench/camera_speed.py [--mission missions/demo-facade.yaml] [--widths 640 1280 1920]
                                 [--renderers raycast warp] [--frames 20]

Poses come from the kinematic flight along the demo mission's first strip (left end of the wall: facade,
roof line and background in view), so the figures include the edge frames, not only plain wall. Prints CPU
(process) time and wall time per frame; the first frame (texture tiles generated) is reported separately, the
load average before and after, and the per-frame CPU ratio of each renderer to the first one.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import tempfile
import time
from pathlib import Path

import cv2

from companion.mission import load_mission, plan_scan
from sim.camera.recording import camera_from_mission, generate_recording
from sim.camera.render import AutoExposure
from sim.camera.scene import Scene
from sim.camera.trajectory import KinematicFlight, scan_path
from sim.camera.warp_render import RENDERERS, make_renderer


def bench_width(mission, width: int, frames: int, seed: int, renderer: str = "raycast", view: str = "edge") -> dict:
    plan = plan_scan(mission)
    cam = camera_from_mission(mission, width)
    scene = Scene.build(plan.frame.length_m, float(mission.facade.height_m), seed=seed)
    r = make_renderer(renderer, scene, plan.frame, cam, exposure_s=float(mission.camera.exposure_s), seed=seed)
    flight = KinematicFlight(plan.frame, scan_path(plan), seed=seed)
    ae = AutoExposure(seed=seed)
    fps = float(mission.camera.fps)
    stride = 10  # 1/3 s apart: the view moves ~0.25 m between benchmark frames
    start = 0.0 if view == "edge" else flight.duration_s / 2  # middle: plain wall, the bulk of a scan
    times = [start + k / fps for k in range(0, frames * stride, stride)]
    c0, w0 = time.process_time(), time.perf_counter()
    f = r.render(flight.pose(times[0]), index=0, time_s=times[0], exposure=ae)
    first_cpu, first_wall = time.process_time() - c0, time.perf_counter() - w0
    cpu, wall, jpg = [], [], []
    for i, t in enumerate(times[1:], start=1):
        pose = flight.pose(t)
        c0, w0 = time.process_time(), time.perf_counter()
        f = r.render(pose, index=i, time_s=t, exposure=ae)
        cpu.append(time.process_time() - c0)
        wall.append(time.perf_counter() - w0)
        j0 = time.perf_counter()
        cv2.imencode(".jpg", f.image, [cv2.IMWRITE_JPEG_QUALITY, 92])
        jpg.append(time.perf_counter() - j0)
    return {
        "width": cam.width, "height": cam.height, "first_cpu_s": first_cpu, "first_wall_s": first_wall,
        "cpu_s": statistics.median(cpu), "wall_s": statistics.median(wall), "jpeg_s": statistics.median(jpg),
        "frames": len(cpu),
    }


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--mission", type=Path, default=Path("missions/demo-facade.yaml"))
    p.add_argument("--widths", type=int, nargs="+", default=[640, 1280, 1920])
    p.add_argument("--renderers", nargs="+", choices=RENDERERS, default=["raycast", "warp"])
    p.add_argument("--views", nargs="+", choices=["edge", "middle"], default=["edge", "middle"],
                   help="edge: the first strip at the wall's left end (trees, far buildings, roof line); middle: "
                        "frames from the middle of the scan (plain wall)")
    p.add_argument("--frames", type=int, default=20, help="frames per width (the 3840 run uses a quarter)")
    p.add_argument("--generator-frames", type=int, default=100)
    p.add_argument("--seed", type=int, default=0)
    a = p.parse_args()
    mission = load_mission(a.mission)
    print(f"machine: {platform.platform()}, {platform.processor() or platform.machine()}, {os.cpu_count()} CPUs; "
          f"mission {a.mission}; load average {os.getloadavg()[0]:.1f}")
    print("view | renderer | width x height | first frame cpu/wall s | per frame cpu s | per frame wall s | "
          "frames/s (cpu) | jpeg s | cpu vs first renderer")
    for view in a.views:
        for w in a.widths:
            n = max(3, a.frames // 4) if w >= 2000 else a.frames
            base = None
            for kind in a.renderers:
                r = bench_width(mission, w, n + 1, a.seed, kind, view)
                base = base or r["cpu_s"]
                print(f"{view} | {kind} | {r['width']} x {r['height']} | {r['first_cpu_s']:.2f} / "
                      f"{r['first_wall_s']:.2f} | {r['cpu_s']:.3f} | {r['wall_s']:.3f} | {1 / r['cpu_s']:.1f} | "
                      f"{r['jpeg_s']:.4f} | "
                      f"{r['cpu_s'] / base:.2f}  (median of {r['frames']})", flush=True)
    print(f"load average after: {os.getloadavg()[0]:.1f}")
    with tempfile.TemporaryDirectory() as tmp:
        for kind in a.renderers:
            c0, w0 = time.process_time(), time.perf_counter()
            generate_recording(mission, Path(tmp) / kind, seed=a.seed, width_px=640, max_frames=a.generator_frames,
                               renderer=kind)
            print(f"generate_recording(width_px=640, max_frames={a.generator_frames}, renderer={kind}): "
                  f"{time.process_time() - c0:.1f} s cpu, {time.perf_counter() - w0:.1f} s wall "
                  f"(scene, sky, render, JPEG + depth + mask files)", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Keyframe gate speed: 118 frames at 3840x2160 (the paper's pass size) and sustained frames/s at 1920x1080.

Frames are synthetic wall views on a continuous serpentine path (evaluation.keyframes.synthetic), rendered
before each push; only the time inside ``gate.push``/``gate.flush`` is counted (SIFT on the working copy,
matching, RANSAC, sharpness). The paper's selection of its 118 images took 40 min 49 s (2449 s) offline on a
Xeon E5-2630 v4.

    python bench/gate_speed.py                      # both figures, default working copy (960 px long side)
    python bench/gate_speed.py --long-side 1920     # slower, more features
"""

from __future__ import annotations

import argparse
import os
import platform
import time

import cv2

from companion.keyframes import FeatureConfig, GateConfig, KeyframeGate
from evaluation.keyframes.synthetic import lawnmower, masked_frame, render, textured_wall

PAPER_SECONDS = 40 * 60 + 49


def run(n: int, width: int, height: int, long_side: int, step_frac: float, seed: int) -> dict:
    zoom = 0.5  # texture px per image px: a 4K frame shows a 1920x1080 texture patch (keeps the wall in memory)
    tex = textured_wall(7200, 3400, seed=seed)
    views = lawnmower(n, step_frac * zoom * height, width, height, tex.shape, zoom=zoom)
    gate = KeyframeGate(GateConfig(features=FeatureConfig(long_side_px=long_side)))
    per_frame = []
    cpu = 0.0
    keys = 0
    for i, v in enumerate(views):
        mf = masked_frame(i, render(tex, v))
        t0, c0 = time.perf_counter(), time.process_time()
        keys += len(gate.push(mf))
        per_frame.append(time.perf_counter() - t0)
        cpu += time.process_time() - c0
    t0 = time.perf_counter()
    keys += len(gate.flush())
    total = sum(per_frame) + time.perf_counter() - t0
    per_frame.sort()
    return {
        "frames": n,
        "size": f"{width}x{height}",
        "keyframes": keys,
        "total_s": total,
        "cpu_s": cpu,  # process CPU time (all threads): what the gate costs regardless of other load
        "fps": n / total,
        "p50_ms": 1000 * per_frame[len(per_frame) // 2],
        "max_ms": 1000 * per_frame[-1],
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--long-side", type=int, default=960, help="feature working copy long side (0 = full res)")
    ap.add_argument("--frames-4k", type=int, default=118)
    ap.add_argument("--frames-1080", type=int, default=120)
    ap.add_argument("--step", type=float, default=0.06, help="camera step per frame as a share of frame height")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    print(f"machine: {platform.platform()}, {os.cpu_count()} CPUs, OpenCV {cv2.__version__}, "
          f"cv2 threads {cv2.getNumThreads()}; working long side {args.long_side or 'full'} px; "
          f"load average at start {os.getloadavg()[0]:.1f}")
    r4k = run(args.frames_4k, 3840, 2160, args.long_side, args.step, args.seed)
    print(f"{r4k['frames']} frames {r4k['size']}: gate {r4k['total_s']:.1f} s ({r4k['fps']:.2f} frames/s, "
          f"median {r4k['p50_ms']:.0f} ms, max {r4k['max_ms']:.0f} ms per frame), {r4k['keyframes']} keyframes; "
          f"paper 40 min 49 s = {PAPER_SECONDS} s -> {PAPER_SECONDS / r4k['total_s']:.0f}x faster; "
          f"process CPU {r4k['cpu_s']:.1f} s")
    r1080 = run(args.frames_1080, 1920, 1080, args.long_side, args.step, args.seed)
    print(f"{r1080['frames']} frames {r1080['size']}: sustained {r1080['fps']:.2f} frames/s "
          f"(median {r1080['p50_ms']:.0f} ms, max {r1080['max_ms']:.0f} ms per frame), {r1080['keyframes']} keyframes; "
          f"process CPU {r1080['cpu_s']:.1f} s = {r1080['frames'] / r1080['cpu_s']:.2f} frames per CPU-second")
    print(f"load average at end {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()

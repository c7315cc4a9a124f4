"""`companion mask` with and without --sequence on the simulator's real-texture passes, side by side (issue 13).

Each pass (sim/camera/photo_passes.py: held-out real photos as wall and background, exact truth masks) is
rendered to image files in capture order, then masked by ``companion.depth.photomask.mask_photos`` exactly as the
command does, once per photo alone and once as a sequence (parallax between neighbours, no telemetry).

    python bench/mask_sequence.py                                   # 4 passes, 80 frames, 960 px, sim + real-nc
    python bench/mask_sequence.py --passes ornate-entry --frames 24 --background-frames 6 --width 640 --models sim
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import platform
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np
from checkout import use_checkout_shared_data

from companion.depth.masker import Masker
from companion.depth.photomask import mask_photos
from sim.camera.photo_passes import DEFAULT_PASSES, RECIPES, build_pass
from sim.camera.photo_scene import CameraModel, PhotoPassRenderer


def render_pass(name: str, frames: int, background_frames: int, width: int, folder: Path) -> list[np.ndarray]:
    """The pass's photos written as PNG files in capture order; their truth masks."""
    spec = build_pass(RECIPES[name], root=use_checkout_shared_data(),
                      frames=frames, background_frames=background_frames)
    spec = dataclasses.replace(spec, camera=CameraModel(width=width, height=width * 9 // 16, hfov_deg=69.0))
    renderer = PhotoPassRenderer(spec)
    truths = []
    for i in range(len(renderer)):
        frame = renderer.render(i)
        cv2.imwrite(str(folder / f"IMG_{i:04d}.png"), frame.image)
        truths.append(frame.roi_mask)
    return truths


def score(results, truths) -> str:
    """One table row's figures: error mean / p95, wall-only frames, background-only frames dropped, wall dropped."""
    errors, wall_only, background, background_dropped, wall_dropped = [], [], 0, 0, 0
    for result, truth in zip(results, truths, strict=True):
        mask = cv2.imread(str(result.mask_path), cv2.IMREAD_UNCHANGED)
        e = float(np.count_nonzero((mask > 127) != (truth > 127))) / mask.size
        errors.append(e)
        if not truth.any():
            background += 1
            background_dropped += result.no_near_surface
            continue
        wall_dropped += result.no_near_surface
        if truth.all():
            wall_only.append(e)
    wall = f"{100 * np.mean(wall_only):.1f} %" if wall_only else "-"
    return (f"{100 * np.mean(errors):.1f} % / {100 * np.percentile(errors, 95):.1f} % | {wall} | "
            f"{background_dropped} of {background} | {wall_dropped}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--passes", default=",".join(DEFAULT_PASSES))
    ap.add_argument("--models", default="sim,real-nc", help="comma list of shipped model names or .onnx paths")
    ap.add_argument("--frames", type=int, default=80)
    ap.add_argument("--background-frames", type=int, default=16)
    ap.add_argument("--width", type=int, default=960, help="photo width in px (16:9, 69 deg hfov)")
    args = ap.parse_args()
    print(f"machine: {platform.platform()}, {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.1f}")
    print(f"{args.frames} frames per pass ({args.background_frames} past the wall's end), {args.width} px wide")
    print("\n| pass | model | --sequence | error mean / p95 | wall-only frames | background-only dropped | "
          "frames with wall dropped | s |")
    print("|---|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for name in [p.strip() for p in args.passes.split(",") if p.strip()]:
            folder = Path(tmp) / name
            folder.mkdir()
            truths = render_pass(name, args.frames, args.background_frames, args.width, folder)
            for model in [m.strip() for m in args.models.split(",") if m.strip()]:
                masker = Masker(model)
                for sequence in (False, True):
                    t0 = time.perf_counter()
                    out = Path(tmp) / f"{name}-{Path(model).stem}-{sequence}"
                    results = mask_photos([folder], out, masker, sequence=sequence)
                    print(f"| {name} | {model} | {'yes' if sequence else 'no'} | {score(results, truths)} | "
                          f"{time.perf_counter() - t0:.0f} |", flush=True)


if __name__ == "__main__":
    main()

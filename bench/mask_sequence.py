"""`companion mask` with and without --sequence on the simulator's real-texture passes, side by side (issue 13).

Each pass (sim/camera/photo_passes.py: held-out real photos as wall and background, exact truth masks) is
rendered to image files in capture order, then masked by ``companion.depth.photomask.mask_photos`` exactly as the
command does, once per photo alone and once as a sequence (parallax between neighbours, no telemetry).

    python bench/mask_sequence.py                                   # 4 passes, 80 frames, 960 px, sim + real-nc
    python bench/mask_sequence.py --passes ornate-entry --frames 24 --background-frames 6 --width 640 --models sim
    python bench/mask_sequence.py --models sim --width 640 --spacing 3 --standoff 13 --rules yes,before-align
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
from companion.depth.parallax import ParallaxParams
from companion.depth.photomask import mask_photos
from sim.camera.photo_passes import DEFAULT_PASSES, RECIPES, build_pass
from sim.camera.photo_scene import CameraModel, PhotoPassRenderer

# --sequence rule sets compared side by side: the shipped rules, and the rules before issue 27 (no alignment of
# photos whose dominant motion is beyond DIS's reach)
SEQUENCE_RULES = {"yes": ParallaxParams(),
                  "before-align": ParallaxParams(sequence_align_share=None, sequence_max_share=float("inf"),
                                                 sequence_wall_depth=False, plane_far_step_px=None,
                                                 sequence_zero_prior=False, sequence_break_deg=None,
                                                 sequence_both_sides=False),
                  "no-wall-depth": ParallaxParams(sequence_wall_depth=False),
                  # the rules before issue 27's sparse-stills step (main at 59bc5c5): two far motions, a strip's first
                  # photo compared with the previous strip's last
                  "before-stills": ParallaxParams(plane_far_step_px=None, sequence_break_deg=None,
                                                  sequence_both_sides=False),
                  "no-far-step": ParallaxParams(plane_far_step_px=None),
                  "zero-prior": ParallaxParams(sequence_zero_prior=True),
                  "all-pairs-scale": ParallaxParams(sequence_scale_min_motion=None),
                  "no-break": ParallaxParams(sequence_break_deg=None),
                  "one-side": ParallaxParams(sequence_both_sides=False)}


def pass_spec(name: str, frames: int, background_frames: int, width: int, standoff_m: float = 4.0,
              spacing_m: float | None = None):
    """A held-out pass (sim/camera/photo_passes.py) or a validation pass (training photos,
    bench/depth_error_regions.py) at ``standoff_m`` with its wall scaled by standoff / 4 m (the frames look as at
    4 m; only the camera's distance, and so the metres between photos for the same image motion, change).
    ``spacing_m``: stills that far apart along each strip (``frames`` is then ignored; ``background_frames``
    past the wall's end at the same spacing)."""
    from bench.depth_error_regions import VALIDATION, validation_spec

    spec = (validation_spec(name, frames, background_frames) if name in VALIDATION
            else build_pass(RECIPES[name], root=use_checkout_shared_data(), frames=frames,
                       background_frames=background_frames))
    scale = standoff_m / spec.standoff_m
    wall = dataclasses.replace(spec.wall, width_m=spec.wall.width_m * scale)
    strips = tuple(u * scale for u in spec.strips_up_m) if spec.strips_up_m else None
    camera = CameraModel(width=width, height=width * 9 // 16, hfov_deg=69.0)
    spec = dataclasses.replace(spec, wall=wall, strips_up_m=strips, standoff_m=standoff_m, camera=camera)
    if spacing_m is not None:
        per_strip = max(1, int(np.ceil((wall.width_m + 0.05) / spacing_m)))
        spec = dataclasses.replace(spec, frames=per_strip * len(strips or (0,)) + background_frames)
    return spec


def render_pass(name: str, frames: int, background_frames: int, width: int, folder: Path,
                standoff_m: float = 4.0, spacing_m: float | None = None) -> list[np.ndarray]:
    """The pass's photos written as PNG files in capture order; their truth masks."""
    spec = pass_spec(name, frames, background_frames, width, standoff_m, spacing_m)
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
    ap.add_argument("--standoff", type=float, default=4.0,
                    help="camera distance to the wall in metres (the wall is scaled by standoff / 4 m)")
    ap.add_argument("--spacing", type=float, default=None,
                    help="stills this many metres apart along each strip (overrides --frames)")
    ap.add_argument("--rules", type=lambda t: [r for r in t.split(",") if r], default=["yes"],
                    help=f"--sequence rule sets beside the photos alone: {', '.join(SEQUENCE_RULES)}")
    args = ap.parse_args()
    print(f"machine: {platform.platform()}, {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.1f}")
    spacing = f"stills {args.spacing} m apart" if args.spacing else f"{args.frames} frames per pass"
    print(f"{spacing} ({args.background_frames} past the wall's end), {args.width} px wide, "
          f"{args.standoff} m from the wall")
    print("\n| pass | model | --sequence (rules) | error mean / p95 | wall-only frames | background-only dropped | "
          "frames with wall dropped | s |")
    print("|---|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for name in [p.strip() for p in args.passes.split(",") if p.strip()]:
            folder = Path(tmp) / name
            folder.mkdir()
            truths = render_pass(name, args.frames, args.background_frames, args.width, folder, args.standoff,
                                 args.spacing)
            for model in [m.strip() for m in args.models.split(",") if m.strip()]:
                masker = Masker(model)
                for rule in [None, *args.rules]:
                    t0 = time.perf_counter()
                    out = Path(tmp) / f"{name}-{Path(model).stem}-{rule}"
                    results = mask_photos([folder], out, masker, sequence=rule is not None,
                                          sequence_params=SEQUENCE_RULES.get(rule))
                    print(f"| {name} | {model} | {rule or 'no'} | {score(results, truths)} | "
                          f"{time.perf_counter() - t0:.0f} |", flush=True)


if __name__ == "__main__":
    main()

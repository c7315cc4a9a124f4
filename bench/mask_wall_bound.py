"""`companion mask` with telemetry (issue 27 item 2): the network alone, the --standoff rule and the mission's wall
bound from the photo's pose (exact, and with a GNSS bias), side by side on the same frames in one run.

Each pass (held-out real photos, sim/camera/photo_passes.py, or validation passes of training-split photos,
bench/depth_error_regions.py) is rendered at ``--standoff`` (the wall scaled by standoff / 4 m) and each frame is
masked once by the network; every rule then masks the same disparity. The bound is computed from the camera's true
centre moved by the bias (the vehicle's estimate), never from the truth masks. "wall cut" is the largest share of
a frame's true wall that the bound removed: it must be 0.

    python bench/mask_wall_bound.py --passes val-b0309-120,val-b0169-40 --frames 40         # choose (validation)
    python bench/mask_wall_bound.py --frames 40                                            # report (held-out)
"""

from __future__ import annotations

import argparse
import os
import platform
from dataclasses import dataclass, field

import numpy as np

from bench.mask_sequence import pass_spec
from companion.depth.masker import Masker
from companion.depth.roi import RoiParams
from companion.depth.wall_bound import CameraView, WallExtent, apply_bound, frontal_view, wall_bound
from sim.camera.photo_passes import DEFAULT_PASSES
from sim.camera.photo_scene import PhotoPassRenderer

BIASES = {"exact": (0.0, 0.0, 0.0), "bias +1.5 m": (1.5, 1.5, 0.5), "bias -1.5 m": (-1.5, 1.5, -0.5)}


@dataclass
class Tally:
    errors: list[float] = field(default_factory=list)
    background: int = 0
    background_dropped: int = 0
    wall_dropped: int = 0
    wall_cut: float = 0.0

    def add(self, mask: np.ndarray, truth: np.ndarray, cut_share: float = 0.0) -> None:
        keep, wall = mask > 127, truth > 127
        self.errors.append(float(np.count_nonzero(keep != wall)) / wall.size)
        self.wall_cut = max(self.wall_cut, cut_share)
        if not wall.any():
            self.background += 1
            self.background_dropped += int(not keep.any())
        else:
            self.wall_dropped += int(not keep.any())

    def row(self) -> str:
        e = 100 * np.array(self.errors)
        return (f"{e.mean():.1f} % / {np.percentile(e, 95):.1f} % | {self.background_dropped} of {self.background} | "
                f"{self.wall_dropped} | {100 * self.wall_cut:.2f} %")


def _view(frame, spec, bias) -> CameraView:
    cam = spec.camera
    return frontal_view(float(cam.K[0, 0]), cam.width, cam.height, frame.along_m + bias[0],
                        spec.standoff_m + bias[1], frame.up_m + bias[2])


def run_pass(name: str, args, model: str) -> dict[str, Tally]:
    spec = pass_spec(name, args.frames, args.background_frames, args.width, args.standoff, args.spacing)
    renderer = PhotoPassRenderer(spec)
    wall = WallExtent(spec.wall.width_m, spec.wall.height_m)
    base = Masker(model, threads=args.threads)
    rules = {"network": base}
    for r in args.ratios:
        rules[f"--standoff x{r:g}"] = Masker(session=base.session, params=RoiParams(pixel_depth_cut=True),
                                            max_roi_depth_m=r * spec.standoff_m)
    tallies: dict[str, Tally] = {}
    for i in range(0, len(renderer), args.every):
        frame = renderer.render(i)
        disparity = base.session.disparity(frame.image)
        masks = {}
        for rule, masker in rules.items():
            roi = masker.roi_from_disparity(disparity, frame.image.shape[:2])
            masks[rule] = roi.mask if not roi.empty else np.zeros(frame.image.shape[:2], np.uint8)
            tallies.setdefault(rule, Tally()).add(masks[rule], frame.roi_mask)
        for label, bias in BIASES.items():
            bound = wall_bound(_view(frame, spec, bias), wall)
            wall_px = frame.roi_mask > 127
            cut = 0.0 if bound is None or not wall_px.any() else float(np.mean(bound[wall_px] == 0))
            tallies.setdefault(f"network + bound, {label}", Tally()).add(apply_bound(masks["network"], bound),
                                                                         frame.roi_mask, cut)
    return tallies


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--passes", default=",".join(DEFAULT_PASSES))
    ap.add_argument("--model", default="sim")
    ap.add_argument("--frames", type=int, default=80)
    ap.add_argument("--background-frames", type=int, default=16)
    ap.add_argument("--every", type=int, default=1, help="mask every n-th frame")
    ap.add_argument("--width", type=int, default=640)
    ap.add_argument("--standoff", type=float, default=4.0)
    ap.add_argument("--spacing", type=float, default=None, help="stills this far apart (overrides --frames)")
    ap.add_argument("--ratios", type=lambda t: [float(v) for v in t.split(",")], default=[2.0, 2.5, 4.0],
                    help="--standoff rule limits to compare, in standoffs")
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args()
    print(f"machine: {platform.platform()}, {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.1f}")
    print(f"model {args.model}, standoff {args.standoff} m, {args.width} px, biases (along, out, up) m: {BIASES}")
    print("\n| pass | rule | error mean / p95 | background-only dropped | frames with wall dropped | wall cut |")
    print("|---|---|---|---|---|---|")
    for name in [p.strip() for p in args.passes.split(",") if p.strip()]:
        for rule, tally in run_pass(name, args, args.model).items():
            print(f"| {name} | {rule} | {tally.row()} |", flush=True)


if __name__ == "__main__":
    main()

"""The gate's R on a working copy against R on the camera's frame, on the same pairs around the decision.

    python bench/chain_working_size.py [--width 1280] [--sizes 960 640 480] [--keys 12]

Why: the onboard chain decides on one working copy per frame (``companion.onboard.working``, 640 px long side by
default) instead of SIFT on a 960 px copy of each full frame. The paper's rule only asks on which side of Rth a
frame's R lies, so the question is how far R moves with the working size near 80 %. A scan leg along a synthetic
wall (``WallScene``: exact poses, true overlap), 4 m standoff, at two heights: the wall's middle (whole frame wall)
and its top edge (far background above, truth ROI mask). For each key view, the frames whose true overlap with it
lies in 70-90 %. ``960`` is the gate before the change (the full frame given, SIFT on its 960 px copy); other sizes
give the gate the frame and mask resized as the chain does. Prints per size: |R - truth| and |R - R(960)| (median,
p95, max, points), pairs decided on the other side of Rth than with 960 and than truth, and CPU per measured frame
(SIFT + match + RANSAC, this process).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from companion.keyframes.features import FeatureConfig  # noqa: E402
from companion.keyframes.gate import GateConfig, KeyframeGate  # noqa: E402
from companion.keyframes.motion import WallMotionPredictor  # noqa: E402
from companion.onboard.working import WorkingCopy  # noqa: E402
from companion.records import Frame, MaskedFrame, TaggedFrame  # noqa: E402
from evaluation.keyframes.synthetic import WallCamera, WallScene, textured_wall  # noqa: E402

STANDOFF_M = 4.0


def pairs(scene: WallScene, keys: int) -> list[tuple[WallCamera, WallCamera, float]]:
    """(key view, frame, true overlap %) for frames 1/30 m apart whose true overlap is 70-90 %."""
    out = []
    for up in (5.0, 9.2):  # whole frame wall; the wall's top edge with far background above (wall 10 m high)
        for k in range(keys):
            key = WallCamera(4.0 + 0.7 * k, STANDOFF_M, up)
            for step in range(20, 50):
                cam = WallCamera(key.along_m + step / 30.0, STANDOFF_M, up)
                truth = 100.0 * scene.true_overlap(key, cam)
                if 70.0 <= truth <= 90.0:
                    out.append((key, cam, truth))
    return out


def masked(scene: WallScene, index: int, cam: WallCamera, size: int) -> MaskedFrame:
    image, mask = scene.render(cam)
    if size != 960:  # the chain's working copy: frame and mask at the working size
        work = WorkingCopy(size)
        h, w = image.shape[:2]
        s = work.scale_for(w, h)
        dims = (round(w * s), round(h * s))
        image = cv2.resize(image, dims, interpolation=cv2.INTER_AREA)
        mask = cv2.resize(mask, dims, interpolation=cv2.INTER_NEAREST)
    return MaskedFrame(TaggedFrame(Frame(index, index / 30.0, image), scene.pose(cam, index / 30.0)), mask)


def measure(scene: WallScene, todo, size: int) -> tuple[list[float | None], float, int]:
    """R of every pair with the gate at this working size, CPU seconds spent measuring, frames measured."""
    predictor = WallMotionPredictor(scene.frame, scene.hfov_deg, standoff_m=STANDOFF_M)
    features = FeatureConfig(long_side_px=960)  # the gate's default; a copy at <= 960 px is used as it is
    out, cpu, n, gate, key_cam = [], 0.0, 0, None, None
    for i, (key, cam, _) in enumerate(todo):
        if key is not key_cam:
            gate, key_cam = KeyframeGate(GateConfig(features=features), predictor), key
            gate.push(masked(scene, 10 * i, key, size))
        frame = masked(scene, 10 * i + 1, cam, size)
        c0 = time.process_time()
        est = gate.measure(frame)
        cpu += time.process_time() - c0
        n += 1
        out.append(est.R if est is not None and est.known else None)
    return out, cpu, n


def stats(values: list[float]) -> str:
    if not values:
        return "-"
    a = np.abs(np.asarray(values))
    return f"{np.median(a):.2f} / {np.percentile(a, 95):.2f} / {a.max():.2f}"


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--width", type=int, default=1280)
    p.add_argument("--sizes", type=int, nargs="+", default=[960, 640, 480])
    p.add_argument("--keys", type=int, default=12, help="key views per height")
    args = p.parse_args()
    height = round(args.width * 9 / 16)
    scene = WallScene(textured_wall(6000, 2000, seed=5), textured_wall(1600, 600, seed=9), 16.0, 10.0,
                      width_px=args.width, height_px=height)  # fmt: skip
    todo = pairs(scene, args.keys)
    truth = [t for _, _, t in todo]
    print(f"{len(todo)} pairs, frames {args.width}x{height}, true overlap 70-90 %")
    ref = None
    rows = []
    for size in args.sizes:
        r, cpu, n = measure(scene, todo, size)
        if size == 960:
            ref = r
        ok = [(x, t, i) for i, (x, t) in enumerate(zip(r, truth, strict=True)) if x is not None]
        err = [x - t for x, t, _ in ok]
        vs_ref = [x - ref[i] for x, _, i in ok if ref is not None and ref[i] is not None]
        side_truth = sum((x >= 80.0) != (t >= 80.0) for x, t, _ in ok)
        side_ref = sum((x >= 80.0) != (ref[i] >= 80.0) for x, _, i in ok if ref is not None and ref[i] is not None)
        rows.append((size, len(ok), stats(err), stats(vs_ref) if size != 960 else "-", side_truth,
                     side_ref if size != 960 else "-", 1000.0 * cpu / max(1, n)))
    print("| working size | pairs measured | abs(R - truth) median / p95 / max | abs(R - R(960)) median / p95 / max "
          "| other side of 80 % than truth | than 960 | CPU ms per measured frame |")
    print("|---|---|---|---|---|---|---|")
    for size, n, e, v, st, sr, ms in rows:
        label = "960 (before: full frame, SIFT on its 960 px copy)" if size == 960 else f"{size} (working copy)"
        print(f"| {label} | {n} | {e} pts | {v} pts | {st} | {sr} | {ms:.0f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())

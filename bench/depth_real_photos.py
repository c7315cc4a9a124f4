"""Depth-mask figures on HELD-OUT real photos only (the fixed split of companion.depth.training.realdata),
models side by side.

Usage: python bench/depth_real_photos.py [--model A.onnx B.onnx ...] [--data ../shared/data] [--composites 200]
       [--json OUT]

Per model, with the shipped ROI extraction (companion/depth/roi.py, default parameters, 15 m drop rule):
1. labelled facade photos (CMP, LabelMeFacade; held-out split): per-photo pixel error of the mask against the
   facade labels (wall, windows, doors, balconies, ... = facade), mean / p95, the share of facade pixels cut
   ("facade lost") and of background pixels kept. Caveat: a label's "background" is not always far (CMP's
   background includes neighbouring buildings and the street; LabelMe's includes cars and pavement), so part of
   that error is the photo, not the model;
2. held-out composites: a held-out facade photo warped onto a wall plane at 3-8 m before a held-out background
   photo at 20-500 m (companion.depth.training.composite, seeded; exact truth masks), 640x360 frames: mask
   error mean / p95, error on wall-only frames, background-only frames dropped;
3. the two DJI drone photos of a plain wall (real-uav-facade): share of the frame kept (the wall is the left
   80 %, the right edge a window reflecting the background);
4. held-out LabelMeFacade background photos (street scenes with >= 30 % sky and trees): share of the frame kept,
   share of their sky and vegetation kept, and frames dropped as all-background;
5. the Strecha fountain-P11 / entry-P10 views (a real wall filling most of the frame, no labels): share kept.
No photo of the training split is read.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

import cv2
import numpy as np
from checkout import use_checkout_shared_data

from companion.depth.masker import Masker
from companion.depth.roi import pixel_error_ratio
from companion.depth.session import DEFAULT_MODEL
from companion.depth.training.realdata import facade_mask, list_real_photos, load_image
from companion.records import Frame, TaggedFrame

_SKY_VEG_RGB = ((0, 128, 128), (0, 128, 0))


def _mask(masker: Masker, image: np.ndarray, n: int):
    return masker.mask(TaggedFrame(Frame(n, 0.0, image), pose=None))[1]


def _pct(values) -> str:
    v = np.asarray(values, dtype=float)
    return f"{100 * v.mean():.1f} % / {100 * np.percentile(v, 95):.1f} %" if len(v) else "n/a"


def labelled_photos(masker: Masker, photos) -> dict:
    out = {}
    for source in ("cmp", "labelmefacade"):
        errs, lost, kept_bg = [], [], []
        for n, photo in enumerate(p for p in photos if p.source == source):
            truth = facade_mask(photo) > 0
            roi = _mask(masker, load_image(photo), n)
            mask = roi.mask > 127
            errs.append(pixel_error_ratio(roi.mask, truth.astype(np.uint8) * 255))
            lost.append(np.count_nonzero(truth & ~mask) / max(1, np.count_nonzero(truth)))
            if (~truth).any():
                kept_bg.append(np.count_nonzero(~truth & mask) / np.count_nonzero(~truth))
        out[source] = {"photos": len(errs), "error_mean": float(np.mean(errs)),
                       "error_p95": float(np.percentile(errs, 95)), "facade_lost_mean": float(np.mean(lost)),
                       "background_kept_mean": float(np.mean(kept_bg)) if kept_bg else float("nan")}
        print(f"  held-out {source} photos ({len(errs)}): mask error mean / p95 {_pct(errs)}, facade lost "
              f"{100 * np.mean(lost):.1f} %, background kept {100 * np.mean(kept_bg):.1f} %")
    return out


def composites(masker: Masker, bank, n: int, seed: int) -> dict:
    from companion.depth.training.composite import compose

    rng = np.random.default_rng(seed)
    errs, wall_only, bg_dropped, bg_total, wrongly_dropped = [], [], 0, 0, 0
    for i in range(n):
        c = compose(bank, rng, 360, 640, 100.0, square_pixels=True)
        roi = _mask(masker, c.image, i)
        e = pixel_error_ratio(roi.mask, c.facade)
        errs.append(e)
        share = np.count_nonzero(c.facade) / c.facade.size
        if share == 1.0:
            wall_only.append(e)
        if share == 0.0:
            bg_total += 1
            bg_dropped += int(roi.empty)
        elif roi.empty:
            wrongly_dropped += 1
    print(f"  held-out composites ({n}, seed {seed}): mask error mean / p95 {_pct(errs)}, wall-only frames "
          f"({len(wall_only)}) {_pct(wall_only)}, background-only frames dropped {bg_dropped} of {bg_total}, "
          f"frames with wall dropped {wrongly_dropped}")
    return {"frames": n, "error_mean": float(np.mean(errs)), "error_p95": float(np.percentile(errs, 95)),
            "wall_only_frames": len(wall_only),
            "wall_only_error_mean": float(np.mean(wall_only)) if wall_only else None,
            "background_only_frames": bg_total, "background_only_dropped": bg_dropped,
            "wall_frames_dropped": wrongly_dropped}


def dji_photos(masker: Masker, photos) -> dict:
    out = {}
    for n, photo in enumerate(p for p in photos if p.source == "dji"):
        roi = _mask(masker, load_image(photo), n)
        wall = roi.mask[:, : int(0.8 * roi.mask.shape[1])]
        out[photo.image.name] = {"frame_kept": roi.roi_fraction, "wall_kept": np.count_nonzero(wall) / wall.size,
                                 "dropped": roi.empty}
        print(f"  DJI {photo.image.name}: kept {100 * roi.roi_fraction:.1f} % of the frame, "
              f"{100 * np.count_nonzero(wall) / wall.size:.1f} % of the plain wall (left 80 %), dropped={roi.empty}")
    return out


def background_photos(masker: Masker, photos) -> dict:
    kept, kept_far, dropped = [], [], 0
    bgs = [p for p in photos if p.source == "labelmefacade-bg"]
    for n, photo in enumerate(bgs):
        roi = _mask(masker, load_image(photo), n)
        label = cv2.imread(str(photo.label), cv2.IMREAD_COLOR)[..., ::-1]
        far = np.zeros(label.shape[:2], bool)
        for colour in _SKY_VEG_RGB:
            far |= np.all(label == np.array(colour, np.uint8), axis=-1)
        kept.append(roi.roi_fraction)
        kept_far.append(np.count_nonzero(far & (roi.mask > 127)) / max(1, np.count_nonzero(far)))
        dropped += int(roi.empty)
    print(f"  held-out background photos ({len(bgs)}): frame kept mean {100 * np.mean(kept):.1f} %, sky+vegetation "
          f"kept mean {100 * np.mean(kept_far):.1f} %, dropped as all-background {dropped}")
    return {"photos": len(bgs), "frame_kept_mean": float(np.mean(kept)),
            "sky_vegetation_kept_mean": float(np.mean(kept_far)), "dropped": dropped}


def strecha_photos(masker: Masker, photos) -> dict:
    kept = [_mask(masker, load_image(p), n).roi_fraction for n, p in enumerate(x for x in photos
                                                                              if x.source == "strecha")]
    print(f"  Strecha fountain/entry views ({len(kept)}): frame kept mean {100 * np.mean(kept):.1f} %, "
          f"min {100 * np.min(kept):.1f} %")
    return {"photos": len(kept), "frame_kept_mean": float(np.mean(kept)), "frame_kept_min": float(np.min(kept))}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", nargs="+", default=[str(DEFAULT_MODEL)])
    ap.add_argument("--data", default=str(use_checkout_shared_data()), help="the shared data folder")
    ap.add_argument("--composites", type=int, default=200, help="held-out composite frames per model")
    ap.add_argument("--seed", type=int, default=5)
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    from companion.depth.training.composite import load_photo_bank

    photos = list_real_photos(Path(args.data), split="heldout")
    assert all(p.split == "heldout" for p in photos)
    bank = load_photo_bank(Path(args.data), split="heldout")
    results = []
    for model in args.model:
        t0 = time.perf_counter()
        masker = Masker(model)
        print(f"--- model {model}")
        row = {"model": model, "labelled": labelled_photos(masker, photos),
               "composites": composites(masker, bank, args.composites, args.seed),
               "dji": dji_photos(masker, photos), "backgrounds": background_photos(masker, photos),
               "strecha": strecha_photos(masker, photos)}
        row["seconds"] = time.perf_counter() - t0
        results.append(row)
    print(f"machine: {platform.machine()} cores={os.cpu_count()}")
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()

"""Overlap ratio on the two real UAV facade photos (plain grey cladding, low texture), with and without CLAHE.

    python bench/gate_real_photos.py [--dir /work/shared/data/real-uav-facade]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import cv2

from companion.errors import CompanionError
from companion.keyframes import FeatureConfig, FeatureExtractor, OverlapConfig, OverlapEstimator


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dir", default="/work/shared/data/real-uav-facade")
    ap.add_argument("--long-side", type=int, default=960)
    args = ap.parse_args()
    paths = [Path(args.dir) / n for n in ("DJI_0977_rgb.JPG", "DJI_0981_rgb.JPG")]
    imgs = [cv2.imread(str(p)) for p in paths]
    if any(i is None for i in imgs):
        raise CompanionError(f"cannot read the photos in {args.dir}", "pass --dir with DJI_0977/0981_rgb.JPG")
    print(f"{paths[0].name} vs {paths[1].name}: {imgs[0].shape[1]}x{imgs[0].shape[0]}, whole frame as ROI")
    for eq in (False, True):
        ex = FeatureExtractor(FeatureConfig(long_side_px=args.long_side, equalize=eq))
        t0 = time.perf_counter()
        fa, fb = ex.extract(imgs[0]), ex.extract(imgs[1])
        for method in ("displacement", "polygon"):
            e = OverlapEstimator(OverlapConfig(method=method)).estimate(fa, fb)
            r = f"R {e.R:.2f} %, dx {e.dx:+.1f} dy {e.dy:+.1f} px" if e.known else f"unknown ({e.status})"
            print(f"CLAHE {'on ' if eq else 'off'} {method:12s}: features {len(fa)}/{len(fb)}, matches {e.matches}, "
                  f"inliers {e.inliers}: {r}")
        print(f"  extraction of both + matching: {time.perf_counter() - t0:.2f} s")


if __name__ == "__main__":
    main()

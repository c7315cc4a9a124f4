"""How the two overlap estimators differ: Eq. 2 (mean displacement) vs the homography polygon, against truth.

Synthetic wall views (evaluation.keyframes.synthetic) with known translation, rotation and zoom (standoff
change); prints R from both estimators on the same RANSAC inliers and the true footprint overlap.

    python bench/gate_estimators.py
"""

from __future__ import annotations

import argparse

from companion.keyframes import FeatureConfig, FeatureExtractor, OverlapEstimator
from evaluation.keyframes.synthetic import View, render, textured_wall, true_overlap

CASES = [  # (dx, dy, angle_deg, zoom) of Iq relative to Ip, dx/dy in texture px
    (0, 0, 0, 1.0),
    (96, 0, 0, 1.0),
    (0, 54, 0, 1.0),
    (150, 60, 0, 1.0),
    (96, 0, 3, 1.0),
    (96, 0, 10, 1.0),
    (96, 0, 20, 1.0),
    (96, 0, 0, 1.1),
    (96, 0, 0, 0.9),
    (96, 0, 0, 1.25),
    (96, 30, 10, 1.1),
]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--width", type=int, default=960)
    ap.add_argument("--height", type=int, default=540)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    w, h = args.width, args.height
    tex = textured_wall(3 * w, 3 * h, seed=args.seed)
    ex, est = FeatureExtractor(FeatureConfig(long_side_px=max(w, h))), OverlapEstimator()
    p = View(1.2 * w, 1.5 * h, w, h)
    fp = ex.extract(render(tex, p))
    print(f"{w}x{h} frames; errors in percentage points (estimate - truth)")
    head = ("dx", "dy", "rot", "zoom", "|", "truth", "|", "Eq.2", "err", "|", "poly", "err")
    print("{:>5} {:>4} {:>4} {:>5} {} {:>6} {} {:>6} {:>6} {} {:>6} {:>6}".format(*head))
    for dx, dy, ang, zoom in CASES:
        q = View(p.cx + dx, p.cy + dy, w, h, angle_deg=ang, zoom=zoom)
        e = est.estimate(fp, ex.extract(render(tex, q)))
        t = 100 * true_overlap(p, q)
        if not e.known:
            print(f"{dx:>5} {dy:>4} {ang:>4} {zoom:>5} | {t:6.2f} | unknown ({e.status})")
            continue
        print(f"{dx:>5} {dy:>4} {ang:>4} {zoom:>5} | {t:6.2f} | {e.R_displacement:6.2f} {e.R_displacement - t:+6.2f}"
              f" | {e.R_polygon:6.2f} {e.R_polygon - t:+6.2f}")


if __name__ == "__main__":
    main()

"""What one measured frame costs in the keyframe gate, stage by stage, old and new ways side by side (issue 17).

Pairs of real-camera-sized frames (a folder of images, e.g. a recorded 640x360 pass): every ``--step``-th frame is a
reference Ip, the next ``--span`` frames are compared with it, as the gate compares candidates with its keyframe.
Printed per variant: process CPU ms per call, ratio-test matches, and R (paper Eq. 2, plain RANSAC homography) with
its difference from the reference variant (FLANN built per pair, 64 checks: the gate before this change).
Whole frames, no ROI mask, no telemetry prior: this isolates the measurement's own cost and agreement.

    python bench/gate_cost.py /tmp/masktrain/sub900 --pairs-from 0:300 --step 10 --span 10
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import cv2
import numpy as np

from companion.keyframes.features import FeatureConfig, FeatureExtractor
from companion.keyframes.overlap import eq2_overlap
from companion.matching import DescriptorIndex, MatcherSettings, Matches, match_descriptors
from companion.ransac import ransac_homography


def _cpu_ms(fn, *args):
    t = time.process_time()
    out = fn(*args)
    return out, 1000.0 * (time.process_time() - t)


def _r(p, q, src_i, dst_i):
    if len(src_i) < 12:
        return None
    src, dst = p.points[src_i], q.points[dst_i]
    H, inl = ransac_homography(src, dst, method=cv2.RANSAC, threshold_px=3.0, max_iters=2000, confidence=0.995)
    if H is None or inl.sum() < 12:
        return None
    d = (dst[inl] - src[inl]).mean(axis=0) / p.scale
    w, h = p.full_size
    return eq2_overlap(float(d[0]), float(d[1]), w, h)


def _features_by_size(images: list, long_sides: list[int]) -> dict[int, list]:
    """SIFT working sizes: each one's features for every frame, its cost per frame printed."""
    feats: dict[int, list] = {}
    for ls in long_sides:
        ext = FeatureExtractor(FeatureConfig(long_side_px=ls))
        t = time.process_time()
        feats[ls] = [ext.extract(im) for im in images]
        ms = 1000.0 * (time.process_time() - t) / len(images)
        print(f"SIFT long side {ls:4d}: {ms:6.1f} ms/frame, {np.mean([len(f) for f in feats[ls]]):.0f} features")
    return feats


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("folder", type=Path)
    ap.add_argument("--pairs-from", default="0:300", help="first:last frame (sorted file order) to use")
    ap.add_argument("--step", type=int, default=10, help="a reference every n frames")
    ap.add_argument("--span", type=int, default=10, help="frames compared with each reference")
    ap.add_argument("--long-sides", default="960,480,320", help="SIFT working sizes to time (long side, px)")
    args = ap.parse_args()
    files = sorted(args.folder.glob("*.jpg")) + sorted(args.folder.glob("*.png"))
    a, b = (int(x) for x in args.pairs_from.split(":"))
    files = files[a:b]
    if len(files) < args.span + 1:
        raise SystemExit(f"{args.folder}: fewer than {args.span + 1} images in {args.pairs_from}")
    images = [cv2.imread(str(f), cv2.IMREAD_GRAYSCALE) for f in files]
    print(f"{len(images)} frames {images[0].shape[1]}x{images[0].shape[0]} from {args.folder}, "
          f"reference every {args.step}, {args.span} candidates each; CPU ms per call (process time)")

    feats = _features_by_size(images, [int(x) for x in args.long_sides.split(",")])

    pairs = [(i, j) for i in range(0, len(images) - 1, args.step)
             for j in range(i + 1, min(len(images), i + 1 + args.span))]
    default = int(args.long_sides.split(",")[0])
    F = feats[default]

    def per_pair_flann(p, q, checks):
        found = match_descriptors(p.descriptors, q.descriptors, MatcherSettings(checks=checks))  # q's trees, built
        return found.query, found.indexed  # src index into p, dst index into q

    def p_to_q(found: Matches):
        return found.indexed, found.query  # q queried p's index: src index into p, dst index into q

    variants = {
        "FLANN per pair, 64 checks (before)": lambda p, q, c: per_pair_flann(p, q, 64),
        "FLANN per pair, 32 checks": lambda p, q, c: per_pair_flann(p, q, 32),
        "keyframe index reused, 64 checks": lambda p, q, c: p_to_q(c(p, 64).match(q.descriptors)),
        "keyframe index reused, 32 checks (after)": lambda p, q, c: p_to_q(c(p, 32).match(q.descriptors)),
        "keyframe index reused, 16 checks": lambda p, q, c: p_to_q(c(p, 16).match(q.descriptors)),
    }
    ref_R: dict[tuple[int, int], float | None] = {}
    for name, fn in variants.items():
        cache: dict[tuple[int, int], DescriptorIndex] = {}

        def index(p, checks, cache=cache):
            key = (id(p), checks)
            if key not in cache:
                cache.clear()
                cache[key] = DescriptorIndex(p.descriptors, MatcherSettings(checks=checks))
            return cache[key]

        cpu = 0.0
        counts, diffs = [], []
        for i, j in pairs:
            (si, di), ms = _cpu_ms(fn, F[i], F[j], index)
            cpu += ms
            counts.append(len(si))
            r = _r(F[i], F[j], si, di)
            if name.endswith("(before)"):
                ref_R[(i, j)] = r
            elif r is not None and ref_R.get((i, j)) is not None:
                diffs.append(abs(r - ref_R[(i, j)]))
        d = f"|R - before| median {np.median(diffs):.3f} max {np.max(diffs):.3f} pts" if diffs else ""
        print(f"{name:42s}: {cpu / len(pairs):6.1f} ms/pair, matches mean {np.mean(counts):6.1f} {d}")

    # Working size: R against the default working size's R (same matcher: the reused index, 32 checks).
    for ls, fs in feats.items():
        diffs = []
        for i, j in pairs:
            r0 = ref_R.get((i, j))
            si, di = p_to_q(DescriptorIndex(fs[i].descriptors, MatcherSettings(checks=32)).match(fs[j].descriptors))
            r = _r(fs[i], fs[j], si, di)
            if r is not None and r0 is not None:
                diffs.append(abs(r - r0))
        print(f"long side {ls:4d} (reused index, 32 checks) vs before: |R diff| median {np.median(diffs):.3f} "
              f"p95 {np.percentile(diffs, 95):.3f} max {np.max(diffs):.3f} pts over {len(diffs)} pairs")


if __name__ == "__main__":
    main()

"""The keyframe gate's matching per candidate, this checkout beside another (``--compare-with``, e.g. main): CPU
time and the matches, inliers and R each finds on the same pairs.

Frames of a folder (e.g. a recorded 640x360 pass, the chain's working size): every ``--step``-th frame is a
keyframe Ip, the next ``--span`` frames are candidates compared with it, as the gate compares them. Each checkout
runs in its own process (its own ``companion`` on sys.path), alternately, ``--rounds`` times. Printed per run:
process CPU ms per candidate of the gate's ``OverlapEstimator.estimate`` (keyframe index built once per keyframe,
ratio-tested matches, RANSAC, R) and of its matching alone (the keyframe's index build over its candidates, and each
candidate's query); then whether both checkouts found the same matches, inliers and R on every pair. Whole frames,
no ROI mask, no telemetry prior, the gate's default settings.

On a loaded machine CPU time drifts between processes; ``--interleaved`` also times the two checkouts' matching in
one process, keyframe by keyframe in turn (the other checkout's ``companion/matching.py`` loaded from its file:
main's ``DescriptorIndex(descriptors, kind, checks).ratio_test`` before this branch),
``--repeat`` times, so the ratio of the two is measured under the same load; ``--stitch-features`` (a stitch run's
``cache/features``) does the same for the stitcher's pair matching on its keyframes' descriptors.

    python bench/matching_speed.py /tmp/masktrain/sub900 --compare-with /tmp/main --frames 0:200 --rounds 2
    python bench/matching_speed.py /tmp/masktrain/sub900 --compare-with /tmp/main --interleaved --repeat 5 \
        --stitch-features /tmp/stitch_speed/warp/cache/features
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parents[1]


def _run_child(args: argparse.Namespace) -> None:
    """Times this process's ``companion`` (the checkout first on sys.path) and prints one JSON line."""
    import cv2

    from companion.keyframes import FeatureExtractor, OverlapEstimator
    from companion.matching import DescriptorIndex

    files = sorted(args.folder.glob("*.jpg")) + sorted(args.folder.glob("*.png"))
    a, b = (int(x) for x in args.frames.split(":"))
    ex = FeatureExtractor()
    feats = [ex.extract(cv2.imread(str(f), cv2.IMREAD_GRAYSCALE)) for f in files[a:b]]
    pairs = [(i, j) for i in range(0, len(feats) - 1, args.step)
             for j in range(i + 1, min(len(feats), i + 1 + args.span))]
    est = OverlapEstimator()
    cv2.setRNGSeed(0)
    results, t_estimate = [], 0.0
    for i, j in pairs:
        t = time.process_time()
        e = est.estimate(feats[i], feats[j])
        t_estimate += time.process_time() - t
        results.append([i, j, e.matches, e.inliers, None if e.R is None else round(e.R, 6)])
    settings = est.config.matching if hasattr(est.config, "matching") else None  # this branch: named settings
    t_match = 0.0
    for i in sorted({i for i, _ in pairs}):
        t = time.process_time()
        index = (DescriptorIndex(feats[i].descriptors, settings) if settings is not None
                 else DescriptorIndex(feats[i].descriptors, "flann", est.config.flann_checks))
        for _, j in (p for p in pairs if p[0] == i):
            if settings is not None:
                index.match(feats[j].descriptors)
            else:
                index.ratio_test(feats[j].descriptors, est.config.ratio_test)
        t_match += time.process_time() - t
    print(json.dumps({
        "candidates": len(pairs),
        "estimate_ms": 1000.0 * t_estimate / len(pairs),
        "match_ms": 1000.0 * t_match / len(pairs),
        "features_mean": float(np.mean([len(f) for f in feats])),
        "results": results,
    }))


def _other_matching(checkout: Path):
    """The other checkout's ``companion/matching.py``, loaded from its file beside this checkout's."""
    spec = importlib.util.spec_from_file_location("other_matching", checkout / "companion" / "matching.py")
    other = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(other)
    return other


def _in_turn(groups: list, ours, theirs, repeat: int) -> tuple[float, float, int, int, int]:
    """CPU seconds of ``ours`` and ``theirs`` over every (indexed frame, query frames) group, called in turn (the
    first of the two alternating), and how many of the matchings agree exactly."""
    cpu = {"this": 0.0, "other": 0.0}
    same = total = 0
    for r in range(repeat):
        for k, (i, js) in enumerate(groups):
            order = (("this", ours), ("other", theirs)) if (r + k) % 2 == 0 else (("other", theirs), ("this", ours))
            got = {}
            for name, fn in order:
                t = time.process_time()
                got[name] = fn(i, js)
                cpu[name] += time.process_time() - t
            for (q1, t1), (q2, t2) in zip(got["this"], got["other"], strict=True):
                same += int(np.array_equal(q1, q2) and np.array_equal(t1, t2))
                total += 1
    return cpu["this"], cpu["other"], same, total, repeat * sum(len(js) for _, js in groups)


def _print_in_turn(what: str, timed: tuple[float, float, int, int, int]) -> None:
    this, other, same, total, n = timed
    print(f"{what}, in turn in one process, {n} matchings each: this {1000 * this / n:.2f} ms, other "
          f"{1000 * other / n:.2f} ms CPU per matching (this/other {this / other:.3f}); same matches on {same} of "
          f"{total}")


def _interleaved(args: argparse.Namespace) -> None:
    """The gate's matching of this checkout and the other's, keyframe by keyframe in turn (same load)."""
    import cv2

    from companion.keyframes import FeatureExtractor, OverlapConfig
    from companion.matching import DescriptorIndex

    other = _other_matching(args.compare_with)
    files = sorted(args.folder.glob("*.jpg")) + sorted(args.folder.glob("*.png"))
    a, b = (int(x) for x in args.frames.split(":"))
    feats = [FeatureExtractor().extract(cv2.imread(str(f), cv2.IMREAD_GRAYSCALE)) for f in files[a:b]]
    settings = OverlapConfig().matching
    groups = [(i, list(range(i + 1, min(len(feats), i + 1 + args.span)))) for i in range(0, len(feats) - 1, args.step)]

    def ours(i, js):
        cv2.setRNGSeed(i)
        index = DescriptorIndex(feats[i].descriptors, settings)
        return [(m.query, m.indexed) for m in (index.match(feats[j].descriptors) for j in js)]

    def theirs(i, js):
        cv2.setRNGSeed(i)
        index = other.DescriptorIndex(feats[i].descriptors, settings.kind, settings.checks)
        return [index.ratio_test(feats[j].descriptors, settings.ratio) for j in js]

    _print_in_turn(f"gate, a keyframe's index queried by its candidates ({settings})",
                   _in_turn(groups, ours, theirs, args.repeat))


def _interleaved_stitch(args: argparse.Namespace) -> None:
    """The stitcher's pair matching of this checkout and the other's on a stitch run's cached features: keyframe
    j's index (seeded by j, as ``stitch.pairs.keyframe_index``) queried by keyframes j-2 and j-1."""
    from companion.matching import DescriptorIndex
    from companion.stitch.config import STITCH_MATCHING

    other = _other_matching(args.compare_with)
    desc = [np.load(p)["desc"] for p in sorted(args.stitch_features.glob("kf*.npz"))]
    groups = [(j, [i for i in (j - 2, j - 1) if i >= 0]) for j in range(1, len(desc))]

    def ours(j, is_):
        index = DescriptorIndex(desc[j], STITCH_MATCHING, seed=7919 * j + 17)
        return [(m.query, m.indexed) for m in (index.match(desc[i]) for i in is_)]

    def theirs(j, is_):
        import cv2

        cv2.setRNGSeed(7919 * j + 17)
        index = other.DescriptorIndex(desc[j], checks=STITCH_MATCHING.checks)
        return [index.ratio_test(desc[i], STITCH_MATCHING.ratio) for i in is_]

    print(f"stitcher features: {len(desc)} keyframes from {args.stitch_features}, "
          f"{np.mean([len(d) for d in desc]):.0f} descriptors each")
    _print_in_turn(f"stitcher, keyframe j's index queried by j-2 and j-1 ({STITCH_MATCHING})",
                   _in_turn(groups, ours, theirs, args.repeat))


def _child(checkout: Path, args: argparse.Namespace) -> dict:
    cmd = [sys.executable, str(Path(__file__).resolve()), str(args.folder), "--child", "--frames", args.frames,
           "--step", str(args.step), "--span", str(args.span)]
    env = dict(os.environ, PYTHONPATH=str(checkout))
    out = subprocess.run(cmd, env=env, cwd=checkout, capture_output=True, text=True, check=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("folder", type=Path)
    ap.add_argument("--frames", default="0:200", help="first:last frame (sorted file order) to use")
    ap.add_argument("--step", type=int, default=10, help="a keyframe every n frames")
    ap.add_argument("--span", type=int, default=8, help="candidates compared with each keyframe")
    ap.add_argument("--compare-with", type=Path, default=None, help="another checkout, run alternately with this")
    ap.add_argument("--rounds", type=int, default=1)
    ap.add_argument("--interleaved", action="store_true", help="with --compare-with: time both in this process")
    ap.add_argument("--repeat", type=int, default=3, help="with --interleaved: passes over the keyframes")
    ap.add_argument("--stitch-features", type=Path, default=None,
                    help="with --interleaved: also the stitcher's pairs on a stitch run's cache/features folder")
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        _run_child(args)
        return
    if args.interleaved:
        if args.compare_with is None:
            raise SystemExit("--interleaved needs --compare-with CHECKOUT")
        _interleaved(args)
        if args.stitch_features is not None:
            _interleaved_stitch(args)
        return
    runs = [("this", HERE)] + ([("other", args.compare_with.resolve())] if args.compare_with else [])
    seen: dict[str, list] = {}
    for r in range(args.rounds):
        for name, checkout in runs if r % 2 == 0 else runs[::-1]:
            load = os.getloadavg()[0]
            res = _child(checkout, args)
            seen.setdefault(name, res["results"])
            print(f"round {r} {name:5s} ({checkout}): {res['candidates']} candidates, {res['features_mean']:.0f} "
                  f"features/frame; CPU per candidate: estimate {res['estimate_ms']:.1f} ms, matching "
                  f"{res['match_ms']:.1f} ms (load {load:.1f})")
    if len(seen) == 2:
        a, b = seen["this"], seen["other"]
        same = sum(x == y for x, y in zip(a, b, strict=True))
        print(f"same matches, inliers and R on {same} of {len(a)} pairs")
        for x, y in zip(a, b, strict=True):
            if x != y:
                print(f"  differs: this {x} other {y}")


if __name__ == "__main__":
    main()

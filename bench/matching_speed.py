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
``--repeat`` times, so the ratio of the two is measured under the same load.

    python bench/matching_speed.py /tmp/masktrain/sub900 --compare-with /tmp/main --frames 0:200 --rounds 2
    python bench/matching_speed.py /tmp/masktrain/sub900 --compare-with /tmp/main --interleaved --repeat 5
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


def _interleaved(args: argparse.Namespace) -> None:
    """This checkout's matching and the other's, keyframe by keyframe in turn in this process (same load)."""
    import cv2

    from companion.keyframes import FeatureExtractor, OverlapConfig
    from companion.matching import DescriptorIndex

    spec = importlib.util.spec_from_file_location("other_matching", args.compare_with / "companion" / "matching.py")
    other = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(other)
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

    cpu = {"this": 0.0, "other": 0.0}
    same = total = 0
    for r in range(args.repeat):
        for i, js in groups:
            order = (("this", ours), ("other", theirs)) if (r + i) % 2 == 0 else (("other", theirs), ("this", ours))
            got = {}
            for name, fn in order:
                t = time.process_time()
                got[name] = fn(i, js)
                cpu[name] += time.process_time() - t
            for (q1, t1), (q2, t2) in zip(got["this"], got["other"], strict=True):
                same += int(np.array_equal(q1, q2) and np.array_equal(t1, t2))
                total += 1
    n = args.repeat * sum(len(js) for _, js in groups)
    print(f"interleaved in one process ({n} candidate matchings each, index built once per keyframe, gate settings "
          f"{settings}): this {1000 * cpu['this'] / n:.2f} ms, other {1000 * cpu['other'] / n:.2f} ms CPU per "
          f"candidate (this/other {cpu['this'] / cpu['other']:.3f}); same matches on {same} of {total}")


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
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        _run_child(args)
        return
    if args.interleaved:
        if args.compare_with is None:
            raise SystemExit("--interleaved needs --compare-with CHECKOUT")
        _interleaved(args)
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

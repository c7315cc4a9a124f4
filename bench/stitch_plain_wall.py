"""Stitching a plain wall from images alone: plain SIFT (the stitcher before) against the gate's extraction
(CLAHE + SIFT contrast threshold 0.01, now shared), side by side in one run.

The wall is real: the plain grey cladding of a real UAV photo (`real-uav-facade`, DJI Mavic 2 Enterprise Dual,
left 80 % of the frame below the on-screen date, i.e. without the window) is the wall texture of a synthetic
pass (evaluation.stitch.synthetic: pinhole views of the texture at its own resolution, a far background beyond
the wall's ends, exact poses), so every keyframe shows real plain-wall texture. Printed per setting: keyframes
connected by image-only alignment (`--no-poses`), pairs registered, features per keyframe, time; with
`--poses` also the same with telemetry. Then the two real photos themselves (two views of the same wall)
registered as one stitcher pair.

    python bench/stitch_plain_wall.py [--photo PATH] [--out /tmp/stitch_plain_wall] [--cost-recording /tmp/rec4k]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np

from companion.errors import CompanionError
from companion.keyframes.features import FeatureConfig
from companion.spool.layout import MANIFEST
from companion.stitch import StitchConfig, load_input, stitch
from companion.stitch.config import STITCH_FEATURES
from companion.stitch.features import detect
from companion.stitch.pairs import PairSettings, match_pair
from evaluation.stitch.synthetic import make_spool, wall_for_texture

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data" / "real-uav-facade"
SETTINGS = {
    "plain SIFT (before)": replace(STITCH_FEATURES, contrast_threshold=0.04, equalize=False),
    "CLAHE + contrast 0.01 (gate's, now)": STITCH_FEATURES,
}


def plain_wall_texture(photo: Path, band_m: float | None, mm_per_px: float) -> np.ndarray:
    """The photo's plain-wall part: left 80 % (the right edge is a window), rows below the date overlay."""
    img = cv2.imread(str(photo), cv2.IMREAD_COLOR)
    if img is None:
        raise CompanionError(f"cannot read {photo}", "pass --photo with a real-uav-facade photo")
    h, w = img.shape[:2]
    wall = img[int(0.08 * h) :, : int(0.8 * w)]
    if band_m:
        rows = min(wall.shape[0], round(band_m * 1000 / mm_per_px))
        top = (wall.shape[0] - rows) // 2
        wall = wall[top : top + rows]
    return np.ascontiguousarray(wall)


def run_pass(spool: Path, out: Path, settings: FeatureConfig, use_poses: bool) -> dict:
    t0 = time.perf_counter()
    res = stitch(load_input(spool), out, StitchConfig(use_poses=use_poses, features=settings), progress=False)
    rep = res.report
    feats = [len(np.load(p)["kp"]) for p in sorted((out / "cache" / "features").glob("*.npz"))]
    return {
        "keyframes_connected": len(rep["keyframes_used"]),
        "keyframes": rep["keyframes_in"],
        "pairs": f"{rep['pairs_accepted']}/{rep['pairs_tried']}",
        "features_median": int(np.median(feats)) if feats else 0,
        "coverage": round(res.coverage_fraction, 3),
        "local_residual_px_median": rep["alignment"]["local_residual_px"]["median"],
        "time_s": round(time.perf_counter() - t0, 1),
    }


def real_pair(paths: list[Path], settings: FeatureConfig) -> dict:
    imgs = [cv2.imread(str(p), cv2.IMREAD_COLOR) for p in paths]
    full = [np.full(i.shape[:2], 255, np.uint8) for i in imgs]
    f = [detect(i, m, settings) for i, m in zip(imgs, full, strict=True)]
    r = match_pair(0, 1, f[0], f[1], settings=PairSettings(ransac_px=max(2.0, 0.004 * imgs[0].shape[1])))
    return {
        "features": [len(x.keypoints) for x in f],
        "matches": r.matches,
        "inliers": r.inliers,
        "registered": r.accepted,
        "model": r.model,
        "reason": r.reason,
    }


def extraction_cost(recording: Path, frames=(0, 10, 20, 30), rounds: int = 2) -> dict:
    """CPU seconds and features per keyframe of both settings on a recording's frames, interleaved (CPU time,
    so the shared machine's load cancels out)."""
    pairs = [
        (
            cv2.imread(str(recording / "frames" / f"{i:06d}.jpg")),
            cv2.imread(str(recording / "masks" / f"{i:06d}.png"), 0),
        )
        for i in frames
    ]
    cpu = dict.fromkeys(SETTINGS, 0.0)
    feats: dict[str, list[int]] = {k: [] for k in SETTINGS}
    for _ in range(rounds):
        for img, mask in pairs:
            for name, settings in SETTINGS.items():
                t0 = time.process_time()
                feats[name].append(len(detect(img, mask, settings).keypoints))
                cpu[name] += time.process_time() - t0
    n = rounds * len(pairs)
    return {k: {"cpu_s": round(cpu[k] / n, 3), "features": int(np.mean(feats[k]))} for k in SETTINGS}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--photo", default=str(SHARED / "DJI_0977_rgb.JPG"))
    ap.add_argument("--pair", nargs=2, default=[str(SHARED / "DJI_0977_rgb.JPG"), str(SHARED / "DJI_0981_rgb.JPG")])
    ap.add_argument("--mm-per-px", type=float, default=1.0, help="wall texture scale (the camera sees it 1:1)")
    ap.add_argument("--band-m", type=float, default=1.0, help="height of the wall band used (0: all)")
    ap.add_argument("--width", type=int, default=1280, help="keyframe width (16:9, hfov 70 deg)")
    ap.add_argument("--overlap", type=float, default=0.75, help="overlap of neighbouring keyframes")
    ap.add_argument("--poses", action="store_true", help="also stitch with telemetry")
    ap.add_argument("--out", default="/tmp/stitch_plain_wall")
    ap.add_argument("--cost-recording", help="also: extraction CPU per keyframe on this recording (e.g. 4K)")
    args = ap.parse_args(argv)
    out = Path(args.out)
    texture = plain_wall_texture(Path(args.photo), args.band_m, args.mm_per_px)
    wall = wall_for_texture(texture, args.mm_per_px)
    width, height = args.width, round(args.width * 9 / 16)
    f_px = (width / 2) / np.tan(np.radians(35.0))
    standoff = f_px * args.mm_per_px / 1000  # the camera sees the texture at its own resolution
    spool = out / "spool"
    make_spool(
        spool,
        wall,
        width=width,
        height=height,
        standoff_m=standoff,
        overlap=args.overlap,
        margin_m=0.02,
        texture=texture,
    )
    n = len((spool / MANIFEST).read_text().splitlines())
    print(
        f"plain wall from {Path(args.photo).name}: {wall.length_m:.2f} x {wall.height_m:.2f} m at "
        f"{args.mm_per_px} mm/px, {n} keyframes {width}x{height}, neighbours overlap {args.overlap:.0%}"
    )
    results: dict = {"wall": {"photo": Path(args.photo).name, "keyframes": n, "width": width}, "runs": {}}
    modes = [("image-only", False)] + ([("telemetry", True)] if args.poses else [])
    for name, settings in SETTINGS.items():
        for mode, poses in modes:
            tag = f"{mode}-{'clahe' if settings.equalize else 'plain'}"
            r = run_pass(spool, out / tag, settings, poses)
            results["runs"][f"{name} / {mode}"] = r
            print(
                f"{name:38s} {mode:10s}: {r['keyframes_connected']}/{r['keyframes']} keyframes connected, "
                f"pairs {r['pairs']}, features {r['features_median']}/keyframe, coverage {r['coverage']:.1%}, "
                f"{r['time_s']} s"
            )
    pair = [Path(p) for p in args.pair]
    for name, settings in SETTINGS.items():
        r = real_pair(pair, settings)
        results["runs"][f"{name} / real pair"] = r
        print(
            f"{name:38s} {pair[0].name} vs {pair[1].name}: features {r['features']}, matches {r['matches']}, "
            f"inliers {r['inliers']}, {'registered (' + r['model'] + ')' if r['registered'] else r['reason']}"
        )
    if args.cost_recording:
        cost = extraction_cost(Path(args.cost_recording))
        results["extraction_cost"] = cost
        for name, c in cost.items():
            print(f"{name:38s} extraction on {args.cost_recording}: {c['cpu_s']} CPU s, {c['features']} features")
    (out / "results.json").write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())

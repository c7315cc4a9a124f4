"""Keyframe masks of an offline cull against the recording's true masks (simulator recordings only).

Usage: python bench/depth_cull_truth.py SPOOL [SPOOL ...] --recording REC [--offset 0]

``companion cull`` of a simulator recording's frames writes ``kf_NNNNNN_mask.png`` per keyframe; the recording
(``companion record``) holds the true ROI mask of every frame (``masks/NNNNNN.png``, 255 = facade). Per spool:
keyframes, keyframes that truly show no facade, frames dropped as background, and the
keyframe masks' pixel error mean / p95, facade lost and background kept, side by side.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import cv2
import numpy as np


def spool_figures(spool: Path, recording: Path, offset: int) -> dict:
    errors, lost, kept, no_facade = [], [], [], 0
    masks = sorted(spool.glob("kf_*_mask.png"))
    for path in masks:
        index = int(path.stem.split("_")[1]) + offset
        truth_path = recording / "masks" / f"{index:06d}.png"
        truth = cv2.imread(str(truth_path), cv2.IMREAD_GRAYSCALE)
        mask = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        if truth is None or mask is None:
            raise SystemExit(f"cannot read {truth_path} or {path}")
        if truth.shape != mask.shape:
            truth = cv2.resize(truth, mask.shape[::-1], interpolation=cv2.INTER_NEAREST)
        t, m = truth > 127, mask > 127
        errors.append(float((t != m).mean()))
        if t.any():
            lost.append(float((t & ~m).sum() / t.sum()))
        else:
            no_facade += 1
        if (~t).any():
            kept.append(float((m & ~t).sum() / (~t).sum()))
    report = json.loads((spool / "cull_report.json").read_text())
    e = np.array(errors)
    return {"spool": str(spool), "keyframes": len(masks), "keyframes_without_facade": no_facade,
            "dropped_no_roi": report.get("dropped_no_roi"), "parallax_frames": report.get("parallax_frames"),
            "parallax_skipped_sure": report.get("parallax_skipped_sure"), "cpu_s": report.get("cpu_s"),
            "error_mean": float(e.mean()) if len(e) else float("nan"),
            "error_p95": float(np.percentile(e, 95)) if len(e) else float("nan"),
            "facade_lost_mean": float(np.mean(lost)) if lost else float("nan"),
            "background_kept_mean": float(np.mean(kept)) if kept else float("nan")}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("spools", nargs="+", type=Path)
    ap.add_argument("--recording", type=Path, required=True, help="the simulator recording the frames came from")
    ap.add_argument("--offset", type=int, default=0, help="recording frame index of the cull's frame 0")
    args = ap.parse_args()
    for spool in args.spools:
        f = spool_figures(spool, args.recording, args.offset)
        print(f"{spool}: {f['keyframes']} keyframes ({f['keyframes_without_facade']} without facade), "
              f"{f['dropped_no_roi']} frames dropped as background, parallax on {f['parallax_frames']} "
              f"(skipped as sure {f['parallax_skipped_sure']}), chain CPU {f['cpu_s']:.1f} s; keyframe masks: error "
              f"{100 * f['error_mean']:.2f} % mean / {100 * f['error_p95']:.2f} % p95, facade lost "
              f"{100 * f['facade_lost_mean']:.2f} %, background kept {100 * f['background_kept_mean']:.2f} %")


if __name__ == "__main__":
    main()

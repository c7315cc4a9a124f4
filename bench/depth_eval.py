"""Depth-mask accuracy on held-out simulator recordings: pixel error ratio vs the true ROI masks (mean, p95) and
the fraction of frames whose ROI is nearer than the background (paper: 0.75 % mean error; ROI always nearer).

Usage: python bench/depth_eval.py [--model M.onnx [M2.onnx ...]] [--seeds 100 101] [--real-photos DIR]
       [--gen-stride 30] [--stride 1] [--data DIR] [--save DIR] [--json OUT] [--near-ratio 0.6 ...] [--far-cut 0.5 ...]
Recordings of missions/demo-facade.yaml with the given seeds are generated into --data if missing (seeds the
shipped model never saw: it was trained on random-view scenes 0-29, its ROI parameters chosen on seed 200).
Several models are evaluated one after the other in the same run, for a side-by-side comparison. With
--real-photos, each model also masks the real drone photos of a wall (../shared/data/real-uav-facade): the
fraction of the frame kept, and of the plain wall (the photos' left 80 %; the right edge is a window).
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

import numpy as np

from companion.depth.masker import Masker
from companion.depth.roi import RoiParams
from companion.depth.session import DEFAULT_MODEL
from evaluation.depth.evaluate import evaluate_recording

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", nargs="+", default=[str(DEFAULT_MODEL)])
    ap.add_argument("--real-photos", default=None, help="folder of real wall photos (*.JPG) to mask too")
    ap.add_argument("--seeds", nargs="+", type=int, default=[100, 101])
    ap.add_argument("--mission", default=str(ROOT / "missions" / "demo-facade.yaml"))
    ap.add_argument("--gen-stride", type=int, default=30, help="camera frames between recorded frames")
    ap.add_argument("--stride", type=int, default=1, help="evaluate every n-th recorded frame")
    ap.add_argument("--data", default="/tmp/companion-depth-eval")
    ap.add_argument("--save", default=None, help="folder for frame | disparity | mask | truth pictures")
    ap.add_argument("--json", default=None)
    ap.add_argument("--near-ratio", type=float, nargs="+", default=[RoiParams.near_ratio])
    ap.add_argument("--far-cut", type=float, nargs="+", default=[RoiParams.far_cut_ratio])
    ap.add_argument("--oracle", action="store_true",
                    help="also run the ROI extraction on the simulator's TRUE depth (isolates the model's error)")
    args = ap.parse_args()
    results = []
    for model in args.model:
        for near in args.near_ratio:
            for far in args.far_cut:
                params = RoiParams(near_ratio=near, far_cut_ratio=far)
                print(f"--- model {model}, ROI parameters: near_ratio {near}, far_cut_ratio {far}")
                results.append({"model": model, "near_ratio": near, "far_cut_ratio": far,
                                "seeds": run(args, model, params)})
                if args.real_photos:
                    real_photos(Path(args.real_photos), model, params)
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1))
    if args.oracle:
        for near in args.near_ratio:
            for far in args.far_cut:
                oracle(args, RoiParams(near_ratio=near, far_cut_ratio=far))


def real_photos(folder: Path, model: str, params: RoiParams) -> None:
    """Fraction of each real wall photo kept, and of its plain-wall part (left 80 %)."""
    import cv2

    from companion.records import Frame, TaggedFrame

    masker = Masker(model, params=params)
    photos = sorted(p for p in folder.iterdir() if p.suffix.lower() in (".jpg", ".jpeg", ".png"))
    for n, photo in enumerate(photos):
        image = cv2.imread(str(photo), cv2.IMREAD_COLOR)
        _, roi = masker.mask(TaggedFrame(Frame(n, 0.0, image), pose=None))
        wall = roi.mask[:, : int(0.8 * roi.mask.shape[1])]
        print(f"real photo {photo.name}: kept {100 * roi.roi_fraction:.1f} % of the frame, "
              f"{100 * np.count_nonzero(wall) / wall.size:.1f} % of the plain wall (left 80 %), "
              f"dropped={roi.empty}")


def oracle(args, params: RoiParams) -> None:
    """ROI extraction on true disparity at the model's input size: the error the method has with a perfect model."""
    import cv2

    from companion.depth.roi import extract_roi, pixel_error_ratio
    from sim.camera.recording import load_recording

    errs = []
    for seed in args.seeds:
        rec = load_recording(Path(args.data) / f"demo_seed{seed:04d}_g{args.gen_stride}")
        for i in range(0, len(rec), args.stride):
            depth = rec.depth(i)
            disp = np.where(np.isfinite(depth), 1.0 / np.maximum(depth, 1e-3), 0.0).astype(np.float32)
            disp = cv2.resize(disp, (640, 192), interpolation=cv2.INTER_NEAREST)
            roi = extract_roi(disp, out_size=(rec.width, rec.height), params=params)
            errs.append(pixel_error_ratio(roi.mask, rec.roi_mask(i)))
    e = np.array(errs)
    print(f"ORACLE (true depth -> ROI extraction), {len(e)} frames: pixel error ratio mean {100 * e.mean():.2f} % "
          f"p95 {100 * np.percentile(e, 95):.2f} %")


def run(args, model: str, params: RoiParams) -> list[dict]:
    from sim.camera.recording import generate_recording

    masker = Masker(model, params=params)
    rows, all_frames = [], []
    for seed in args.seeds:
        path = Path(args.data) / f"demo_seed{seed:04d}_g{args.gen_stride}"
        if not (path / "meta.json").is_file():
            generate_recording(args.mission, path, seed=seed, stride=args.gen_stride)
        t0 = time.perf_counter()
        ev = evaluate_recording(path, masker, stride=args.stride,
                                save_dir=Path(args.save) / f"seed{seed}" if args.save else None)
        s = ev.summary()
        s["seconds"] = time.perf_counter() - t0
        rows.append(s)
        all_frames += ev.frames
        print(f"seed {seed}: {s['frames']} frames  error mean {100 * s['error_mean']:.2f} %  "
              f"p95 {100 * s['error_p95']:.2f} %  max {100 * s['error_max']:.2f} %  ROI nearer "
              f"{s['roi_nearer_fraction']:.3f} of {s['frames_with_both_sides']}  (true-mask nearer "
              f"{s['true_roi_nearer_fraction']:.3f})  dropped {s['dropped_empty']} (true empty {s['true_empty']})  "
              f"no-boundary {s['no_boundary']}")
    e = np.array([f.error_ratio for f in all_frames])
    near = [f.roi_nearer for f in all_frames if f.roi_nearer is not None]
    tnear = [f.true_roi_nearer for f in all_frames if f.true_roi_nearer is not None]
    edge = np.array([f.error_ratio for f in all_frames if 0.0 < f.true_roi_fraction < 1.0])
    print(f"ALL: model {Path(model).name}, {len(e)} frames: pixel error ratio mean {100 * e.mean():.2f} % "
          f"p95 {100 * np.percentile(e, 95):.2f} %; frames with background in truth ({len(edge)}): mean "
          f"{100 * edge.mean() if len(edge) else float('nan'):.2f} %; ROI nearer than background in "
          f"{100 * np.mean(near) if near else float('nan'):.1f} % of {len(near)} frames with both sides "
          f"(true masks: {100 * np.mean(tnear) if tnear else float('nan'):.1f} % of {len(tnear)})")
    print(f"machine: {platform.machine()} cores={__import__('os').cpu_count()}")
    return rows


if __name__ == "__main__":
    main()

"""`companion mask` one photo at a time (no --sequence, no telemetry) with each single-photo rule, side by side.

Each real-texture pass (held-out: sim/camera/photo_passes.py; validation, training-split photos:
bench/depth_error_regions.py VALIDATION) is rendered to photo files and masked by
``companion.depth.photomask.mask_photos`` exactly as the command does, once per rule of
``companion.depth.single_photo.SINGLE_PHOTO_RULES`` ("network" is the rule before issue 27). ``--sim-seeds``
also masks the simulator's demo recordings of those seeds frame by frame with each rule (a simulator figure).

    python bench/mask_single.py --passes val-b0309-120,val-b0169-40,val-coruna-120,val-montana-40   # validation
    python bench/mask_single.py --models sim,real-nc --frames 50 --background-frames 10 --width 640   # held-out
    python bench/mask_single.py --passes none --sim-seeds 200 --models sim
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # bench.* when run as a script

from bench.mask_sequence import render_pass, score  # noqa: E402
from companion.depth.masker import Masker  # noqa: E402
from companion.depth.photomask import mask_photos  # noqa: E402
from companion.depth.single_photo import SINGLE_PHOTO_RULES, SinglePhotoMasker  # noqa: E402
from sim.camera.photo_passes import DEFAULT_PASSES  # noqa: E402

MISSION = Path(__file__).resolve().parents[1] / "missions" / "demo-facade.yaml"


def oracle_split(folder: Path, truths, masker: Masker) -> str:
    """What the best split of the network's depth could do, one photo at a time: each photo cut at the depth
    threshold (41 quantiles, none, all) that gives the least error against ITS TRUTH. A bound on any rule that
    splits the network's depth per photo (a histogram split, a wider ratio), not a method."""
    import cv2
    import numpy as np

    errors = []
    for path, truth in zip(sorted(folder.iterdir()), truths, strict=True):
        disparity = np.squeeze(masker.session.disparity(cv2.imread(str(path), cv2.IMREAD_COLOR)))
        t = cv2.resize(truth, (disparity.shape[1], disparity.shape[0]), interpolation=cv2.INTER_NEAREST) > 127
        cuts = np.concatenate([[-1.0], np.quantile(disparity, np.linspace(0, 1, 41)), [2.0]])
        errors.append(min(float(np.mean((disparity >= c) != t)) for c in cuts))
    return f"{100 * np.mean(errors):.1f} %"


def sim_rows(seeds: list[int], model: str, rules: list[str], gen_stride: int, data: Path) -> None:
    """Mean / p95 mask error on the simulator's demo recordings (every frame a photo alone), per rule."""
    from evaluation.depth.evaluate import evaluate_recording
    from sim.camera.recording import generate_recording

    for seed in seeds:
        path = data / f"demo_seed{seed:04d}_g{gen_stride}"
        if not (path / "meta.json").is_file():
            generate_recording(MISSION, path, seed=seed, stride=gen_stride)
        for rule in rules:
            masker = SinglePhotoMasker(Masker(model, threads=1), rule)
            s = evaluate_recording(path, masker).summary()
            print(f"| sim seed {seed} (simulator) | {model} | {rule} | {100 * s['error_mean']:.2f} % / "
                  f"{100 * s['error_p95']:.2f} % | - | dropped {s['dropped_empty']} (true empty {s['true_empty']}) | "
                  f"{s['dropped_with_facade']} | - |", flush=True)


def labelled_rows(split: str, models: list[str], rules: list[str], stride: int) -> None:
    """Labelled facade photos (CMP, LabelMeFacade) of one split of companion.depth.training.realdata, every
    ``stride``-th, one at a time: mask error against the facade labels, facade lost, background kept, per rule
    (the network runs once per photo; each rule post-processes the same answer, as ``companion mask`` does).
    Caveat as in bench/depth_real_photos.py: a label's background is not always far (neighbours, street, cars)."""
    import numpy as np
    from checkout import use_checkout_shared_data

    from companion.depth.single_photo import apply_rule, single_photo_rule
    from companion.depth.training.realdata import facade_mask, list_real_photos, load_image

    photos = [p for p in list_real_photos(use_checkout_shared_data(), split=split)
              if p.source in ("cmp", "labelmefacade")][::stride]
    assert all(p.split == split for p in photos)
    for model in models:
        masker = Masker(model, threads=1)
        depth_of = masker.session.info.depth_from_disparity
        scores = {(source, rule): [] for source in ("cmp", "labelmefacade") for rule in rules}
        for photo in photos:
            image, truth = load_image(photo), facade_mask(photo) > 0
            disparity = np.squeeze(masker.session.disparity(image))
            roi = masker.roi_from_disparity(disparity, image.shape[:2])
            for rule in rules:
                mask = apply_rule(roi, disparity, masker.params, single_photo_rule(rule), depth_of).mask > 127
                mask &= not roi.empty
                scores[photo.source, rule].append((
                    np.count_nonzero(mask != truth) / truth.size,
                    np.count_nonzero(truth & ~mask) / max(1, np.count_nonzero(truth)),
                    np.count_nonzero(~truth & mask) / max(1, np.count_nonzero(~truth))))
        for (source, rule), rows in scores.items():
            e, lost, kept = (100 * np.mean(c) for c in zip(*rows, strict=True))
            print(f"| {split} {source} photos ({len(rows)}) | {model} | {rule} | {e:.1f} % | "
                  f"facade lost {lost:.1f} % | background kept {kept:.1f} % |", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--passes", default=",".join(DEFAULT_PASSES), help="comma list; 'none' for no pass")
    ap.add_argument("--models", default="sim", help="comma list of shipped model names or .onnx paths")
    ap.add_argument("--rules", default=",".join(SINGLE_PHOTO_RULES), help="comma list of single-photo rules")
    ap.add_argument("--frames", type=int, default=50, help="frames per pass (every 5th of the issue's 250)")
    ap.add_argument("--background-frames", type=int, default=10)
    ap.add_argument("--width", type=int, default=640, help="photo width in px (16:9, 69 deg hfov)")
    ap.add_argument("--sim-seeds", type=int, nargs="*", default=[], help="demo recordings to mask too")
    ap.add_argument("--gen-stride", type=int, default=60, help="camera frames between recorded sim frames")
    ap.add_argument("--data", default="/tmp/companion-depth-eval", help="cache of the sim recordings")
    ap.add_argument("--labelled", choices=["train", "heldout"], default=None,
                    help="also the labelled facade photos of that split, one at a time")
    ap.add_argument("--labelled-stride", type=int, default=5, help="every n-th labelled photo")
    ap.add_argument("--oracle", action="store_true",
                    help="also the best per-photo depth threshold chosen with the truth (a bound, not a method)")
    args = ap.parse_args()
    rules = [r for r in args.rules.split(",") if r]
    models = [m for m in args.models.split(",") if m]
    passes = [p for p in args.passes.split(",") if p and p != "none"]
    print(f"machine: {platform.platform()}, {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.1f}")
    print(f"{args.frames} frames per pass ({args.background_frames} past the wall's end), {args.width} px wide")
    print("\n| pass | model | rule | error mean / p95 | wall-only frames | background-only dropped | "
          "frames with wall dropped | s |")
    print("|---|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for name in passes:
            folder = Path(tmp) / name
            folder.mkdir()
            truths = render_pass(name, args.frames, args.background_frames, args.width, folder)
            for model in models:
                masker = Masker(model, threads=1)
                for rule in rules:
                    t0 = time.perf_counter()
                    out = Path(tmp) / f"{name}-{Path(model).stem}-{rule}"
                    results = mask_photos([folder], out, masker, single_rule=rule)
                    print(f"| {name} | {model} | {rule} | {score(results, truths)} | "
                          f"{time.perf_counter() - t0:.0f} |", flush=True)
                if args.oracle:
                    print(f"| {name} | {model} | oracle split (truth-chosen) | {oracle_split(folder, truths, masker)} "
                          "| | | | |", flush=True)
    if args.labelled:
        labelled_rows(args.labelled, models, rules, args.labelled_stride)
    for model in models:
        sim_rows(args.sim_seeds, model, rules, args.gen_stride, Path(args.data))


if __name__ == "__main__":
    main()

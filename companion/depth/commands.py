"""CLI: ``companion depth export|train|average|run`` and ``companion mask IMAGES``."""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

from companion.depth.session import DEFAULT_SIZE
from companion.depth.training.config import TrainConfig
from companion.errors import CompanionError
from companion.plugins import provided
from companion.resources import DEMO_MISSION_NAME, mission_argument

log = logging.getLogger(__name__)


def _seeds(text: str) -> list[int]:
    """'0-23' or '1,2,5' or '0-3,10' -> list of ints."""
    out: list[int] = []
    try:
        for part in text.split(","):
            if "-" in part:
                a, b = part.split("-")
                out.extend(range(int(a), int(b) + 1))
            elif part.strip():
                out.append(int(part))
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"bad seed list {text!r}: use e.g. 0-23 or 1,2,5") from exc
    return out


def _size(text: str) -> tuple[int, int]:
    try:
        h, w = (int(v) for v in text.lower().split("x"))
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"bad size {text!r}: use HEIGHTxWIDTH, e.g. 192x640") from exc
    return h, w


def _need_torch() -> None:
    try:
        import onnx  # noqa: F401
        import torch  # noqa: F401
    except ImportError as exc:
        raise CompanionError(
            f"this command needs the training extra ({exc.name} is not installed)",
            "pip install torch==2.13.0 (a CPU build) && pip install -e '.[train]'",
        ) from exc


def cmd_export(args) -> int:
    _need_torch()
    from companion.depth.training.export import export_checkpoints

    h, w = args.size
    rep = export_checkpoints(
        args.encoder, args.decoder, args.out, height=h, width=w, source=args.source, licence=args.licence,
        opset=args.opset,
    )
    print(f"wrote {rep.path} ({rep.size_bytes / 1e6:.1f} MB, input 1x3x{rep.height}x{rep.width}); "
          f"torch vs onnxruntime max abs diff {rep.max_abs_diff:.3g}")
    return 0


def cmd_train(args) -> int:
    _need_torch()
    from companion.depth.training.train import TrainConfig, train

    if args.seeds or args.eval_seeds:
        ensure_recordings = provided("ensure_recordings", "recording simulator scenes for training (--seeds)")
    out = Path(args.out)
    recs = [Path(p) for p in args.recordings or []]
    evals = [Path(p) for p in args.eval_recordings or []]
    if args.seeds:
        recs += ensure_recordings(args.mission, args.seeds, out / "data", width_px=args.width_px, stride=args.stride)
    if args.eval_seeds:
        evals += ensure_recordings(args.mission, args.eval_seeds, out / "data", width_px=args.width_px, stride=4)
    if not (0.0 <= args.reflect_windows <= 1.0 and 0.0 <= args.bright_walls <= 1.0):
        raise CompanionError(
            f"--reflect-windows {args.reflect_windows} / --bright-walls {args.bright_walls} out of range",
            "give shares between 0 and 1 (0 = off)",
        )
    if args.mask_loss_weight < 0 or args.mask_margin < 1.0:
        raise CompanionError(
            f"--mask-loss-weight {args.mask_loss_weight} / --mask-margin {args.mask_margin} out of range",
            "use a weight >= 0 (0 turns the mask loss off) and a margin >= 1 (e.g. 1.25)",
        )
    h, w = args.size
    cfg = TrainConfig(
        out=out, recordings=recs, eval_recordings=evals, height=h, width=w, crop=args.crop, batch=args.batch,
        model_width=args.model_width, lr=args.lr, max_minutes=args.max_minutes, max_steps=args.max_steps,
        threads=args.threads, view_seeds=args.view_seeds or [], eval_view_seeds=args.eval_view_seeds or [],
        views_per_seed=args.views_per_seed, init_from=Path(args.init_from) if args.init_from else None,
        real_photos=Path(args.real_photos) if args.real_photos else None, real_fraction=args.real_fraction,
        mask_loss_weight=args.mask_loss_weight, mask_margin=args.mask_margin,
        reflect_windows=args.reflect_windows, bright_walls=args.bright_walls,
    )
    path = train(cfg)
    print(f"model: {path}")
    return 0


def cmd_average(args) -> int:
    _need_torch()
    from companion.depth.training.average import average_runs

    rep = average_runs([Path(r) for r in args.runs], Path(args.out))
    print(f"model: {rep.onnx} (average of {len(rep.runs)} runs; torch vs onnxruntime max abs diff "
          f"{rep.max_abs_diff:.3g})")
    if rep.held_out is not None:
        print(f"held-out scenes: loss {rep.held_out['loss']:.4f}, abs. rel. depth error (facade and near) "
              f"{rep.held_out['abs_rel_facade_and_near']:.3f}")
    return 0


def cmd_run(args) -> int:
    """Mask image files and save frame | disparity | masked frame pictures (for looking at real photos)."""
    from companion.depth.inspect import inspect_images
    from companion.depth.masker import Masker

    for seen in inspect_images(args.images, Path(args.out), Masker(args.model)):
        roi = seen.roi
        print(f"{seen.image}: ROI {100 * roi.roi_fraction:.1f} % of the frame, regions {roi.n_regions}, "
              f"no_boundary={roi.no_boundary}, empty={roi.empty}, "
              f"disparity p5/p50/p95 = {' / '.join(f'{v:.4f}' for v in seen.disparity_p5_p50_p95)}")
    return 0


def _photo_masker(args):
    """The masker ``companion mask`` uses: with ``--standoff``, what the network puts farther than the standoff
    rule's limit is background (companion/depth/standoff_rule.py)."""
    from companion.depth.masker import Masker
    from companion.depth.standoff_rule import standoff_masker

    if args.standoff is None:
        return Masker(args.model, threads=args.threads)
    return standoff_masker(args.model, args.standoff, threads=args.threads)


def _photo_bound(args):
    """``--mission``: each photo's wall bound from its own pose tags (None without a mission)."""
    if args.mission is None:
        return None
    from companion.depth.photo_pose import checked_mission_wall, photo_bound

    wall = checked_mission_wall(args.mission)
    return lambda path, shape: photo_bound(path, shape, wall)


def cmd_mask(args) -> int:
    """Write ``<stem>_mask.png`` (255 facade, 0 background) for each photo and print its ROI share."""
    from companion.depth.photomask import mask_photos

    def report(m) -> None:
        what = "no near surface: all-zero mask" if m.no_near_surface else f"ROI {100 * m.roi_fraction:.1f} %"
        how = (" (parallax)" if m.by_parallax else "") + (" (wall bound)" if m.bounded else "")
        print(f"{m.image}: {what}{how} -> {m.mask_path}", flush=True)

    results = mask_photos(args.images, args.out, _photo_masker(args), on_mask=report, sequence=args.sequence,
                          bound=_photo_bound(args), single_rule=args.single_rule)
    dropped = sum(m.no_near_surface for m in results)
    print(f"{len(results)} masks written to {args.out} ({dropped} with no near surface)")
    if args.sequence and not any(m.by_parallax for m in results):
        print("--sequence: no neighbouring photos showed usable motion, so the network alone decided every mask "
              "(photos of one pass along the wall, in capture order, are needed; stills whose wall moves more than "
              "0.3 of the frame between neighbours are too far apart for the flow)")
    return 0


def register(subparsers) -> None:
    depth = subparsers.add_parser("depth", help="depth model: export, train, run on images")
    dsub = depth.add_subparsers(dest="depth_command", required=True)

    p = dsub.add_parser("export", help="Monodepth2 encoder.pth + depth.pth -> verified ONNX")
    p.add_argument("--encoder", required=True, help="encoder.pth (official key layout)")
    p.add_argument("--decoder", required=True, help="depth.pth (official key layout)")
    p.add_argument("--out", required=True, help="output .onnx")
    p.add_argument("--size", type=_size, default=DEFAULT_SIZE,
                   help="input HEIGHTxWIDTH (default {}x{})".format(*DEFAULT_SIZE))
    p.add_argument("--source", default=None, help="metadata: where the weights come from")
    p.add_argument("--licence", default="as licensed by the checkpoint's owner", help="metadata: weights licence")
    p.add_argument("--opset", type=int, default=17)
    p.set_defaults(func=cmd_export)

    p = dsub.add_parser("train", help="train the Monodepth2 model on simulator recordings (needs .[train])")
    p.add_argument("--out", required=True, help="run folder (checkpoints, logs, model.onnx); resumes if present")
    p.add_argument("--mission", type=mission_argument, default=DEMO_MISSION_NAME,
                   help=f"mission the recordings fly, a YAML or a shipped mission's name (default {DEMO_MISSION_NAME})")
    p.add_argument("--seeds", type=_seeds, default=None, help="training recording seeds, e.g. 0-23")
    p.add_argument("--eval-seeds", type=_seeds, default=None, help="held-out seeds, e.g. 100-103")
    p.add_argument("--view-seeds", type=_seeds, default=None, help="random-viewpoint scene seeds, e.g. 0-23")
    p.add_argument("--eval-view-seeds", type=_seeds, default=None, help="held-out random-view scenes, e.g. 1000-1003")
    p.add_argument("--views-per-seed", type=int, default=TrainConfig.views_per_seed)
    p.add_argument("--recordings", nargs="*", help="existing training recording folders")
    p.add_argument("--eval-recordings", nargs="*", help="existing held-out recording folders")
    p.add_argument("--width-px", type=int, default=640, help="recording width in pixels")
    p.add_argument("--stride", type=int, default=2, help="keep every n-th camera frame of a recording")
    p.add_argument("--size", type=_size, default=(TrainConfig.height, TrainConfig.width),
                   help="model input HEIGHTxWIDTH")
    p.add_argument("--crop", type=_size, default=TrainConfig.crop, help="training crop HEIGHTxWIDTH (CPU speed)")
    p.add_argument("--batch", type=int, default=TrainConfig.batch)
    p.add_argument("--model-width", type=float, default=TrainConfig.model_width,
                   help="channel width factor (1.0 = original)")
    p.add_argument("--lr", type=float, default=TrainConfig.lr)
    p.add_argument("--max-minutes", type=float, default=TrainConfig.max_minutes, help="wall-time budget")
    p.add_argument("--max-steps", type=int, default=TrainConfig.max_steps)
    p.add_argument("--threads", type=int, default=TrainConfig.threads, help="torch threads (1 on a shared machine)")
    p.add_argument("--init-from", default=None,
                   help="fine-tune: start from this run folder's weights or a Monodepth2 .onnx (e.g. the shipped one)")
    p.add_argument("--real-photos", default=None,
                   help="shared data folder (../shared/data): mix in composites of its train-split real photos "
                        "(makes the model research / non-commercial)")
    p.add_argument("--real-fraction", type=float, default=TrainConfig.real_fraction,
                   help="share of each batch from real photos")
    p.add_argument("--mask-loss-weight", type=float, default=TrainConfig.mask_loss_weight,
                   help="weight of the near/far mask hinge on samples with a facade mask, beside the depth loss "
                        "(0: depth loss only)")
    p.add_argument("--mask-margin", type=float, default=TrainConfig.mask_margin,
                   help="the hinge's margin: a factor (> 1) on disparity around the ROI rules' keep/cut threshold")
    p.add_argument("--reflect-windows", type=float, default=TrainConfig.reflect_windows,
                   help="share of real-photo wall composites whose windows reflect the background photo (depth "
                        "truth stays the wall's; 0: off)")
    p.add_argument("--bright-walls", type=float, default=TrainConfig.bright_walls,
                   help="share of real-photo composites whose wall becomes bright grey low-texture cladding (0: off)")
    p.set_defaults(func=cmd_train)

    p = dsub.add_parser("average", help="uniform weight average of training runs (a model soup) -> verified ONNX")
    p.add_argument("runs", nargs="+", help="run folders of companion depth train (one architecture, one ancestor)")
    p.add_argument("--out", required=True, help="output folder (model.onnx, encoder.pth, depth.pth, summary.json)")
    p.set_defaults(func=cmd_average)

    p = dsub.add_parser("run", help="mask image files; save frame | disparity | masked frame pictures")
    p.add_argument("images", nargs="+")
    p.add_argument("--out", required=True, help="folder for the pictures")
    p.add_argument("--model", default=None, help="ONNX model (default: the shipped one)")
    p.set_defaults(func=cmd_run)

    from companion.depth.single_photo import DEFAULT_RULE, SINGLE_PHOTO_RULES

    p = subparsers.add_parser(
        "mask", help="write <image stem>_mask.png (255 facade, 0 background) for photos, for OpenDroneMap/Metashape")
    p.add_argument("images", nargs="+", help="photo files or folders of photos (jpg, png, tif)")
    p.add_argument("--out", required=True, help="folder for the masks (created if missing)")
    p.add_argument("--model", default=None, help="ONNX depth model (default: the shipped one)")
    p.add_argument("--threads", type=int, default=None, help="onnxruntime threads (default: cores - 1)")
    p.add_argument("--sequence", action="store_true",
                   help="the photos are one pass along the wall in capture order (folders: sorted by name): "
                        "motion parallax between neighbours corrects each mask (docs/DEPTH.md)")
    p.add_argument("--single-rule", default=None, choices=list(SINGLE_PHOTO_RULES),
                   help=f"without --sequence, how each photo's network mask is post-processed (default "
                        f"{DEFAULT_RULE}: far patches that do not reach the frame's top are wall; network: the "
                        "network's mask alone; docs/DEPTH.md)")
    _add_mask_telemetry_options(p)
    p.set_defaults(func=cmd_mask)


def _add_mask_telemetry_options(p) -> None:
    """``companion mask``'s geometry options (issue 27): the mission's wall and the standoff."""
    p.add_argument("--mission", default=None,
                   help="mission YAML of the wall the photos show: photos with a pose in their tags (EXIF GPS, DJI "
                        "gimbal XMP) are masked only inside the wall's projection (docs/DEPTH.md)")
    p.add_argument("--standoff", type=float, default=None,
                   help="the camera's distance to the wall in metres: what the network puts well beyond it is "
                        "background (docs/DEPTH.md)")

"""`companion eval gate RECORDING`: the keyframe gate measured against a simulator recording's truth."""

from __future__ import annotations

import json
from pathlib import Path

from companion.errors import CompanionError
from companion.keyframes.evaluate import evaluate_gate, format_report, plot_curve
from companion.keyframes.features import FeatureConfig
from companion.keyframes.gate import GateConfig
from companion.keyframes.overlap import METHODS, OverlapConfig


def _eval_subparsers(subparsers):
    from companion.cli import shared_group

    return shared_group(subparsers, "eval", "measure a pipeline stage against simulator ground truth")


def gate_config_from_args(args) -> GateConfig:
    return GateConfig(
        rth=args.rth,
        features=FeatureConfig(long_side_px=args.long_side),
        overlap=OverlapConfig(method=args.method),
    )


def cmd_eval_gate(args) -> int:
    from sim.camera.recording import load_recording

    path = Path(args.recording)
    if not path.is_dir():
        raise CompanionError(f"{path} is not a directory", "pass a recording folder (sim.camera generate_recording)")
    rec = load_recording(path)
    ev = evaluate_gate(rec, gate_config_from_args(args), use_masks=not args.no_mask, curve_p=args.curve_p)
    print(f"{path} ({rec.width}x{rec.height}, masks {'off' if args.no_mask else 'truth'}):")
    print(format_report(ev))
    if args.plot:
        plot_curve(ev, args.plot)
        print(f"R vs q plot: {args.plot}")
    if args.json:
        med, p95, n = ev.error_stats()
        summary = {
            "recording": str(path),
            "frames": ev.frames,
            "keyframes": ev.keyframes,
            "minimum_keyframes": ev.minimum_keyframes,
            "R_error_median_pts": med,
            "R_error_p95_pts": p95,
            "comparisons": n,
            "unknown": ev.unknown,
            "keyframe_pair_true_overlap": ev.keyframe_pair_truth,
            "gaps": ev.gaps,
            "warnings": ev.warnings,
            "gate_seconds": ev.gate_seconds,
        }
        Path(args.json).write_text(json.dumps(summary, indent=1))
    return 0


def register(subparsers) -> None:
    p = _eval_subparsers(subparsers).add_parser(
        "gate", help="keyframe gate vs simulator truth: R error, keyframe-pair overlap, count vs minimum"
    )
    p.add_argument("recording", help="recording folder (meta.json, frames/, masks/, truth.jsonl)")
    p.add_argument("--rth", type=float, default=0.80, help="overlap threshold as a fraction (default 0.80)")
    p.add_argument("--method", choices=METHODS, default="displacement", help="overlap estimator")
    p.add_argument("--long-side", type=int, default=960, help="feature working copy long side in px (0 = full)")
    p.add_argument("--no-mask", action="store_true", help="ignore the ROI masks (whole frame)")
    p.add_argument("--curve-p", type=int, default=0, help="reference frame p of the R-vs-q curve")
    p.add_argument("--plot", default=None, help="write the R-vs-q curve (paper Fig. 9) to this PNG")
    p.add_argument("--json", default=None, help="write a JSON summary here")
    p.set_defaults(func=cmd_eval_gate)

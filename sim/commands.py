"""The simulator's commands, registered into ``companion``'s command line when sim is installed (the CLI loads this
module as a plugin): ``companion sim`` (the SITL vehicle), ``record`` (a recording with ground truth), ``demo``
(the whole job in SITL) and the ``eval`` group (a pipeline stage measured against simulator truth)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from companion.errors import CompanionError
from companion.keyframes.features import FeatureConfig
from companion.keyframes.gate import GateConfig
from companion.keyframes.overlap import METHODS, OverlapConfig

# The top-level commands this module adds; the CLI names them when sim is not installed.
COMMANDS = ("sim", "record", "demo", "eval")  # the same names as companion.plugins.PLUGIN_MODULES lists


def register(sub: argparse._SubParsersAction) -> None:
    from sim import demo
    from sim.camera import commands as record

    _register_vehicle(sub)
    record.register(sub)
    demo.register(sub)
    evaluations = sub.add_parser("eval", help="measure a pipeline stage against simulator ground truth")
    what = evaluations.add_subparsers(dest="eval_what", required=True)
    _register_eval_mask(what)
    _register_eval_gate(what)


def _register_vehicle(sub: argparse._SubParsersAction) -> None:
    from sim.vehicle.cli import add_arguments, run

    s = sub.add_parser("sim", allow_abbrev=False,
                       help="run the simulated MAVLink vehicle (same options as `python -m sim vehicle`)")
    add_arguments(s)
    s.set_defaults(func=run)


def _register_eval_mask(what: argparse._SubParsersAction) -> None:
    p = what.add_parser("mask", help="depth mask error ratio against simulator masks")
    p.add_argument("recordings", nargs="+", help="recording folder(s) (held-out seeds)")
    p.add_argument("--model", default=None, help="ONNX model (default: the shipped one)")
    p.add_argument("--stride", type=int, default=1)
    p.add_argument("--max-frames", type=int, default=None)
    p.add_argument("--save", default=None, help="folder for frame | disparity | mask | truth pictures")
    p.add_argument("--json", default=None, help="write the summaries to this JSON file")
    p.set_defaults(func=run_eval_mask)


def run_eval_mask(args: argparse.Namespace) -> int:
    from companion.depth.masker import Masker
    from evaluation.depth.evaluate import evaluate_recording

    masker = Masker(args.model)
    summaries = []
    for rec in args.recordings:
        ev = evaluate_recording(rec, masker, stride=args.stride, max_frames=args.max_frames, save_dir=args.save)
        s = ev.summary()
        summaries.append(s)
        print(f"{rec}: {s['frames']} frames, pixel error ratio mean {100 * s['error_mean']:.2f} % "
              f"p95 {100 * s['error_p95']:.2f} % max {100 * s['error_max']:.2f} %; ROI nearer than background in "
              f"{100 * s['roi_nearer_fraction']:.0f} % of {s['frames_with_both_sides']} frames with both; "
              f"dropped {s['dropped_empty']} (true empty {s['true_empty']}, "
              f"dropped with facade {s['dropped_with_facade']})")
    if args.json:
        Path(args.json).write_text(json.dumps(summaries, indent=1))
    return 0


def _register_eval_gate(what: argparse._SubParsersAction) -> None:
    gate, features = GateConfig(), FeatureConfig()
    p = what.add_parser(
        "gate", help="keyframe gate vs simulator truth: R error, keyframe-pair overlap, count vs minimum"
    )
    p.add_argument("recording", help="recording folder (meta.json, frames/, masks/, truth.jsonl)")
    p.add_argument("--rth", type=float, default=gate.rth,
                   help=f"overlap threshold as a fraction (default {gate.rth:.2f})")
    p.add_argument("--method", choices=METHODS, default=OverlapConfig().method, help="overlap estimator")
    p.add_argument("--long-side", type=int, default=features.long_side_px,
                   help="feature working copy long side in px (0 = full)")
    p.add_argument("--no-mask", action="store_true", help="ignore the ROI masks (whole frame)")
    p.add_argument("--curve-p", type=int, default=0, help="reference frame p of the R-vs-q curve")
    p.add_argument("--plot", default=None, help="write the R-vs-q curve (paper Fig. 9) to this PNG")
    p.add_argument("--json", default=None, help="write a JSON summary here")
    p.set_defaults(func=run_eval_gate)


def gate_config_from_args(args: argparse.Namespace) -> GateConfig:
    return GateConfig(rth=args.rth, features=FeatureConfig(long_side_px=args.long_side),
                      overlap=OverlapConfig(method=args.method))


def run_eval_gate(args: argparse.Namespace) -> int:
    from evaluation.keyframes.evaluate import evaluate_gate, format_report, plot_curve
    from sim.camera.recording import load_recording

    path = Path(args.recording)
    if not path.is_dir():
        raise CompanionError(f"{path} is not a directory", "pass a recording folder (companion record --out DIR)")
    rec = load_recording(path)
    ev = evaluate_gate(rec, gate_config_from_args(args), use_masks=not args.no_mask, curve_p=args.curve_p)
    print(f"{path} ({rec.width}x{rec.height}, masks {'off' if args.no_mask else 'truth'}):")
    print(format_report(ev))
    if args.plot:
        plot_curve(ev, args.plot)
        print(f"R vs q plot: {args.plot}")
    if args.json:
        Path(args.json).write_text(json.dumps(gate_summary(path, ev), indent=1))
    return 0


def gate_summary(path: Path, ev) -> dict:
    med, p95, n = ev.error_stats()
    return {
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

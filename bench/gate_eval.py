"""Keyframe gate against simulator truth (issue 6): R error, keyframe-pair overlap, count vs minimum, Fig. 9.

Generates a fast kinematic recording of a mission with sim.camera (or reuses --recording), runs the streaming
gate over it with the truth ROI masks and prints the figures; writes the R-vs-q plot (paper Figure 9).

    python bench/gate_eval.py                                       # paper-like pass: 118 raw frames
    python bench/gate_eval.py --stride 6 --max-frames 240           # longer: strip turns included
    python bench/gate_eval.py --recording /tmp/rec --plot docs/img/gate_fig9.png --curve-p 12
"""

from __future__ import annotations

import argparse
import os
import platform
import time
from pathlib import Path

from companion.keyframes.evaluate import evaluate_gate, format_report, plot_curve
from companion.keyframes.features import FeatureConfig
from companion.keyframes.gate import GateConfig
from companion.keyframes.overlap import METHODS, OverlapConfig


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mission", default="missions/demo-facade.yaml")
    ap.add_argument("--recording", default=None, help="existing recording folder (skips generation)")
    ap.add_argument("--out", default=None, help="where to generate (default /tmp/gate_eval_<mission>_<args>)")
    ap.add_argument("--width", type=int, default=960, help="rendered width in px")
    ap.add_argument("--stride", type=int, default=8, help="keep every n-th camera frame (30 fps camera)")
    ap.add_argument("--max-frames", type=int, default=118, help="paper: 118 raw images")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--rth", type=float, default=0.80)
    ap.add_argument("--method", choices=METHODS, default="displacement")
    ap.add_argument("--long-side", type=int, default=960)
    ap.add_argument("--no-mask", action="store_true")
    ap.add_argument("--plot", default=None, help="PNG for the R-vs-q curve (paper Fig. 9)")
    ap.add_argument("--curve-p", type=int, default=0, help="reference frame p of the R-vs-q curve")
    args = ap.parse_args()

    if args.recording:
        rec_dir = Path(args.recording)
    else:
        from sim.camera.recording import generate_recording

        name = Path(args.mission).stem
        rec_dir = Path(args.out or f"/tmp/gate_eval_{name}_w{args.width}_s{args.stride}_n{args.max_frames}_"
                                   f"seed{args.seed}")
        if not (rec_dir / "meta.json").exists():
            t0 = time.perf_counter()
            generate_recording(args.mission, rec_dir, seed=args.seed, width_px=args.width, stride=args.stride,
                               max_frames=args.max_frames)
            print(f"generated {rec_dir} in {time.perf_counter() - t0:.0f} s")
    from sim.camera.recording import load_recording

    rec = load_recording(rec_dir)
    cfg = GateConfig(rth=args.rth, features=FeatureConfig(long_side_px=args.long_side),
                     overlap=OverlapConfig(method=args.method))
    print(f"machine: {platform.platform()}, {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.1f}")
    print(f"recording {rec_dir}: {len(rec)} frames {rec.width}x{rec.height}, mission {rec.meta.get('mission')}, "
          f"generator {rec.meta.get('generator')}, masks {'off' if args.no_mask else 'truth'}")
    ev = evaluate_gate(rec, cfg, use_masks=not args.no_mask, curve_p=args.curve_p)
    print(format_report(ev))
    if args.plot:
        Path(args.plot).parent.mkdir(parents=True, exist_ok=True)
        plot_curve(ev, args.plot)
        print(f"R vs q plot (p = {ev.curve_p}): {args.plot}")


if __name__ == "__main__":
    main()

"""Keyframe gate against simulator truth (issues 6, 15): keyframes vs the minimum, keyframe-pair true overlap,
R error, Fig. 9; images-only gate (the paper's, today's without poses) side by side with the telemetry gate.

Generates a fast kinematic recording of a mission with sim.camera (or reuses --recording), runs the streaming
gate over it once per (mask, gate) configuration and prints one row each; writes the R-vs-q plot (paper Fig. 9).

    python bench/gate_eval.py                                       # paper-like pass: 118 raw frames
    python bench/gate_eval.py --stride 6 --max-frames 240           # longer: strip turns included
    python bench/gate_eval.py --mission bench/missions/wall-end-pass.yaml --stride 12 --max-frames 160
    python bench/gate_eval.py --masks truth,none,model --pose-noise 1.0,0.8,-1.0,3,0.05,0.3
    python bench/gate_eval.py --recording /tmp/rec --plot docs/img/gate_fig9.png --curve-p 12 --gates images

Masks: ``truth`` (the simulator's ROI), ``none`` (whole frame, the onboard ``--no-mask``), ``model`` (the shipped
depth model through the onboard Masker; frames it drops as all-background never reach the gate, as onboard).
Gates: ``images`` (no poses: the paper's rule, and the gate's behaviour for frames without telemetry) and
``telemetry`` (frames tagged with the recording's camera poses, optionally with --pose-noise).
"""

from __future__ import annotations

import argparse
import os
import platform
import time
from pathlib import Path

from companion.keyframes.features import FeatureConfig
from companion.keyframes.gate import GateConfig
from companion.keyframes.motion import WallMotionPredictor
from companion.keyframes.overlap import METHODS, OverlapConfig
from evaluation.keyframes.evaluate import (
    PoseNoise,
    evaluate_gate,
    format_report,
    format_table,
    plot_curve,
    telemetry_poses,
)


def model_masks(rec):
    """mask_of(i) from the shipped depth model (None where the Masker drops the frame), computed once."""
    from companion.depth.masker import Masker
    from companion.records import TaggedFrame

    masker = Masker(None)
    cache: dict[int, object] = {}

    def mask_of(i: int):
        if i not in cache:
            masked = masker(TaggedFrame(rec.frame_record(i), None))
            cache[i] = None if masked is None else masked.mask
        return cache[i]

    return mask_of


def parse_pose_noise(text: str | None) -> PoseNoise:
    if not text:
        return PoseNoise()
    v = [float(x) for x in text.split(",")]
    if len(v) != 6:
        raise SystemExit("--pose-noise takes 6 numbers: bias_along,bias_out,bias_up (m),bias_yaw (deg),"
                         "sigma_m,sigma_deg")
    return PoseNoise(bias_m=(v[0], v[1], v[2]), bias_yaw_deg=v[3], sigma_m=v[4], sigma_deg=v[5])


def _parser() -> argparse.ArgumentParser:
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
    ap.add_argument("--masks", default="truth,none", help="comma list of truth, none, model")
    ap.add_argument("--no-mask", action="store_true", help="same as --masks none")
    ap.add_argument("--gates", default="images,telemetry", help="comma list of images, telemetry")
    ap.add_argument("--pose-noise", default=None,
                    help="telemetry error: bias_along,bias_out,bias_up (m),bias_yaw (deg),sigma_m,sigma_deg per frame")
    ap.add_argument("--verbose", action="store_true", help="print each run's full report")
    ap.add_argument("--plot", default=None, help="PNG for the R-vs-q curve (paper Fig. 9) of the first run")
    ap.add_argument("--curve-p", type=int, default=0, help="reference frame p of the R-vs-q curve")
    return ap


def recording_dir(args) -> Path:
    """--recording as given, else a recording of --mission generated once into a folder named by its settings."""
    if args.recording:
        return Path(args.recording)
    from sim.camera.recording import generate_recording

    name = Path(args.mission).stem
    rec_dir = Path(args.out or f"/tmp/gate_eval_{name}_w{args.width}_s{args.stride}_n{args.max_frames}_"
                               f"seed{args.seed}")
    if not (rec_dir / "meta.json").exists():
        t0 = time.perf_counter()
        generate_recording(args.mission, rec_dir, seed=args.seed, width_px=args.width, stride=args.stride,
                           max_frames=args.max_frames)
        print(f"generated {rec_dir} in {time.perf_counter() - t0:.0f} s")
    return rec_dir


def run_configurations(rec, cfg: GateConfig, args, masks: list[str], gates: list[str], noise: PoseNoise) -> list:
    """One gate evaluation per (mask, gate) pair, in order, each announced when done; (mask, gate, evaluation)."""
    standoff = rec.meta.get("standoff_m")
    predictor = WallMotionPredictor(rec.frame, float(rec.meta["camera"]["hfov_deg"]),
                                    float(standoff) if standoff else None)
    rows = []
    rec_masks = None
    for mask in masks:
        if mask not in ("truth", "none", "model"):
            raise SystemExit(f"unknown mask {mask!r}: use truth, none or model")
        if mask == "model" and rec_masks is None:
            rec_masks = model_masks(rec)
        for gate in gates:
            if gate not in ("images", "telemetry"):
                raise SystemExit(f"unknown gate {gate!r}: use images or telemetry")
            pose = telemetry_poses(rec, rec.frame, noise) if gate == "telemetry" else None
            ev = evaluate_gate(rec, cfg, use_masks=mask == "truth", curve_p=args.curve_p,
                               predictor=predictor if pose else None, pose=pose,
                               mask_of=rec_masks if mask == "model" else None)
            if args.verbose:
                print(f"--- mask {mask}, gate {gate}\n{format_report(ev)}")
            if args.plot and not rows:
                Path(args.plot).parent.mkdir(parents=True, exist_ok=True)
                plot_curve(ev, args.plot)
                print(f"R vs q plot (p = {ev.curve_p}): {args.plot}")
            rows.append((mask, gate, ev))
            print(f"done: mask {mask}, gate {gate}: {len(ev.keyframes)} keyframes, lowest pair "
                  f"{min(ev.keyframe_pair_truth, default=float('nan')):.1f} %", flush=True)
    return rows


def print_visible_wall_table(rec, rows: list, rth: float) -> None:
    """The same keyframe pairs measured on the VISIBLE wall only (footprints cut to the wall rectangle), over pairs
    whose first frame shows wall: near a wall's end this is lower than the plane overlap that Eq. 2 measures."""
    print(f"\n| mask | gate | keyframes showing no wall | visible-wall overlap of keyframe pairs: min | "
          f"pairs < {100 * rth - 3:.0f} % |")
    print("|---|---|---|---|---|")
    for mask, gate, ev in rows:
        shows = {k: bool(rec.roi_mask(k).any()) for k in ev.keyframes}
        seen = [100.0 * rec.true_overlap(a, b, wall_only=True)
                for a, b in zip(ev.keyframes, ev.keyframes[1:], strict=False) if shows[a]]
        print(f"| {mask} | {gate} | {sum(not v for v in shows.values())} of {len(ev.keyframes)} | "
              f"{min(seen, default=float('nan')):.1f} % | {sum(v < 100 * rth - 3 for v in seen)} of {len(seen)} |")


def main() -> None:
    args = _parser().parse_args()
    rec_dir = recording_dir(args)
    from sim.camera.recording import load_recording

    rec = load_recording(rec_dir)
    cfg = GateConfig(rth=args.rth, features=FeatureConfig(long_side_px=args.long_side),
                     overlap=OverlapConfig(method=args.method))
    masks = ["none"] if args.no_mask else [m.strip() for m in args.masks.split(",") if m.strip()]
    gates = [g.strip() for g in args.gates.split(",") if g.strip()]
    noise = parse_pose_noise(args.pose_noise)
    standoff = rec.meta.get("standoff_m")
    print(f"machine: {platform.platform()}, {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.1f}")
    print(f"recording {rec_dir}: {len(rec)} frames {rec.width}x{rec.height}, mission {rec.meta.get('mission')}, "
          f"generator {rec.meta.get('generator')}")
    print(f"telemetry: true camera poses{'' if noise.exact else f' + {noise}'}; wall at the planned standoff "
          f"{standoff} m")
    rows = run_configurations(rec, cfg, args, masks, gates, noise)
    print()
    print(format_table(rows, args.rth))
    print_visible_wall_table(rec, rows, args.rth)


if __name__ == "__main__":
    main()

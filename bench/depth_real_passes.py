"""Depth-mask accuracy on real-texture passes: held-out real facade photos on the simulator's wall plane, held-out
real outdoor photos as a plane behind it, a 1920x1080 camera (69 deg) at 4 m flying along the wall and off its end
(``sim/camera/photo_scene.py``, exact truth masks); plus the simulator's own held-out recordings.

Usage: python bench/depth_real_passes.py [--model A.onnx [B.onnx ...]] [--passes NAME ...] [--roi NAME ...]
       [--bg-distance M] [--frames 250] [--sim-seeds 100 101] [--sim-stride 1] [--save DIR] [--json OUT]

Per pass and per (model, ROI rule), all in one run on the same frames (the model runs once per frame):
pixel error mean and p95 over all frames, mean error on wall-only frames, facade lost (share of the true wall
cut, mean over frames with wall), background kept (share of the true background kept, mean over mixed frames),
all-background frames dropped (of how many) and frames with wall wrongly dropped.
Passes (sim/camera/photo_passes.py): ornate-entry, cmp-balconies, dji-plain-wall, cmp-roofline-40m; ``sim`` is
the demo mission's simulator recordings (seeds 100, 101: never trained on); or your own photos:
``--passes mine:/photos/wall.jpg:15:/photos/park.jpg:120`` (wall 15 m wide, background 120 m behind).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path

import numpy as np

from companion.depth.masker import Masker
from companion.depth.parallax import ParallaxParams
from companion.depth.session import DEFAULT_MODEL, DepthSession
from companion.depth.visual import save_visual
from evaluation.depth.evaluate import MaskEval, frame_eval
from evaluation.depth.parallax_rules import PARALLAX_RULES
from evaluation.depth.roi_rules import ROI_RULES

ROOT = Path(__file__).resolve().parents[1]


def photo_pass_frames(name: str, args) -> Iterator[tuple[int, np.ndarray, np.ndarray]]:
    from checkout import use_checkout_shared_data

    from sim.camera.photo_passes import RECIPES, build_pass, parse_recipe

    recipe = RECIPES[name] if name in RECIPES else parse_recipe(name)
    spec = build_pass(recipe, root=use_checkout_shared_data(),
                      frames=args.frames, background_frames=args.background_frames,
                      background_distance_m=args.bg_distance)
    print(f"pass {name}: wall {spec.wall.name} {spec.wall.width_m:.1f} x {spec.wall.height_m:.1f} m, background "
          f"{spec.background.name} at {spec.background_distance_m:.0f} m, {spec.frames} frames "
          f"{spec.camera.width}x{spec.camera.height} at {spec.standoff_m} m")
    yield from rendered_pass_frames(spec)


def rendered_pass_frames(spec):
    """Each frame of a photo pass with its truth mask and pose: (index, image, truth, (position, R, fx, standoff))
    in facade coordinates, the shape every pass of these benches yields."""
    from sim.camera.photo_scene import PhotoPassRenderer

    renderer = PhotoPassRenderer(spec)
    # camera axes in facade coordinates (along, out, up): x along the wall, y down, z into the wall
    R = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, -1.0, 0.0]])
    for i in range(len(renderer)):
        f = renderer.render(i)
        yield i, f.image, f.roi_mask, (np.array([f.along_m, spec.standoff_m, f.up_m]), R, spec.camera.fx,
                                       spec.standoff_m)


def sim_frames(args) -> Iterator[tuple[int, np.ndarray, np.ndarray]]:
    from companion.mission import load_mission
    from sim.camera.recording import generate_recording, load_recording

    n = 0
    for seed in args.sim_seeds:
        path = Path(args.data) / f"demo_seed{seed:04d}_g30"
        if not (path / "meta.json").is_file():
            generate_recording(str(ROOT / "missions" / "demo-facade.yaml"), path, seed=seed, stride=30)
        rec = load_recording(path)
        print(f"pass sim: simulator recording {path} ({len(rec)} frames, every {args.sim_stride})")
        fx = float(rec.K[0, 0])
        standoff_m = load_mission(ROOT / "missions" / "demo-facade.yaml").standoff_m
        for i in range(0, len(rec), args.sim_stride):
            pose = rec.camera_pose(i)
            yield n, rec.image(i), rec.roi_mask(i), (pose.position_enu, pose.R_world_from_cam, fx, standoff_m)
            n += 1


def facade_pose(index: int, position: np.ndarray):
    """The exact telemetry pose (``companion.records.Pose``) of a photo pass's camera at facade (along, out, up),
    facing the wall with the gimbal level: what the onboard masker reads (its parallax baselines are relative)."""
    from evaluation.stitch.synthetic import SyntheticWall, TelemetryErrors, reported_pose, wall_frame

    along, out, up = (float(v) for v in position)
    frame = wall_frame(SyntheticWall(length_m=12.0, height_m=3.0))  # any wall: only its site and heading matter
    return reported_pose(np.random.default_rng(0), frame, (along, out, up, 0.0, 0.0), TelemetryErrors(), index,
                         time_s=index / 10.0)


def _parallax_maskers(sessions: dict[str, DepthSession], rules: list[str], params: dict, fx: float, width: int,
                      standoff_m: float) -> dict[tuple[str, str], Masker]:
    """One onboard masker per (model, ROI rule, parallax label, flow skipped where the network is sure or not),
    each with its own frame history, as the chain builds it (``SequenceParallax`` with the mission's standoff)."""
    from companion.depth.parallax import SequenceParallax

    hfov = float(np.degrees(2 * np.arctan(width / 2 / fx)))
    out = {}
    for m, session in sessions.items():
        for r in rules:
            for w, pp in params.items():
                for tag in ("", " sure skipped"):
                    judged = pp if tag else replace(pp, sure_wall_standoffs=None)  # "": every frame judged
                    out[(m, f"{r}+parallax@{w}{tag}")] = Masker(
                        session=session, params=ROI_RULES[r],
                        parallax=SequenceParallax(hfov, judged, standoff_m=standoff_m))
    return out


def evaluate_pass(frames, sessions: dict[str, DepthSession], rules: list[str], save: Path | None,
                  parallax: dict | None = None, facade_poses: bool = True):
    """Run every model once per frame and every ROI rule on its disparity; MaskEval per (model, rule).

    With ``parallax`` (label -> ParallaxParams): also each (model, rule) masked by the onboard masker with motion
    parallax (``Masker.mask_disparity`` on the same network output: each label's flow width and rules), frames in
    capture order with exact telemetry (``facade_pose``; ``facade_poses=False``, the simulator's recordings: no
    pose, so the network alone, as their frames are a metre apart), once judging every frame and once skipping the
    frames the network is sure of (``network_is_sure``) as the chain does; and parallax alone (model "-",
    untrusted pixels background).
    """
    from companion.depth.parallax import (
        camera_translation,
        dense_flow,
        depth_from_flow,
        fuse_with_network,
        pick_reference,
    )
    from companion.records import Frame, TaggedFrame

    maskers = {(m, r): Masker(session=s, params=ROI_RULES[r]) for m, s in sessions.items() for r in rules}
    evals = {key: MaskEval(recording=f"{key[0]} / {key[1]}") for key in maskers}
    params = parallax or {}
    for m, r in list(maskers):
        for w in params:
            for tag in ("", " sure skipped"):
                evals[(m, f"{r}+parallax@{w}{tag}")] = MaskEval(recording=f"{m} / {r}+parallax@{w}{tag}")
    if params:
        evals[("-", "parallax alone")] = MaskEval(recording="parallax alone")
    onboard: dict[tuple[str, str], Masker] = {}
    history: list[tuple[np.ndarray, np.ndarray]] = []  # (image, camera position) of recent frames: parallax alone
    for i, image, truth, (pos, R, fx, standoff_m) in frames:
        if params and not onboard:
            onboard = _parallax_maskers(sessions, rules, params, fx, image.shape[1], standoff_m)
        if params:
            first = next(iter(params.values()))
            k = pick_reference([h[1] for h in history], pos, first) if fx else None
            zero = np.zeros(image.shape[:2], np.uint8)
            alone, dropped = zero, False
            if k is not None:
                t = camera_translation(R, history[k][1], R, pos)
                alone, dropped = fuse_with_network(zero, depth_from_flow(dense_flow(history[k][0], image, first), t,
                                                                         fx, first, standoff_m))
            history = (history + [(image, pos)])[-12:]
            evals[("-", "parallax alone")].frames.append(frame_eval(i, truth, np.zeros((8, 8), np.float32),
                                                                    _as_roi(alone, dropped)))
        tagged = TaggedFrame(Frame(i, i / 10.0, image), facade_pose(i, pos) if facade_poses else None)
        for model, session in sessions.items():
            t0 = time.perf_counter()
            disp = session.disparity(image)
            depth_ms = (time.perf_counter() - t0) * 1e3
            for rule in rules:
                masker = maskers[(model, rule)]
                t1 = time.perf_counter()
                roi = masker.roi_from_disparity(disp, image.shape[:2])
                ev = frame_eval(i, truth, disp, roi, depth_ms=depth_ms, mask_ms=(time.perf_counter() - t1) * 1e3)
                evals[(model, rule)].frames.append(ev)
                for key, seq in onboard.items():
                    if key[0] == model and key[1].startswith(f"{rule}+"):
                        masked, own = seq.mask_disparity(tagged, disp)
                        mask = own.mask if masked is not None else np.zeros(image.shape[:2], np.uint8)
                        evals[key].frames.append(frame_eval(i, truth, disp, _as_roi(mask, masked is None)))
                if save is not None and i % 10 == 0:
                    save_visual(save / f"{Path(model).stem}_{rule}" / f"{i:04d}.jpg", image, disp, roi.mask, truth)
    skipped = {key: (seq.stats.parallax_skipped_sure if "sure skipped" in key[1] else 0)
               for key, seq in onboard.items()}
    return evals, skipped


def _as_roi(mask: np.ndarray, dropped: bool):
    """A fused mask in the RoiResult shape frame_eval reads (disparity statistics do not apply)."""
    from companion.depth.roi import RoiResult

    share = float(np.count_nonzero(mask)) / mask.size
    return RoiResult(mask, dropped, share == 1.0, share, 0, 0, float("nan"), float("nan"), float("nan"))


def print_table(name: str, evals: dict, skipped: dict) -> list[dict]:
    print(f"\n{name}: model / ROI rule | error mean / p95 | wall-only frames: error | facade lost | background kept "
          f"(mixed frames) | all-background frames dropped | wrongly dropped (frames with wall)")
    rows = []
    for (model, rule), ev in evals.items():
        s = ev.summary()
        s.update(model=model, rule=rule, pass_name=name, flow_skipped_sure=skipped.get((model, rule), 0))
        rows.append(s)
        print(f"  {Path(model).name} / {rule} | {100 * s['error_mean']:.2f} % / {100 * s['error_p95']:.2f} % | "
              f"{100 * s['error_wall_only_mean']:.2f} % ({s['wall_only_frames']}) | "
              f"{100 * s['facade_lost_mean']:.1f} % | {100 * s['background_kept_mixed_mean']:.1f} % "
              f"({s['mixed_frames']}) | {s['dropped_empty'] - s['dropped_with_facade']} of {s['true_empty']} | "
              f"{s['dropped_with_facade']} (most wall {100 * s['dropped_with_facade_max_share']:.1f} %) | "
              f"{s['frames']} frames, depth {s['depth_ms_median']:.0f} ms median"
              + (f", flow skipped on {s['flow_skipped_sure']} (network sure)" if "sure skipped" in rule else ""))
    return rows


def main() -> None:
    from sim.camera.photo_passes import DEFAULT_PASSES

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", nargs="+", default=[str(DEFAULT_MODEL)], help="ONNX models, side by side")
    ap.add_argument("--passes", nargs="+", default=[*DEFAULT_PASSES, "sim"],
                    help="named passes, 'sim', or NAME:WALL_PHOTO:WALL_WIDTH_M:BACKGROUND_PHOTO[:DISTANCE_M] with "
                         "photos by file name in ../shared/data (held-out only) or by path (your own photos)")
    ap.add_argument("--roi", nargs="+", default=["default"], choices=sorted(ROI_RULES), help="ROI rules to compare")
    ap.add_argument("--bg-distance", type=float, default=None, help="override every pass's background distance (m)")
    ap.add_argument("--frames", type=int, default=250)
    ap.add_argument("--background-frames", type=int, default=22, help="frames past the wall's end (no wall)")
    ap.add_argument("--sim-seeds", nargs="+", type=int, default=[100, 101])
    ap.add_argument("--sim-stride", type=int, default=1)
    ap.add_argument("--data", default="/tmp/companion-depth-eval", help="where simulator recordings are cached")
    ap.add_argument("--threads", type=int, default=None)
    ap.add_argument("--parallax", action="store_true",
                    help="also correct each mask by motion parallax with the true camera positions as telemetry")
    ap.add_argument("--parallax-widths", nargs="+", type=int, default=[ParallaxParams().work_width],
                    help="working widths of the flow to compare (with --parallax)")
    ap.add_argument("--parallax-rules", nargs="+", default=["default"], choices=sorted(PARALLAX_RULES),
                    help="parallax rule sets to compare (with --parallax): 'fixed-15m' is the rule before issue 13's "
                         "wall-ratio far rule, plain-pixel calibration and strip-safe drop rule")
    ap.add_argument("--save", default=None, help="folder for frame | disparity | mask | truth pictures (every 10th)")
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    sessions = {m: DepthSession(m, threads=args.threads) for m in args.model}
    parallax = {}
    if args.parallax:
        for w in args.parallax_widths:
            for rule in args.parallax_rules:
                label = f"{w}" if args.parallax_rules == ["default"] else f"{w} {rule}"
                parallax[label] = replace(PARALLAX_RULES[rule], work_width=w)
    rows = []
    t0 = time.perf_counter()
    for name in args.passes:
        frames = sim_frames(args) if name == "sim" else photo_pass_frames(name, args)
        save = Path(args.save) / name if args.save else None
        rows += print_table(name, *evaluate_pass(frames, sessions, args.roi, save, parallax, name != "sim"))
    print(f"\nmachine: {platform.machine()} {os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f}; "
          f"{time.perf_counter() - t0:.0f} s")
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()

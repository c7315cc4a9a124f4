"""Where the shipped mask loses wall on the real-texture passes, keyframe by keyframe, and what the map can cover.

Usage: python bench/mask_wall_coverage.py [--passes NAME ...] [--model sim] [--rules before-borders default]
       [--frames 80] [--width-px 640] [--save DIR]

Each pass (``sim/camera/photo_passes.py``: held-out photos only) is rendered as ``bench/stitch_eval.py --passes``
renders it (80 frames, 640 px), every frame masked by the onboard ``Masker`` with parallax (true relative
telemetry) once per parallax rule set (``PARALLAX_RULES``: ``before-borders`` is main's before the mask-wall change),
and the gate keeps the keyframes it keeps with that mask (``stitch_photo_passes.gate_pass``). A frame the network alone
had to judge (a strip's first: no frame behind it) is masked again against the next frame, as the onboard chain does
(``companion.depth.parallax_first``, issue 15); each rule set is also reported as ``RULE-network-first`` with those
frames' network-alone masks (main before issue 15), side by side on the same frames. Per rule set it prints

* mask error over all frames, background-only frames dropped, frames with wall dropped;
* on the keyframes: the share of their wall the mask cuts and of their background it keeps;
* the wall cut, as a share of the keyframes' wall, by band (top / middle / bottom fifth of the frame) and by what
  decided it: ``network alone`` (no parallax answer: the first frame of a strip, or the network was sure), ``untrusted``
  (parallax had no trusted flow there: plain pixels), ``parallax`` (trusted flow called the wall far), ``other``
  (the fusion's smoothing);
* **the seen wall the keyframes' masks cover**: every keyframe's mask laid on the wall with the true geometry, their
  union against the wall the frames saw (the labels' facade). This is the map's coverage before the stitcher
  (registration, the wall check's cuts and give-back): an upper bound for ``bench/stitch_eval.py``'s coverage.

``--save DIR``: per keyframe a picture (frame | wall cut red, background kept blue / network disparity | parallax
near green, far red over the network's mask) and per pass the wall left uncovered (red on the wall photo).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))


def render(name: str, frames: int, width: int):
    """The pass's renderer as bench/stitch_eval.py builds it (no gate yet)."""
    from checkout import use_checkout_shared_data
    from stitch_photo_passes import RenderedPass

    from sim.camera.model import CameraModel
    from sim.camera.photo_passes import RECIPES, build_pass
    from sim.camera.photo_scene import PhotoPassRenderer

    background_frames = max(2, round(frames * 22 / 250))
    if name in RECIPES:
        spec = build_pass(RECIPES[name], root=use_checkout_shared_data(),
                          frames=frames, background_frames=background_frames)
    else:  # a validation pass of training-split photos (bench/depth_error_regions.py): rules are chosen there
        spec = validation_spec(name, frames, background_frames)
    cam = spec.camera
    spec = replace(spec, camera=CameraModel(width, round(cam.height * width / cam.width), cam.hfov_deg))
    r = PhotoPassRenderer(spec)
    ups = [p[1] for p in r.positions]
    strips = sorted(set(ups))
    return RenderedPass(name, spec, r, [], [], [], [strips.index(u) for u in ups])


def validation_spec(name: str, frames: int, background_frames: int):
    """The PhotoPass of one of bench/depth_error_regions.py's validation passes (training-split photos only)."""
    from depth_error_regions import validation_spec as spec_of

    return spec_of(name, frames, background_frames)


class _Recorder:
    """A SequenceParallax whose every answer is kept (None: no reference), for the per-stage split."""

    def __init__(self, seq):
        self.seq = seq
        self.last = "sure"
        update = seq.update

        def recorded(image, pose):
            self.last = update(image, pose)
            return self.last

        seq.update = recorded


NETWORK_FIRST = "-network-first"  # suffix of a rule set's figures with main's first frames (network alone)


def mask_pass(rp, model: str, rules: list[str]):
    """Every frame masked by one Masker per rule set (frames in capture order, exact relative telemetry), a frame
    the network alone had to judge (a strip's first: no reference) held and masked again against the next frame
    far enough along the baseline (``companion.depth.parallax_first``, as the onboard chain does with its
    keyframes); returns per rule {frame: (mask or None, network mask, parallax answer or "sure" or None, network
    disparity)}, the same per rule + ``NETWORK_FIRST`` with those frames' network-alone masks (main's path), and the
    frames' truth."""
    from stitch_photo_passes import SyntheticWall, TelemetryErrors, reported_pose, wall_frame

    from companion.depth.masker import Masker
    from companion.depth.parallax import SequenceParallax
    from companion.depth.parallax_first import LaterReference, judged_alone, reference_mark
    from companion.depth.session import DepthSession
    from companion.records import Frame, TaggedFrame
    from evaluation.depth.parallax_rules import PARALLAX_RULES

    spec = rp.spec
    session = DepthSession(model)
    maskers, recorders, later = {}, {}, {}
    for rule in rules:
        seq = SequenceParallax(spec.camera.hfov_deg, PARALLAX_RULES[rule])
        recorders[rule] = _Recorder(seq)
        maskers[rule] = Masker(session=session, parallax=seq)
        later[rule] = LaterReference(maskers[rule])
    frame = wall_frame(SyntheticWall(length_m=spec.wall.width_m, height_m=spec.wall.height_m))
    rng = np.random.default_rng(0)
    out = {label: {} for rule in rules for label in (rule, rule + NETWORK_FIRST)}
    truth = {}
    for i in range(len(rp.renderer)):
        f = rp.renderer.render(i)
        truth[i] = f.roi_mask > 0
        pose = reported_pose(rng, frame, (f.along_m, spec.standoff_m, f.up_m, 0.0, 0.0), TelemetryErrors(), i,
                             time_s=i / 10.0)
        tagged = TaggedFrame(Frame(i, i / 10.0, f.image), pose)
        for rule in rules:
            recorders[rule].last = "sure"
            mark = reference_mark(maskers[rule])
            masked, _, disp = maskers[rule].mask_measured(tagged)
            net = maskers[rule].roi_from_disparity(disp, f.image.shape[:2]).mask
            entry = (None if masked is None else masked.mask, net, recorders[rule].last, disp)
            out[rule][i] = out[rule + NETWORK_FIRST][i] = entry
            for r in later[rule].offer(tagged):
                if r.judgement is None:  # the next frame was already beyond the baseline's reach: network alone
                    continue
                j = r.tagged.frame.index
                _, net_j, _, disp_j = out[rule][j]
                out[rule][j] = (None if r.masked is None else r.masked.mask, net_j, r.judgement.parallax, disp_j)
            if judged_alone(maskers[rule], mark, tagged):
                later[rule].hold(tagged, masked)
    for rule in rules:
        later[rule].release()  # still held at the end: they keep the network's mask (already in ``out``)
    return out, truth


def seen_wall_covered(rp, keyframes: list[int], masks: dict[int, np.ndarray], res_m: float = 0.02):
    """The share of the wall the keyframes saw (labels' facade inside their footprints) that their masks keep, laid
    on the wall with the true geometry; and the two grids (seen, covered) for a picture."""
    r = rp.renderer
    wall = rp.spec.wall
    gw, gh = int(wall.width_m / res_m), int(wall.height_m / res_m)
    grid_to_wall = np.array([[res_m, 0, 0.5 * res_m], [0, -res_m, wall.height_m - 0.5 * res_m], [0, 0, 1]])
    seen = np.zeros((gh, gw), bool)
    covered = np.zeros((gh, gw), bool)
    flags = cv2.INTER_NEAREST | cv2.WARP_INVERSE_MAP
    for i in keyframes:
        f = r.render(i)
        to_image = (np.linalg.inv(f.wall_from_image) @ grid_to_wall)[:2]
        on_wall = cv2.warpAffine(f.roi_mask, to_image, (gw, gh), flags=flags, borderValue=0) > 0
        mask = masks[i] if masks[i] is not None else np.zeros_like(f.roi_mask)
        kept = cv2.warpAffine(mask, to_image, (gw, gh), flags=flags, borderValue=0) > 0
        seen |= on_wall
        covered |= kept & on_wall
    return float(covered.sum()) / max(1, int(seen.sum())), seen, covered


def _stage_of_cut(par, shape):
    """Per pixel, what decided a wall pixel was cut (bool maps): ``network alone`` (no parallax answer: no
    reference, or the network was sure), ``untrusted``, ``parallax`` (trusted far), ``other`` (smoothing)."""
    h, w = shape
    if par is None or isinstance(par, str):
        return {"network alone": np.ones(shape, bool)}

    def full(a):
        return cv2.resize(a.astype(np.uint8), (w, h), interpolation=cv2.INTER_NEAREST) > 0
    trusted, far = full(par.trusted), full(par.far)
    return {"parallax": far, "untrusted": ~trusted, "other": trusted & ~far}


def report(rp, rule: str, masks: dict, truth: dict, save: Path | None) -> dict:
    """One rule set's figures on one pass (module docstring), printed and returned."""
    from stitch_photo_passes import gate_pass

    final = {i: m for i, (m, _, _, _) in masks.items()}
    gated = gate_pass(rp, final)
    kf = gated.keyframes
    errs, bg_frames, bg_dropped, wall_dropped = [], 0, 0, []
    for i, t in truth.items():
        m = final[i] > 0 if final[i] is not None else np.zeros_like(t)
        errs.append(float((m != t).mean()))
        if not t.any():
            bg_frames += 1
            bg_dropped += final[i] is None
        elif final[i] is None:
            wall_dropped.append(i)
    wall = cut = bg = kept = 0
    parts: dict[str, float] = {}
    for i in kf:
        t = truth[i]
        m = final[i] > 0 if final[i] is not None else np.zeros_like(t)
        lost = t & ~m
        wall += int(t.sum())
        cut += int(lost.sum())
        bg += int((~t).sum())
        kept += int((~t & m).sum())
        h = t.shape[0]
        rows = np.arange(h)[:, None]
        bands = {"top": rows < h // 5, "middle": (rows >= h // 5) & (rows < h - h // 5), "bottom": rows >= h - h // 5}
        stages = _stage_of_cut(masks[i][2], t.shape)
        for b, sel in bands.items():
            for s, where in stages.items():
                n = int((lost & sel & where).sum())
                if n:
                    parts[f"{b} {s}"] = parts.get(f"{b} {s}", 0) + n
        if save is not None:
            _picture(save / f"{rp.name}-{rule}-kf{i:03d}.png", rp.renderer.render(i).image, t, m, masks[i])
    covered, seen, cov = seen_wall_covered(rp, kf, {i: final[i] for i in kf})
    if save is not None:
        tex = cv2.resize(rp.spec.wall.image, seen.shape[::-1])
        tex[seen & ~cov] = (0, 0, 255)
        tex[~seen] //= 3
        cv2.imwrite(str(save / f"{rp.name}-{rule}-uncovered.png"), tex)
    out = {"pass": rp.name, "rule": rule, "error_mean": 100 * float(np.mean(errs)),
           "background_dropped": f"{bg_dropped} of {bg_frames}", "frames_with_wall_dropped": wall_dropped,
           "keyframes": len(kf), "keyframe_wall_cut": 100 * cut / max(1, wall),
           "keyframe_background_kept": 100 * kept / max(1, bg), "seen_wall_covered": 100 * covered,
           "cut_by_part": {k: round(100 * v / max(1, wall), 2)
                           for k, v in sorted(parts.items(), key=lambda kv: -kv[1])}}
    print(f"{rp.name} / {rule}: mask error {out['error_mean']:.2f} %; background-only frames dropped "
          f"{out['background_dropped']}; frames with wall dropped {wall_dropped}; {len(kf)} keyframes: wall cut "
          f"{out['keyframe_wall_cut']:.1f} %, background kept {out['keyframe_background_kept']:.1f} %; seen wall "
          f"covered by the keyframes' masks {out['seen_wall_covered']:.2f} %", flush=True)
    print(f"   wall cut by band and stage (% of the keyframes' wall): {out['cut_by_part']}", flush=True)
    return out


def _picture(path: Path, image, truth, mask, entry) -> None:
    _, net, par, disp = entry
    h, w = truth.shape
    v = image.copy()
    v[truth & ~mask] = (0, 0, 255)
    v[~truth & mask] = (255, 0, 0)
    v = cv2.addWeighted(image, 0.4, v, 0.6, 0)
    d = cv2.resize(np.squeeze(disp), (w, h))
    d = cv2.applyColorMap((255 * d / max(float(d.max()), 1e-6)).astype(np.uint8), cv2.COLORMAP_VIRIDIS)
    p = np.zeros((h, w, 3), np.uint8)
    if par is not None and not isinstance(par, str):
        p[cv2.resize(par.near.astype(np.uint8), (w, h), interpolation=cv2.INTER_NEAREST) > 0] = (0, 255, 0)
        p[cv2.resize(par.far.astype(np.uint8), (w, h), interpolation=cv2.INTER_NEAREST) > 0] = (0, 0, 255)
    p = cv2.addWeighted(p, 0.6, np.dstack([net] * 3), 0.4, 0)
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), np.vstack([np.hstack([image, v]), np.hstack([d, p])]))


def main() -> None:
    from evaluation.depth.parallax_rules import PARALLAX_RULES
    from sim.camera.photo_passes import DEFAULT_PASSES

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--passes", nargs="+", default=list(DEFAULT_PASSES),
                    help="held-out passes (sim/camera/photo_passes.py) or bench/depth_error_regions.py's validation "
                         "passes of training-split photos (val-b0309-120, val-b0169-40, val-coruna-120, "
                         "val-montana-40)")
    ap.add_argument("--model", default="sim")
    ap.add_argument("--rules", nargs="+", default=["before-borders", "default"], choices=sorted(PARALLAX_RULES))
    ap.add_argument("--frames", type=int, default=80)
    ap.add_argument("--width-px", type=int, default=640)
    ap.add_argument("--save", default=None)
    args = ap.parse_args()
    save = Path(args.save) if args.save else None
    t0 = time.process_time()
    for name in args.passes:
        rp = render(name, args.frames, args.width_px)
        masks, truth = mask_pass(rp, args.model, args.rules)
        for rule in args.rules:
            for label in (rule + NETWORK_FIRST, rule):  # main's first frames, then judged by a later frame
                report(rp, label, masks[label], truth, save)
    print(f"{time.process_time() - t0:.0f} s CPU, load average {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()

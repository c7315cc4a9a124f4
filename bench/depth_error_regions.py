"""Where the mask is wrong on the real-texture passes, and which stage decided it (issue 13's diagnosis).

Usage: python bench/depth_error_regions.py [--model real-nc] [--passes NAME ...] [--frames 100]
       [--background-frames 12] [--variants today ratio] [--json OUT]

Every frame of each pass is masked as the onboard chain does (network + ROI rules, then motion parallax with the
true camera positions as telemetry, the flow skipped where the network is sure), once per parallax variant
(``VARIANTS``: today's fixed 15 m near limit against the far rule and drop rule that follow the wall's own flow),
all on the same frames and network output. Each wrong pixel (evaluated at 480 px) is counted by

* what it is: wall lost (a true wall pixel cut) or background kept;
* where it is: ``edge`` (within 3 % of the frame width of the true wall/background outline: the wall's end, the
  roof line, the edge of a window hole), ``top`` (top fifth of the frame, away from the outline), ``interior``;
* which stage decided it: ``drop`` (the whole frame dropped), ``network`` (no parallax: no reference frame or the
  network was sure), ``in view`` (a frame about to be dropped kept the strip of wall the last kept frame showed),
  ``untrusted`` (parallax had no trusted flow there: the network's answer stands),
  ``parallax`` (trusted flow said near on background or far on wall), ``smoothing`` (the fusion's median and
  resize flipped a pixel both sources had right).

It prints shares of all pixels of the pass (so the columns add up to the mean error) and every frame with wall
that was dropped, with its wall share.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from collections import defaultdict
from dataclasses import dataclass, field, replace
from pathlib import Path

import cv2
import numpy as np

from companion.depth.masker import Masker
from companion.depth.parallax import (
    ParallaxParams,
    PlainRule,
    camera_translation,
    carried_wall,
    dense_flow,
    depth_from_flow,
    fuse_with_network,
    keep_wall_in_view,
    kept_wall,
    network_is_sure,
    pick_reference,
    wall_depth_of,
)
from companion.depth.session import DepthSession
from evaluation.depth.parallax_rules import PARALLAX_RULES

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # the bench.* modules it borrows from, run as a script

EVAL_WIDTH = 480
VARIANTS: dict[str, ParallaxParams] = {
    "today": PARALLAX_RULES["fixed-15m"],
    "ratio": ParallaxParams(plain_rule=PlainRule.NETWORK, wall_in_view_rule=False),
    "ratio+continuity": ParallaxParams(plain_rule=PlainRule.CONTINUITY, wall_in_view_rule=False),
    "ratio+calibrated": ParallaxParams(wall_in_view_rule=False),
    "ratio+calibrated+in-view": ParallaxParams(wall_in_view_rule=True),
}


# Validation passes: TRAINING-split photos only (the held-out passes of sim/camera/photo_passes.py report figures;
# these choose thresholds). Same geometry as the held-out passes: 4 m standoff, strips along the wall, off its end.
VALIDATION = {
    "val-b0309-120": ("cmp_b0309.jpg", 16.0, "static_outdoor_street_city_cambridge_uk__IMG_8765.jpg", 120.0,
                      (0.45, 0.9)),
    "val-b0169-40": ("cmp_b0169.jpg", 14.0, "static_boston_street_april__p1010115.jpg", 40.0, (0.55, 0.88)),
    "val-coruna-120": ("static_outdoor_urban_city_street_coruna_spain__IMG_7792.jpg", 12.0,
                       "static_outdoor_urban_city_street_boston__IMG_6384.jpg", 120.0, (0.5,)),
    "val-montana-40": ("cmp_b0309.jpg", 16.0, "static_outdoor_montana_usa__IMG_9727.jpg", 40.0, (0.55, 0.88)),
}


def validation_spec(name: str, frames: int, background_frames: int):
    """The PhotoPass of one validation pass (training-split photos only: a figure on them is never a held-out one)."""
    from checkout import use_checkout_shared_data

    from companion.depth.training.realdata import facade_mask, list_real_photos, load_image
    from sim.camera.photo_scene import PhotoPass, PhotoTexture

    wall_name, width_m, bg_name, distance_m, strips = VALIDATION[name]
    photos = {p.image.name: p for p in list_real_photos(use_checkout_shared_data())}
    for n in (wall_name, bg_name):
        if photos[n].split != "train":
            raise SystemExit(f"{n} is held out: validation passes use training photos only")
    wall = PhotoTexture(wall_name, load_image(photos[wall_name]), width_m, facade_mask(photos[wall_name]))
    background = PhotoTexture(bg_name, load_image(photos[bg_name]), 1.0)
    spec = PhotoPass(name, wall, background, background_distance_m=distance_m, frames=frames,
                     background_frames=background_frames)
    return replace(spec, strips_up_m=tuple(f * wall.height_m for f in strips))


def validation_pass_frames(name: str, args):
    """Frames of a validation pass, in the shape ``bench.depth_real_passes.photo_pass_frames`` yields."""
    from bench.depth_real_passes import rendered_pass_frames

    spec = validation_spec(name, args.frames, args.background_frames)
    wall_name, width_m, bg_name, distance_m, _ = VALIDATION[name]
    print(f"pass {name} (validation, training photos): wall {wall_name} {width_m:.0f} m, background {bg_name} at "
          f"{distance_m:.0f} m, {spec.frames} frames")
    yield from rendered_pass_frames(spec)


def _region_masks(truth: np.ndarray) -> dict[str, np.ndarray]:
    wall = truth > 127
    h, w = wall.shape
    band = max(1, int(round(0.03 * w)))
    outline = cv2.morphologyEx(wall.astype(np.uint8), cv2.MORPH_GRADIENT, np.ones((3, 3), np.uint8)) > 0
    near_outline = cv2.dilate(outline.astype(np.uint8), np.ones((2 * band + 1, 2 * band + 1), np.uint8)) > 0
    top = np.zeros_like(wall)
    top[: h // 5] = True
    return {"edge": near_outline, "top": top & ~near_outline, "interior": ~near_outline & ~top}


def _drop_evidence(i: int, wall_share: float, network_mask: np.ndarray, par, dropped: bool, net_depth) -> dict:
    """What the drop rule saw on one frame: trusted share, near share, largest near component, plain kept."""
    from companion.depth.parallax import plain_vote

    net = plain_vote(network_mask, par, net_depth)
    n, _, stats, _ = cv2.connectedComponentsWithStats(par.near.astype(np.uint8), connectivity=4)
    largest = int(stats[1:, cv2.CC_STAT_AREA].max()) if n > 1 else 0
    return {"frame": i, "wall": round(wall_share, 4), "trusted": round(par.trusted_share, 4),
            "near": round(float(par.near.mean()), 4), "near_largest": round(largest / par.near.size, 4),
            "plain_kept": round(float((net[~par.trusted] >= 0.5).sum()) / net.size, 4), "dropped": dropped}


def _small(a: np.ndarray, h: int, w: int) -> np.ndarray:
    return cv2.resize(a.astype(np.uint8), (w, h), interpolation=cv2.INTER_NEAREST) > 0


@dataclass
class _VariantTally:
    """One parallax variant's running figures over a pass."""

    counts: defaultdict = field(default_factory=lambda: defaultdict(float))
    dropped_wall: list = field(default_factory=list)  # (frame, wall %) of frames with wall that were dropped
    per_frame: list = field(default_factory=list)  # the drop rule's evidence per frame parallax judged
    background_dropped: int = 0
    kept: object = None  # the last kept frame's wall (KeptWall)


def _mask_one_variant(pp: ParallaxParams, tally: _VariantTally, roi, par, net_depth, frame, standoff_m: float):
    """The mask one variant gives a frame: (full-size mask, dropped, stage_map or None, rescued by the carried wall)."""
    i, image, wall_share, (pos, R, fx) = frame
    in_view = carried_wall(tally.kept, pos, R, fx, image.shape[1], pp)
    if par is None:
        full, dropped, stage_map = roi.mask, roi.empty, None
    else:
        full, dropped = fuse_with_network(roi.mask, par, net_depth, image)
        h, w = _eval_size(image)
        stage_map = (_small(par.near, h, w), _small(par.far, h, w), _small(par.trusted, h, w))
        tally.per_frame.append(_drop_evidence(i, wall_share, roi.mask, par, dropped, net_depth))
    rescued = dropped or not full.any()
    full, dropped = keep_wall_in_view(full, dropped, in_view, par, pp)
    rescued = rescued and not dropped
    if rescued:
        stage_map = None  # the carried strip decided this frame
    if not dropped and full.any():
        wall_m = tally.kept.wall_depth_m if rescued else wall_depth_of(par, standoff_m)
        tally.kept = kept_wall(full, pos, wall_m, pp)
    return full, dropped, stage_map, rescued


def _wrong_by_stage(wrong, tr, net, dropped: bool, rescued: bool, stage_map) -> dict[str, np.ndarray]:
    """The wrong pixels split by the stage that decided them (module docstring)."""
    if stage_map is None:
        return {"drop" if dropped else ("in view" if rescued else "network"): wrong}
    near, far, trusted = stage_map
    par_wrong = (near & ~tr) | (far & tr)
    stages = {"drop": wrong if dropped else np.zeros_like(wrong)}
    if not dropped:
        stages["parallax"] = wrong & par_wrong
        stages["untrusted"] = wrong & ~trusted & (net != tr)
        stages["smoothing"] = wrong & ~par_wrong & ~(~trusted & (net != tr))
    return stages


def _eval_size(image: np.ndarray) -> tuple[int, int]:
    return int(round(image.shape[0] * EVAL_WIDTH / image.shape[1])), EVAL_WIDTH


def evaluate_pass(name: str, args, session: DepthSession, masker: Masker) -> tuple[dict[str, _VariantTally], int, int]:
    """Mask every frame of one pass once per variant; returns the tallies, background-only frames and pixels."""
    from bench.depth_real_passes import photo_pass_frames

    tallies = {v: _VariantTally() for v in args.variants}
    bg_frames = n_px = 0
    history: list[tuple[np.ndarray, np.ndarray]] = []
    frames = validation_pass_frames(name, args) if name in VALIDATION else photo_pass_frames(name, args)
    for i, image, truth, (pos, R, fx, standoff_m) in frames:
        h, w = _eval_size(image)
        tr = _small(truth > 127, h, w)
        regions = {k: _small(m, h, w) for k, m in _region_masks(truth).items()}
        n_px += tr.size
        disp = session.disparity(image)
        roi = masker.roi_from_disparity(disp, image.shape[:2])
        net = _small(roi.mask > 127, h, w)
        sure = network_is_sure(roi, session.info, standoff_m)
        k = pick_reference([p for _, p in history], pos, ParallaxParams())
        flow_pair = None if k is None else (history[k][0], camera_translation(R, history[k][1], R, pos))
        history = (history + [(image, pos)])[-12:]
        bg_frames += not tr.any()
        flow = None
        net_depth = session.info.depth_from_disparity(np.squeeze(disp))
        for v, tally in tallies.items():
            pp = VARIANTS[v]
            par = None
            if flow_pair is not None and not sure:
                flow = dense_flow(flow_pair[0], image, pp) if flow is None else flow
                par = depth_from_flow(flow, flow_pair[1], fx, pp, standoff_m)
            full, dropped, stage_map, rescued = _mask_one_variant(
                pp, tally, roi, par, net_depth, (i, image, float(tr.mean()), (pos, R, fx)), standoff_m)
            final = np.zeros_like(tr) if dropped else _small(full > 127, h, w)
            if dropped and tr.any():
                tally.dropped_wall.append((i, round(100 * float(tr.mean()), 2)))
            tally.background_dropped += (not tr.any()) and dropped
            wrong = final != tr
            for kind, sel in (("wall lost", tr), ("background kept", ~tr)):
                for reg, rm in regions.items():
                    for st, sm in _wrong_by_stage(wrong, tr, net, dropped, rescued, stage_map).items():
                        c = float(np.count_nonzero(sm & sel & rm))
                        if c:
                            tally.counts[(kind, reg, st)] += c
            tally.counts[("total", "", "")] += float(np.count_nonzero(wrong))
    return tallies, bg_frames, n_px


def report_pass(name: str, model: str, tallies: dict[str, _VariantTally], bg_frames: int, n_px: int) -> dict:
    """Print one pass's figures per variant (shares of all pixels) and return them for the JSON report."""
    out = {}
    for v, t in tallies.items():
        c = t.counts
        total = 100 * c[("total", "", "")] / n_px
        print(f"\n{name} / {model} / {v}: mean error {total:.2f} %; background-only frames dropped "
              f"{t.background_dropped} of {bg_frames}; frames with wall dropped {len(t.dropped_wall)} "
              f"(frame, wall %): {t.dropped_wall}")
        rows = sorted(((100 * n / n_px, key) for key, n in c.items() if key[0] != "total"), reverse=True)
        for share, (kind, reg, st) in rows:
            if share >= 0.05:
                print(f"   {share:5.2f} %  {kind:15s} {reg:8s} {st}")
        out[v] = {"error_mean": total, "background_dropped": t.background_dropped, "background_frames": bg_frames,
                  "dropped_with_wall": t.dropped_wall, "frames": t.per_frame,
                  "breakdown": {" / ".join(k): 100 * n / n_px for k, n in c.items() if k[0] != "total"}}
    return out


def main() -> None:
    from sim.camera.photo_passes import DEFAULT_PASSES

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", default="real-nc")
    ap.add_argument("--passes", nargs="+", default=list(DEFAULT_PASSES),
                    help=f"held-out passes (sim/camera/photo_passes.py) or validation passes {sorted(VALIDATION)}")
    ap.add_argument("--frames", type=int, default=100)
    ap.add_argument("--background-frames", type=int, default=12)
    ap.add_argument("--bg-distance", type=float, default=None)
    ap.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=sorted(VARIANTS))
    ap.add_argument("--threads", type=int, default=None)
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    session = DepthSession(args.model, threads=args.threads)
    masker = Masker(session=session)
    t0 = time.perf_counter()
    report = {name: report_pass(name, args.model, *evaluate_pass(name, args, session, masker))
              for name in args.passes}
    print(f"\n{time.perf_counter() - t0:.0f} s, load average {os.getloadavg()[0]:.1f}")
    if args.json:
        Path(args.json).write_text(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()

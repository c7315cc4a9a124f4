"""Keyframe gate on real-texture passes (issue 15): held-out real facade photos on the simulator's wall plane at 4 m,
held-out real outdoor photos 120 m behind (40 m on one pass), the camera flying along the wall and off its end
(``sim/camera/photo_passes.py``, exact truth). Images-only gate (today's, and the paper's) side by side with the
telemetry gate, with the truth mask, with no mask (``--no-mask`` onboard) and with the shipped depth model's mask.

    python bench/gate_photo_passes.py                       # every pass, masks truth,none,model, both gates
    python bench/gate_photo_passes.py --passes ornate-entry --masks none --frames 120
    python bench/gate_photo_passes.py --masks sim,real-nc --gates telemetry   # the shipped masks, with parallax

Truth, two definitions, both printed: "plane" = share of frame a's footprint on the wall PLANE that frame b's
covers (what Eq. 2 measures, the simulator's ``true_overlap``; used for the minimum keyframe count), and
"visible wall" = share of the wall pixels of a that b also sees (labels cut sky and neighbours out of the wall),
over pairs where a shows wall. Telemetry: the true camera positions (facade frame of a site in Seoul, yaw facing
the wall), optionally with --pose-noise as in bench/gate_eval.py.
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import types
from dataclasses import replace

import numpy as np

from companion.errors import CompanionError
from companion.keyframes.features import FeatureConfig
from companion.keyframes.gate import GateConfig
from companion.keyframes.motion import WallMotionPredictor
from evaluation.keyframes.evaluate import PoseNoise, evaluate_gate, format_table, telemetry_poses
from evaluation.keyframes.synthetic import SITE


class PhotoPassRecording:
    """The duck-typed recording interface of evaluation.keyframes.evaluate over a rendered photo pass."""

    def __init__(self, renderer, fps: float = 10.0):
        self.r = renderer
        cam = renderer.spec.camera
        self.width, self.height = cam.width, cam.height
        self.fps = fps
        self.standoff_m = renderer.spec.standoff_m
        self._last: tuple[int, object] | None = None
        self._truth: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # index -> (roi mask, wall_from_image)
        self.predictor = WallMotionPredictor(SITE, cam.hfov_deg)

    def __len__(self) -> int:
        return len(self.r)

    def _frame(self, i: int):
        if self._last is None or self._last[0] != i:
            f = self.r.render(i)
            self._truth[i] = (f.roi_mask, f.wall_from_image)
            self._last = (i, f)
        return self._last[1]

    def image(self, i: int) -> np.ndarray:
        return self._frame(i).image

    def roi_mask(self, i: int) -> np.ndarray:
        return self._frame(i).roi_mask

    def frame_record(self, i: int):
        from companion.records import Frame

        return Frame(i, self.capture_time(i), self.image(i))

    def capture_time(self, i: int) -> float:
        return i / self.fps

    def camera_pose(self, i: int):
        along, up = self.r.positions[i]
        lat, lon, alt = (float(v) for v in SITE.facade_to_geodetic(along, self.standoff_m, up))
        return types.SimpleNamespace(lat=lat, lon=lon, alt_amsl_m=alt, yaw_deg=SITE.yaw_facing_wall_deg,
                                     pitch_deg=0.0)

    def true_overlap(self, i: int, j: int) -> float:
        """Plane footprint overlap (exact poses; the predictor matches the simulator's truth to 0.03 pts)."""
        exact = telemetry_poses(self, SITE)
        m = self.predictor.predict(exact(i), exact(j), self.width, self.height)
        return 0.0 if m is None else m.overlap_percent / 100.0

    def wall_overlap(self, i: int, j: int) -> float | None:
        """Share of frame i's wall pixels that frame j sees; None when frame i shows no wall."""
        from sim.camera.photo_scene import true_overlap

        for k in (i, j):
            if k not in self._truth:
                self._frame(k)
        (mi, wi), (mj, wj) = self._truth[i], self._truth[j]
        if not np.any(mi):
            return None
        a = types.SimpleNamespace(roi_mask=mi, wall_from_image=wi)
        b = types.SimpleNamespace(roi_mask=mj, wall_from_image=wj)
        return true_overlap(a, b, (self.height, self.width))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--passes", nargs="*", default=None, help="pass names (default: every pass)")
    ap.add_argument("--frames", type=int, default=120, help="frames per pass (the mask bench uses 250)")
    ap.add_argument("--width", type=int, default=960, help="camera width in px (1920 in the mask bench)")
    ap.add_argument("--masks", default="truth,none,model",
                    help="truth, none, model (the default depth model, no parallax) or a shipped model by name "
                         "(sim, real-nc: the onboard Masker with parallax, frames in capture order)")
    ap.add_argument("--gates", default="images,telemetry")
    ap.add_argument("--pose-noise", default=None, help="as in bench/gate_eval.py")
    ap.add_argument("--rth", type=float, default=0.80)
    args = ap.parse_args()
    try:
        from checkout import use_checkout_shared_data

        from sim.camera.model import CameraModel
        from sim.camera.photo_passes import DEFAULT_PASSES, RECIPES, build_pass
        from sim.camera.photo_scene import PhotoPassRenderer
    except ImportError as exc:
        raise CompanionError("the real-texture passes (sim/camera/photo_passes.py) are not in this checkout",
                             "merge the mask evaluation's real-texture passes (issue 13) first") from exc
    from gate_eval import model_masks as model_masks_of  # beside this script
    from gate_eval import parse_pose_noise
    from stitch_photo_passes import shipped_masks


    noise: PoseNoise = parse_pose_noise(args.pose_noise)
    cfg = GateConfig(rth=args.rth, features=FeatureConfig(long_side_px=960))
    print(f"machine: {platform.platform()}, {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.1f}")
    for name in args.passes or DEFAULT_PASSES:
        spec = build_pass(RECIPES[name], root=use_checkout_shared_data(),
                          frames=args.frames, background_frames=max(2, round(args.frames * 22 / 250)))
        cam = spec.camera
        spec = replace(spec, camera=CameraModel(args.width, round(cam.height * args.width / cam.width), cam.hfov_deg))
        rec = PhotoPassRecording(PhotoPassRenderer(spec))
        print(f"\npass {name}: wall {spec.wall.name} {spec.wall.width_m:.1f} x {spec.wall.height_m:.1f} m, "
              f"background {spec.background.name} at {spec.background_distance_m:.0f} m, {len(rec)} frames "
              f"{rec.width}x{rec.height} at {spec.standoff_m} m; telemetry "
              f"{'exact' if noise.exact else noise}")
        rows = []
        model_masks = None
        for mask in [m.strip() for m in args.masks.split(",") if m.strip()]:
            mask_of = None
            if mask == "model":
                model_masks = model_masks or model_masks_of(rec)
                mask_of = model_masks
            elif mask not in ("truth", "none"):  # a shipped model by name, with parallax as the chain runs it
                mask_of = shipped_masks(spec, rec.r, mask).get
            for gate in [g.strip() for g in args.gates.split(",") if g.strip()]:
                pose = telemetry_poses(rec, SITE, noise) if gate == "telemetry" else None
                ev = evaluate_gate(rec, cfg, use_masks=mask == "truth", predictor=rec.predictor if pose else None,
                                   pose=pose, mask_of=mask_of, curve_floor=101.0)
                rows.append((mask, gate, ev))
                print(f"done: mask {mask}, gate {gate}: {len(ev.keyframes)} keyframes, lowest pair "
                      f"{min(ev.keyframe_pair_truth, default=float('nan')):.1f} %", flush=True)
        print(format_table(rows, args.rth))
        print("\n| mask | gate | keyframes showing no wall | visible-wall overlap of keyframe pairs: min | "
              f"pairs < {100 * args.rth - 3:.0f} % |")
        print("|---|---|---|---|---|")
        for mask, gate, ev in rows:
            walls = [rec.wall_overlap(a, b) for a, b in zip(ev.keyframes, ev.keyframes[1:], strict=False)]
            seen = [100.0 * w for w in walls if w is not None]
            no_wall = sum(not np.any(rec._truth[k][0]) for k in ev.keyframes if k in rec._truth)
            low = sum(v < 100 * args.rth - 3 for v in seen)
            print(f"| {mask} | {gate} | {no_wall} of {len(ev.keyframes)} | "
                  f"{min(seen) if seen else math.nan:.1f} % | {low} of {len(seen)} |")


if __name__ == "__main__":
    main()

"""The warp renderer with its far scenery layers against the same renderer drawing every frame in full
(``layers=False``, the previous behaviour), on the same consecutive 30 fps frames in one process, alternating which
goes first: CPU per frame (render, and render + JPEG q88), how often each layer was re-used, and how far the frames
differ (image, surface ids, ROI mask, z-depth).

    python bench/camera_layers.py [--width 1280] [--windows 12] [--seconds 2]

Frames: ``--windows`` windows spread evenly over the demo mission's planned scan (kinematic flight, scene seed 0),
each ``--seconds`` of consecutive frames at the camera's 30 fps (a layer is re-used only on consecutive frames, so
the figure needs them; the first frame of each window warms both renderers' caches and is not counted). Sensor noise
on, the same noise window per frame in both, one fixed gain (so the images compare pixel for pixel). A frame is
"plain" when over 99 % of it is the wall (ROI), else it has an edge.
"""

from __future__ import annotations

import argparse
import collections
import os
import time
from pathlib import Path

import cv2
import numpy as np

import sim.camera.warp_render as warp_render
from companion.mission import load_mission, plan_scan
from sim.camera.recording import camera_from_mission
from sim.camera.scene import Scene
from sim.camera.trajectory import KinematicFlight, scan_path
from sim.camera.warp_render import WarpRenderer

ROOT = Path(__file__).resolve().parents[1]


class FixedGain:
    """An exposure that keeps the gain at 1 (both renderers' images then compare pixel for pixel)."""

    def update(self, mean_radiance: float, t_s: float) -> float:
        return 1.0


def _steps(frame) -> np.ndarray:
    """Pixels within one pixel of a surface change or of a depth step over 5 % (silhouettes, the horizon)."""
    k = np.ones((3, 3), np.uint8)
    sid = frame.surface
    inv = frame.inverse_depth
    return (cv2.dilate(sid, k) != cv2.erode(sid, k)) | (cv2.dilate(inv, k) > cv2.erode(inv, k) * np.float32(1.05))


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--mission", type=Path, default=ROOT / "missions/demo-facade.yaml")
    p.add_argument("--width", type=int, default=1280)
    p.add_argument("--windows", type=int, default=12)
    p.add_argument("--seconds", type=float, default=2.0)
    p.add_argument("--max-error", type=float, default=None,
                   help="a layer's re-use bound in pixels (default: the renderer's _LAYER_MAX_ERROR_PX)")
    a = p.parse_args()
    if a.max_error is not None:
        warp_render._LAYER_MAX_ERROR_PX = a.max_error
    mission = load_mission(a.mission)
    plan = plan_scan(mission)
    cam = camera_from_mission(mission, a.width)
    scene = Scene.build(plan.frame.length_m, float(mission.facade.height_m), seed=0)
    flight = KinematicFlight(plan.frame, scan_path(plan), seed=0)
    fps = float(mission.camera.fps)
    kw = dict(exposure_s=float(mission.camera.exposure_s), seed=0)
    rs = {"full": WarpRenderer(scene, plan.frame, cam, layers=False, **kw),
          "layers": WarpRenderer(scene, plan.frame, cam, layers=True, **kw)}
    cpu = {k: collections.defaultdict(list) for k in rs}
    jpeg = {k: collections.defaultdict(list) for k in rs}
    diff = collections.defaultdict(list)
    load0, index = os.getloadavg()[0], 0
    n = int(round(a.seconds * fps))
    for start in np.linspace(0.0, flight.duration_s - a.seconds, a.windows):
        for i in range(n + 1):
            t = float(start) + i / fps
            pose = flight.pose(t)
            got, spent = {}, {}
            for k in ("full", "layers") if (index % 2) else ("layers", "full"):
                c0 = time.process_time()
                got[k] = rs[k].render(pose, index=index, time_s=t, exposure=FixedGain())
                spent[k] = time.process_time() - c0
                c0 = time.process_time()
                cv2.imencode(".jpg", got[k].image, [cv2.IMWRITE_JPEG_QUALITY, 88])
                spent[k + "_jpeg"] = time.process_time() - c0
            index += 1
            if i == 0:
                continue  # the window's first frame: caches warm up (a jump from the last window)
            ref, new = got["full"], got["layers"]
            kind = "plain" if float(np.mean(ref.roi_mask > 0)) > 0.99 else "edge"
            for k in rs:
                cpu[k][kind].append(spent[k])
                jpeg[k][kind].append(spent[k] + spent[k + "_jpeg"])
            d = np.abs(ref.image.astype(np.int16) - new.image).max(axis=-1)
            steps = _steps(ref)
            same = (ref.surface == new.surface) & ~steps & (ref.inverse_depth > 0)
            rel = np.abs(new.depth[same] - ref.depth[same]) / ref.depth[same]
            diff[kind].append((int(d.max()), float(np.mean(d > 0)), float(np.mean(d > 1)),
                               float(np.mean((d > 1) & ~steps)), float(np.mean(ref.surface != new.surface)),
                               int(np.count_nonzero(ref.roi_mask != new.roi_mask)),
                               float(rel.max()) if rel.size else 0.0))
    frames = sum(len(v) for v in cpu["full"].values())
    print(f"{a.width} px, {frames} frames ({a.windows} windows of {n} consecutive frames at {fps:g} fps) of "
          f"{a.mission.name}; layer re-use bound {warp_render._LAYER_MAX_ERROR_PX} px; load average {load0:.1f} -> "
          f"{os.getloadavg()[0]:.1f}; CPU ms per frame")
    for kind in ("plain", "edge"):
        if not cpu["full"][kind]:
            continue
        for k in rs:
            v, j = 1000 * np.array(cpu[k][kind]), 1000 * np.array(jpeg[k][kind])
            print(f"  {kind} ({len(v)}) {k:6s}: render mean {v.mean():.1f} median {np.median(v):.1f} "
                  f"p90 {np.percentile(v, 90):.1f}; render + JPEG mean {j.mean():.1f} p90 {np.percentile(j, 90):.1f}")
        x = np.array(diff[kind])
        print(f"  {kind} differences (layers vs full, per frame, worst / mean): image max {int(x[:, 0].max())} DN "
              f"(mean of frames {x[:, 0].mean():.1f}); pixels differing {100 * x[:, 1].max():.2f} / "
              f"{100 * x[:, 1].mean():.2f} %, by > 1 DN {100 * x[:, 2].max():.2f} / {100 * x[:, 2].mean():.3f} % "
              f"(off silhouettes and depth steps {100 * x[:, 3].max():.3f} / {100 * x[:, 3].mean():.4f} %); "
              f"surface ids {100 * x[:, 4].max():.3f} / {100 * x[:, 4].mean():.4f} %; ROI mask pixels "
              f"{int(x[:, 5].max())}; depth where surfaces agree off steps, relative {x[:, 6].max():.1e}")
    for k in rs:
        all_r = 1000 * np.array([x for v in cpu[k].values() for x in v])
        all_j = 1000 * np.array([x for v in jpeg[k].values() for x in v])
        print(f"all {k:6s}: render mean {all_r.mean():.1f}, render + JPEG mean {all_j.mean():.1f} ms")
    print("layers (renders, re-uses):", rs["layers"].layer_counts())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

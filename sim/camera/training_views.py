"""Random-viewpoint training frames for ``companion depth train``, rendered by the camera simulator.

The mission's own recordings only see the wall from the planned path; a depth model that must also work on
other walls and real photos needs more: here every seed is a new scene (facade style, background, light), and
views are drawn around the wall at random standoff, height, heading, pitch and roll, including wall ends, roof
lines, ground and views that are mostly background. Two frame aspects (16:9, 4:3) so the squash to the model
input varies as it does between real cameras. Output: FrameSet at the model input size, cached as .npz.
"""

from __future__ import annotations

import logging
from pathlib import Path

import cv2
import numpy as np

from companion.depth.training.data import FrameSet
from companion.geo import FacadeFrame, GeoPoint
from sim.camera.model import CameraModel, TruePose
from sim.camera.render import Renderer
from sim.camera.scene import Scene

log = logging.getLogger(__name__)


def render_views(
    seed: int, n_views: int, height: int, width: int, max_depth: float, *, wall_length_m: float = 26.5,
    wall_height_m: float = 12.0,
) -> FrameSet:
    """``n_views`` random views of the scene of ``seed``, resized to height x width (as the runtime does)."""
    rng = np.random.default_rng([seed, 2024])
    length = float(wall_length_m * rng.uniform(0.6, 1.6))
    wall_h = float(wall_height_m * rng.uniform(0.6, 1.8))
    start = GeoPoint(37.5665, 126.978, 30.0)
    bearing = rng.uniform(0, 2 * np.pi)
    dlat = length * np.cos(bearing) / 111_320.0
    dlon = length * np.sin(bearing) / (111_320.0 * np.cos(np.radians(start.lat)))
    frame = FacadeFrame.from_wall(start, GeoPoint(start.lat + dlat, start.lon + dlon, 30.0))
    scene = Scene.build(frame.length_m, wall_h, seed=seed)
    aspect_h = 360 if rng.random() < 0.5 else 480
    camera = CameraModel(640, aspect_h, float(rng.uniform(55, 80)))
    renderer = Renderer(scene, frame, camera, exposure_s=float(rng.uniform(1 / 1000, 1 / 120)), seed=seed)
    facing = frame.yaw_facing_wall_deg
    images, depths, masks = [], [], []
    for i in range(n_views):
        if rng.random() < 0.4:  # mid-wall: the scan's most common view (no boundary)
            along = rng.uniform(0.15, 0.85) * length
            up = rng.uniform(1.5, max(wall_h - 1.5, 2.0))
        else:  # anywhere around the wall: ends, roof line, ground, far background
            along = rng.uniform(-0.3, 1.3) * length
            up = rng.uniform(0.8, wall_h + 4.0)
        out = rng.uniform(2.5, 8.0)
        yaw = facing + float(np.clip(rng.normal(0, 12), -35, 35))
        pitch = float(np.clip(rng.normal(0, 10), -30, 25)) - (8.0 if up > wall_h else 0.0)
        roll = float(rng.normal(0, 3))
        e, n, u = frame.facade_to_enu(along, out, up)
        pose = TruePose.from_angles(np.array([float(e), float(n), float(u)]), yaw, pitch, roll)
        f = renderer.render(pose, index=i, time_s=i * 0.5)
        ok, buf = cv2.imencode(".jpg", f.image, [cv2.IMWRITE_JPEG_QUALITY, 90])  # as recordings store them
        img = cv2.imdecode(buf, cv2.IMREAD_COLOR) if ok else f.image
        images.append(cv2.resize(img, (width, height), interpolation=cv2.INTER_AREA))
        d = np.where(np.isfinite(f.depth), f.depth, max_depth).astype(np.float32)
        depths.append(np.clip(cv2.resize(d, (width, height), interpolation=cv2.INTER_NEAREST), 0.1, max_depth))
        masks.append(cv2.resize(f.roi_mask, (width, height), interpolation=cv2.INTER_NEAREST))
    return FrameSet(np.stack(images), np.stack(depths), np.stack(masks))


def cached_views(
    cache_dir: Path, seeds: list[int], n_views: int, height: int, width: int, max_depth: float
) -> FrameSet:
    """Render (or load from ``cache_dir``) the views of every seed and concatenate them."""
    parts = []
    for seed in seeds:
        path = Path(cache_dir) / f"views_seed{seed:04d}_n{n_views}_{height}x{width}.npz"
        if path.is_file():
            z = np.load(path)
            fs = FrameSet(z["images"], z["depths"], z["masks"])
        else:
            log.info("rendering %d views of scene seed %d", n_views, seed)
            fs = render_views(seed, n_views, height, width, max_depth)
            path.parent.mkdir(parents=True, exist_ok=True)
            tmp = path.with_suffix(".tmp.npz")
            np.savez(tmp, images=fs.images, depths=fs.depths.astype(np.float16), masks=fs.roi_masks)
            tmp.replace(path)
        parts.append(fs)
    return FrameSet(
        np.concatenate([p.images for p in parts]),
        np.concatenate([p.depths for p in parts]),
        np.concatenate([p.roi_masks for p in parts]),
    )

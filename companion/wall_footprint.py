"""Where a camera's image lands on the wall plane: one home for the gate's predicted overlap, the simulator's
true overlap, the map's keyframe footprints and the synthetic test scenes.

Facade coordinates are ``(along_m, out_m, up_m)`` (companion/geo.py); the wall plane is ``out_m = 0`` and a
footprint is a polygon of ``(along_m, up_m)`` points on it. A camera is its centre in facade coordinates and
its rotation facade <- camera (OpenCV axes: x right, y down, z forward).
"""

from __future__ import annotations

import numpy as np

from companion.geo import FacadeFrame
from companion.polygons import clip_half_plane


def facade_from_enu(frame: FacadeFrame) -> np.ndarray:
    """3x3 rotation taking ENU vectors to facade (along, out, up) vectors."""
    de, dn = frame.along_enu
    oe, on = frame.out_enu
    return np.array([[de, dn, 0.0], [oe, on, 0.0], [0.0, 0.0, 1.0]])


def _image_corners(width: float, height: float) -> np.ndarray:
    return np.array([[0.0, 0.0, 1.0], [width, 0.0, 1.0], [width, height, 1.0], [0.0, height, 1.0]])


def corner_footprint(
    K: np.ndarray, width: float, height: float, centre: np.ndarray, rotation: np.ndarray
) -> np.ndarray | None:
    """The image corners on the wall plane, (4, 2) ``(along_m, up_m)`` in the image's corner order; None when
    the camera is not in front of the wall or a corner's ray does not reach the wall plane ahead of it."""
    centre = np.asarray(centre, dtype=np.float64)
    rays = (rotation @ np.linalg.inv(K) @ _image_corners(width, height).T).T  # facade-frame ray directions
    if centre[1] <= 0 or np.any(rays[:, 1] >= -1e-6):
        return None
    t = -centre[1] / rays[:, 1]
    return (centre + t[:, None] * rays)[:, [0, 2]]


def visible_footprint(
    K: np.ndarray,
    width: float,
    height: float,
    centre: np.ndarray,
    rotation: np.ndarray,
    *,
    max_range_m: float = 500.0,
    near_m: float = 0.01,
) -> np.ndarray:
    """The exact footprint for any pose: the wall-plane points in front of the camera whose projection lies in
    the image (the intersection of the four image borders' and the near plane's half-planes), bounded by a
    square of ``max_range_m`` around the camera so views towards the horizon stay finite; (0, 2) if unseen."""
    # camera coordinates of the wall point (a, 0, u): p = R^T (X - C) = G @ (a, u) + g
    G = rotation.T[:, [0, 2]]
    g = -rotation.T @ np.asarray(centre, dtype=np.float64)
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    half_planes = [
        (fx * G[0] + cx * G[2], fx * g[0] + cx * g[2]),  # u >= 0
        ((width - cx) * G[2] - fx * G[0], (width - cx) * g[2] - fx * g[0]),  # u <= width
        (fy * G[1] + cy * G[2], fy * g[1] + cy * g[2]),  # v >= 0
        ((height - cy) * G[2] - fy * G[1], (height - cy) * g[2] - fy * g[1]),  # v <= height
        (G[2], g[2] - near_m),  # in front of the camera
    ]
    a0, u0, r = centre[0], centre[2], max_range_m
    poly = np.array([[a0 - r, u0 - r], [a0 + r, u0 - r], [a0 + r, u0 + r], [a0 - r, u0 + r]])
    for normal, offset in half_planes:
        poly = clip_half_plane(poly, normal, float(offset))
        if len(poly) < 3:
            return np.zeros((0, 2))
    return poly

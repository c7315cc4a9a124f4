"""True overlap between frames, from the geometry: each frame's footprint on the wall plane is a convex polygon.

The footprint is exact for any pose: it is the set of wall-plane points in front of the camera whose projection
lies inside the image, i.e. the intersection of five half-planes (four image borders and the near plane),
clipped to a large square so that views towards the horizon stay bounded.
"""

from __future__ import annotations

import cv2
import numpy as np

from companion.geo import FacadeFrame
from sim.camera.model import TruePose

_NEAR = 0.01


def _clip(poly: np.ndarray, n: np.ndarray, c: float) -> np.ndarray:
    """Sutherland-Hodgman: keep the part of a convex polygon where n . x + c >= 0."""
    if len(poly) == 0:
        return poly
    out = []
    d = poly @ n + c
    for i in range(len(poly)):
        j = (i + 1) % len(poly)
        if d[i] >= 0:
            out.append(poly[i])
        if (d[i] >= 0) != (d[j] >= 0):
            s = d[i] / (d[i] - d[j])
            out.append(poly[i] + s * (poly[j] - poly[i]))
    return np.array(out).reshape(-1, 2)


def footprint_on_wall(K: np.ndarray, width: int, height: int, pose: TruePose, frame: FacadeFrame,
                      max_range_m: float = 500.0) -> np.ndarray:
    """Polygon (N, 2) of the image's footprint on the wall plane in facade (along_m, up_m); empty if unseen."""
    de, dn = frame.along_enu
    oe, on = frame.out_enu
    M = np.array([[de, dn, 0.0], [oe, on, 0.0], [0.0, 0.0, 1.0]])
    A = M @ pose.R_world_from_cam  # facade <- camera
    C = M @ pose.position_enu
    # camera coordinates of the wall point (a, 0, u): p = A^T (X - C) = G @ (a, u) + g
    G = A.T[:, [0, 2]]
    g = -A.T @ C
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    rows = [
        (fx * G[0] + cx * G[2], fx * g[0] + cx * g[2]),  # u >= 0
        ((width - cx) * G[2] - fx * G[0], (width - cx) * g[2] - fx * g[0]),  # u <= width
        (fy * G[1] + cy * G[2], fy * g[1] + cy * g[2]),  # v >= 0
        ((height - cy) * G[2] - fy * G[1], (height - cy) * g[2] - fy * g[1]),  # v <= height
        (G[2], g[2] - _NEAR),  # in front of the camera
    ]
    a0, u0 = C[0], C[2]
    r = max_range_m
    poly = np.array([[a0 - r, u0 - r], [a0 + r, u0 - r], [a0 + r, u0 + r], [a0 - r, u0 + r]])
    for n, c in rows:
        poly = _clip(poly, np.asarray(n, float), float(c))
        if len(poly) < 3:
            return np.zeros((0, 2))
    return poly


def clip_to_rect(poly: np.ndarray, a0: float, u0: float, a1: float, u1: float) -> np.ndarray:
    """The part of a convex polygon inside an axis-aligned rectangle (e.g. the wall itself)."""
    for n, c in (((1, 0), -a0), ((-1, 0), a1), ((0, 1), -u0), ((0, -1), u1)):
        poly = _clip(poly, np.asarray(n, float), float(c))
        if len(poly) < 3:
            return np.zeros((0, 2))
    return poly


def polygon_area(poly: np.ndarray) -> float:
    if len(poly) < 3:
        return 0.0
    x, y = poly[:, 0], poly[:, 1]
    return 0.5 * abs(float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))


def overlap_ratio(poly_i: np.ndarray, poly_j: np.ndarray) -> float:
    """Area of poly_i covered by poly_j divided by the area of poly_i (0 when poly_i is empty)."""
    ai = polygon_area(poly_i)
    if ai <= 0 or len(poly_j) < 3:
        return 0.0
    origin = poly_i.mean(axis=0)
    pi = np.ascontiguousarray(poly_i - origin, dtype=np.float32)
    pj = np.ascontiguousarray(poly_j - origin, dtype=np.float32)
    if cv2.contourArea(pi, oriented=True) < 0:
        pi = pi[::-1].copy()
    if cv2.contourArea(pj, oriented=True) < 0:
        pj = pj[::-1].copy()
    inter, _ = cv2.intersectConvexConvex(pi, pj)
    return float(np.clip(inter / ai, 0.0, 1.0))

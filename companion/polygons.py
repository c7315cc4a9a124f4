"""Plane polygons as (N, 2) float arrays: area and convex clipping, one home for the gate's overlap, the
simulator's true overlap, the planner's footprint orientation and the stitcher's homography checks.

Clipping is Sutherland-Hodgman in float64, written out because ``cv2.intersectConvexConvex`` (float32)
misreports coincident edges: two identical frames gave 53 % overlap instead of 100 %.
"""

from __future__ import annotations

import numpy as np


def signed_area(poly) -> float:
    """Shoelace area: positive when the vertices run counter-clockwise in a y-up frame (clockwise in image
    coordinates, y down)."""
    p = np.asarray(poly, dtype=np.float64).reshape(-1, 2)
    x, y = p[:, 0], p[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))


def polygon_area(poly) -> float:
    """Unsigned area; 0 for fewer than three vertices."""
    p = np.asarray(poly, dtype=np.float64).reshape(-1, 2)
    return abs(signed_area(p)) if len(p) >= 3 else 0.0


def clip_half_plane(poly: np.ndarray, normal, offset: float, *, tolerance: float = 0.0) -> np.ndarray:
    """The part of a convex polygon where ``normal . x + offset >= -tolerance`` (one Sutherland-Hodgman pass)."""
    poly = np.asarray(poly, dtype=np.float64).reshape(-1, 2)
    if len(poly) == 0:
        return poly
    d = poly @ np.asarray(normal, dtype=np.float64) + offset
    inside = d >= -tolerance
    out = []
    for i in range(len(poly)):
        j = (i + 1) % len(poly)
        if inside[i]:
            out.append(poly[i])
        if inside[i] != inside[j]:
            s = d[i] / (d[i] - d[j])
            out.append(poly[i] + s * (poly[j] - poly[i]))
    return np.array(out, dtype=np.float64).reshape(-1, 2)


def clip_to_rect(poly: np.ndarray, x0: float, y0: float, x1: float, y1: float) -> np.ndarray:
    """The part of a convex polygon inside the axis-aligned rectangle [x0, x1] x [y0, y1]; empty (0, 2) if none."""
    for normal, offset in (((1, 0), -x0), ((-1, 0), x1), ((0, 1), -y0), ((0, -1), y1)):
        poly = clip_half_plane(poly, normal, float(offset))
        if len(poly) < 3:
            return np.zeros((0, 2))
    return poly


def clip_convex(subject: np.ndarray, clip: np.ndarray) -> np.ndarray:
    """The part of ``subject`` (convex) inside the convex polygon ``clip`` (either orientation); empty if none.

    Points within 1e-9 (in the edge's cross-product units) of a clip edge count as inside, so coincident edges
    keep their vertices instead of producing slivers."""
    clip = np.asarray(clip, dtype=np.float64).reshape(-1, 2)
    if signed_area(clip) < 0:
        clip = clip[::-1]
    out = np.asarray(subject, dtype=np.float64).reshape(-1, 2)
    for k in range(len(clip)):
        a, b = clip[k], clip[(k + 1) % len(clip)]
        ex, ey = b - a
        normal = np.array([-ey, ex])  # left of a->b is inside a counter-clockwise polygon
        out = clip_half_plane(out, normal, -float(normal @ a), tolerance=1e-9)
        if len(out) < 3:
            return np.zeros((0, 2))
    return out


def convex_intersection_area(subject: np.ndarray, clip: np.ndarray) -> float:
    """Area of the intersection of two convex polygons."""
    return polygon_area(clip_convex(subject, clip))


def covered_share(poly_i: np.ndarray, poly_j: np.ndarray) -> float:
    """Share (0..1) of convex ``poly_i``'s area that convex ``poly_j`` covers (0 when poly_i is empty)."""
    ai = polygon_area(poly_i)
    if ai <= 0 or len(poly_j) < 3:
        return 0.0
    return float(np.clip(convex_intersection_area(poly_j, poly_i) / ai, 0.0, 1.0))

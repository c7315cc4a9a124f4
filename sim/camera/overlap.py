"""True overlap between frames, from the geometry: each frame's footprint on the wall plane is a convex polygon.

The footprint is exact for any pose (``companion.wall_footprint.visible_footprint``); the polygon maths is
``companion.polygons``, the same the keyframe gate measures its overlap with.
"""

from __future__ import annotations

import numpy as np

from companion.geo import FacadeFrame
from companion.polygons import clip_to_rect, covered_share, polygon_area
from companion.wall_footprint import facade_from_enu, visible_footprint
from sim.camera.model import TruePose

__all__ = ["clip_to_rect", "footprint_on_wall", "overlap_ratio", "polygon_area"]


def footprint_on_wall(K: np.ndarray, width: int, height: int, pose: TruePose, frame: FacadeFrame,
                      max_range_m: float = 500.0) -> np.ndarray:
    """Polygon (N, 2) of the image's footprint on the wall plane in facade (along_m, up_m); empty if unseen."""
    M = facade_from_enu(frame)
    return visible_footprint(K, width, height, M @ pose.position_enu, M @ pose.R_world_from_cam,
                             max_range_m=max_range_m)


def overlap_ratio(poly_i: np.ndarray, poly_j: np.ndarray) -> float:
    """Area of poly_i covered by poly_j divided by the area of poly_i (0 when poly_i is empty)."""
    return covered_share(poly_i, poly_j)

"""The shared helpers: polygon area and clipping, the camera footprint on the wall, SIFT ratio matching and
RANSAC fits (companion/polygons.py, companion/wall_footprint.py, companion/matching.py, companion/ransac.py)."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from companion.errors import CompanionError
from companion.geo import FacadeFrame, GeoPoint
from companion.keyframes.motion import camera_rotation_enu
from companion.matching import MatcherSettings, match_descriptors
from companion.polygons import (
    clip_convex,
    clip_to_rect,
    convex_intersection_area,
    covered_share,
    polygon_area,
    signed_area,
)
from companion.ransac import ransac_affine, ransac_homography
from companion.wall_footprint import corner_footprint, facade_from_enu, visible_footprint

SQUARE = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 2.0], [0.0, 2.0]])


def test_area_sign_follows_the_vertex_order():
    assert signed_area(SQUARE) == pytest.approx(4.0)
    assert signed_area(SQUARE[::-1]) == pytest.approx(-4.0)
    assert polygon_area(SQUARE[::-1]) == pytest.approx(4.0)
    assert polygon_area(SQUARE[:2]) == 0.0
    closed = np.vstack([SQUARE, SQUARE[:1]])  # a GeoJSON ring repeats its first point: same area
    assert signed_area(closed) == pytest.approx(4.0)


def test_convex_clipping_is_exact_for_coincident_edges_and_either_orientation():
    # identical frames: cv2.intersectConvexConvex gave 53 % here; the shared clipper gives the whole square
    assert convex_intersection_area(SQUARE, SQUARE) == pytest.approx(4.0, abs=1e-12)
    shifted = SQUARE + [1.0, 0.5]
    assert convex_intersection_area(shifted, SQUARE[::-1]) == pytest.approx(1.0 * 1.5)
    assert covered_share(SQUARE, shifted) == pytest.approx(1.5 / 4.0)
    assert covered_share(SQUARE, SQUARE + [5.0, 0.0]) == 0.0
    diamond = np.array([[1.0, -1.0], [3.0, 1.0], [1.0, 3.0], [-1.0, 1.0]])
    inside = clip_convex(diamond, SQUARE)
    assert polygon_area(inside) == pytest.approx(4.0)  # the square lies inside the diamond
    assert polygon_area(clip_to_rect(diamond, 0.0, 0.0, 1.0, 1.0)) == pytest.approx(1.0)
    assert clip_to_rect(diamond, 10.0, 10.0, 11.0, 11.0).shape == (0, 2)


def _facing_camera(hfov_deg=70.0, width=640, height=360, pitch_deg=0.0):
    frame = FacadeFrame.from_wall(GeoPoint(37.5665, 126.978, 30.0), GeoPoint(37.5665, 126.979, 30.0))
    f = (width / 2) / math.tan(math.radians(hfov_deg) / 2)
    K = np.array([[f, 0.0, width / 2], [0.0, f, height / 2], [0.0, 0.0, 1.0]])
    rotation = facade_from_enu(frame) @ camera_rotation_enu(frame.yaw_facing_wall_deg, pitch_deg)
    return K, width, height, rotation


def test_footprint_of_a_camera_facing_the_wall_is_the_planned_rectangle():
    K, w, h, rotation = _facing_camera()
    centre = np.array([5.0, 4.0, 3.0])  # 5 m along, 4 m out, 3 m up
    fp = corner_footprint(K, w, h, centre, rotation)
    width_m = 2 * 4.0 * math.tan(math.radians(35.0))  # the planner's footprint: 2 d tan(hfov / 2)
    assert fp[1, 0] - fp[0, 0] == pytest.approx(width_m)
    assert fp[0, 1] - fp[3, 1] == pytest.approx(width_m * h / w)  # image top is higher on the wall
    assert fp.mean(axis=0) == pytest.approx([5.0, 3.0])
    # the exact (clipped) footprint is the same polygon when every corner reaches the wall
    assert polygon_area(visible_footprint(K, w, h, centre, rotation)) == pytest.approx(polygon_area(fp))


def test_footprint_of_a_camera_looking_past_the_wall():
    K, w, h, rotation = _facing_camera(pitch_deg=80.0)  # the top corners' rays never reach the wall
    centre = np.array([5.0, 4.0, 3.0])
    assert corner_footprint(K, w, h, centre, rotation) is None
    part = visible_footprint(K, w, h, centre, rotation, max_range_m=100.0)
    assert len(part) >= 3 and part[:, 1].max() == pytest.approx(3.0 + 100.0)  # bounded by the range square
    assert corner_footprint(K, w, h, np.array([5.0, -1.0, 3.0]), rotation) is None  # behind the wall


def test_ratio_test_and_ransac_recover_a_known_homography():
    rng = np.random.default_rng(1)
    img = cv2.GaussianBlur((rng.random((360, 640)) * 255).astype(np.uint8), (0, 0), 2.0)
    H = np.array([[1.0, 0.02, 30.0], [-0.01, 1.0, 12.0], [0.0, 0.0, 1.0]])
    warped = cv2.warpPerspective(img, H, (640, 360))
    sift = cv2.SIFT_create(1000)
    ka, da = sift.detectAndCompute(img, None)
    kb, db = sift.detectAndCompute(warped, None)
    found = match_descriptors(da, db, MatcherSettings(kind="bf"))
    qa, tb = found.query, found.indexed
    assert len(qa) > 100 and qa.dtype == np.intp
    src = np.array([ka[i].pt for i in qa])
    dst = np.array([kb[i].pt for i in tb])
    cv2.setRNGSeed(0)
    Hf, inl = ransac_homography(src, dst, method=cv2.USAC_MAGSAC, threshold_px=2.0, max_iters=2000, confidence=0.99)
    assert inl.dtype == bool and inl.sum() > 0.8 * len(src)
    moved, truth = cv2.perspectiveTransform(src[None], Hf)[0], cv2.perspectiveTransform(src[None], H)[0]
    assert np.abs(moved - truth).max() < 1.0  # within a pixel of the true warp over every match
    A, inl_a = ransac_affine(src, dst, threshold_px=2.0, partial=True)
    assert A.shape == (3, 3) and inl_a.sum() > 0.5 * len(src)
    none, mask = ransac_homography(src[:3], dst[:3], method=cv2.RANSAC, threshold_px=2.0, max_iters=10, confidence=0.9)
    assert none is None and mask.shape == (3,) and not mask.any()
    with pytest.raises(CompanionError, match="unknown matcher"):
        MatcherSettings(kind="orb")

"""Overlap ratio on synthetic wall views with exactly known overlap (translation, rotation, zoom, masks, blur)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from companion.errors import CompanionError
from companion.keyframes import (
    FeatureConfig,
    FeatureExtractor,
    OverlapConfig,
    OverlapEstimator,
    OverlapStatus,
    eq2_overlap,
    laplacian_variance,
    polygon_overlap,
)
from companion.keyframes.overlap import convex_intersection_area
from evaluation.keyframes.synthetic import View, render, textured_wall, true_overlap

W, H = 480, 360


@pytest.fixture(scope="module")
def tex():
    return textured_wall(1800, 900, seed=1)


@pytest.fixture(scope="module")
def ex():
    return FeatureExtractor(FeatureConfig(long_side_px=480))


def _estimate(tex, ex, a: View, b: View, method="displacement", mask_a=None, mask_b=None, blur_b=0.0):
    fa = ex.extract(render(tex, a), mask_a)
    fb = ex.extract(render(tex, b, blur_sigma=blur_b), mask_b)
    return OverlapEstimator(OverlapConfig(method=method)).estimate(fa, fb)


def test_eq2_matches_paper_formula():
    assert eq2_overlap(0, 0, 640, 480) == pytest.approx(100.0)
    assert eq2_overlap(64, -48, 640, 480) == pytest.approx(100 * 0.9 * 0.9)
    assert eq2_overlap(700, 0, 640, 480) == 0.0


@pytest.mark.parametrize("dx,dy", [(0, 0), (30, 0), (-60, 10), (0, 70), (120, -40), (200, 0)])
@pytest.mark.parametrize("method", ["displacement", "polygon"])
def test_translation_gives_true_overlap(tex, ex, dx, dy, method):
    a = View(700, 450, W, H)
    b = View(700 + dx, 450 + dy, W, H)
    est = _estimate(tex, ex, a, b, method)
    assert est.status == OverlapStatus.OK
    assert est.percent == pytest.approx(100 * true_overlap(a, b), abs=0.5)
    # Iq moved right on the wall -> the wall moves left in the picture.
    assert est.dx == pytest.approx(-dx, abs=1.0)
    assert est.dy == pytest.approx(-dy, abs=1.0)


@pytest.mark.parametrize("method", ["displacement", "polygon"])
def test_identical_frames_are_full_overlap(tex, ex, method):
    a = View(700, 450, W, H)
    est = _estimate(tex, ex, a, a, method)
    assert est.percent == pytest.approx(100.0, abs=0.05)
    assert est.inliers == est.matches


def test_polygon_area_with_coincident_edges():
    """cv2.intersectConvexConvex reported 53 % for two identical rectangles; ours must not."""
    rect = np.array([[0, 0], [W, 0], [W, H], [0, H]], float)
    assert convex_intersection_area(rect, rect) == pytest.approx(W * H)
    assert polygon_overlap(np.eye(3), W, H) == pytest.approx(100.0)
    shifted = np.array([[1, 0, W / 2], [0, 1, 0], [0, 0, 1.0]])
    assert polygon_overlap(shifted, W, H) == pytest.approx(50.0)


@pytest.mark.parametrize("angle,zoom", [(8.0, 1.0), (15.0, 1.0), (0.0, 1.15), (10.0, 0.9)])
def test_polygon_estimator_handles_rotation_and_scale(tex, ex, angle, zoom):
    a = View(700, 450, W, H)
    b = View(740, 460, W, H, angle_deg=angle, zoom=zoom)
    truth = 100 * true_overlap(a, b)
    poly = _estimate(tex, ex, a, b, "polygon")
    disp = _estimate(tex, ex, a, b, "displacement")
    assert poly.percent == pytest.approx(truth, abs=1.0)
    # Eq. 2 assumes pure translation: with rotation/zoom it is off by more than the polygon estimate.
    assert abs(disp.R - truth) > abs(poly.R - truth)
    assert poly.R_displacement == pytest.approx(disp.R, abs=0.3)  # two RANSAC runs: same answer within noise


def test_all_black_frame_is_unknown_not_zero(tex, ex):
    fa = ex.extract(render(tex, View(700, 450, W, H)))
    fb = ex.extract(np.zeros((H, W, 3), np.uint8))
    est = OverlapEstimator().estimate(fa, fb)
    assert est.status == OverlapStatus.TOO_FEW_FEATURES
    assert est.R is None and not est.known and est.ratio is None


def test_disjoint_views_are_unknown(tex, ex):
    est = _estimate(tex, ex, View(300, 250, W, H), View(1400, 650, W, H))
    assert est.status in (OverlapStatus.TOO_FEW_MATCHES, OverlapStatus.TOO_FEW_INLIERS)
    assert est.R is None


def test_mask_keeps_static_background_out(tex, ex):
    """A far background barely moves; without the ROI mask its features pull R towards 100 %."""
    a, b = View(700, 450, W, H), View(790, 450, W, H)
    img_a, img_b = render(tex, a), render(tex, b)
    far = textured_wall(W, H // 2, seed=7)  # same in both frames: far away, no parallax
    img_a[: H // 2], img_b[: H // 2] = far, far
    mask = np.zeros((H, W), np.uint8)
    mask[H // 2 :] = 255
    # Both frames now show the wall only in the lower half: truth is Eq. 2 on the shift.
    truth = eq2_overlap(90, 0, W, H)
    fa, fb = ex.extract(img_a, mask), ex.extract(img_b, mask)
    masked = OverlapEstimator().estimate(fa, fb)
    assert masked.percent == pytest.approx(truth, abs=0.5)
    assert np.all(fa.points[:, 1] >= H // 2)  # no keypoint outside the ROI
    unmasked = OverlapEstimator().estimate(ex.extract(img_a), ex.extract(img_b))
    assert unmasked.R is None or abs(unmasked.R - truth) > 3.0


@pytest.mark.parametrize("dx", [20, 45])
def test_small_roi_at_frame_edge_still_measures(tex, ex, dx):
    """A wall edge just entering view: features only in a narrow strip (where H alone is ill-posed)."""
    a, b = View(700, 450, W, H), View(700 + dx, 450, W, H)
    mask = np.zeros((H, W), np.uint8)
    mask[:, -int(0.15 * W) :] = 255
    est = OverlapEstimator().estimate(ex.extract(render(tex, a), mask), ex.extract(render(tex, b), mask))
    assert est.status == OverlapStatus.OK
    assert est.percent == pytest.approx(100 * true_overlap(a, b), abs=1.0)
    assert est.model in ("homography", "similarity")


def test_working_copy_reports_full_resolution_pixels(tex):
    small = FeatureExtractor(FeatureConfig(long_side_px=240))  # half of W
    a, b = View(700, 450, W, H), View(760, 430, W, H)
    fa, fb = small.extract(render(tex, a)), small.extract(render(tex, b))
    assert fa.scale == pytest.approx(0.5)
    est = OverlapEstimator().estimate(fa, fb)
    assert est.dx == pytest.approx(-60, abs=1.5)
    assert est.dy == pytest.approx(20, abs=1.5)
    assert est.H[0, 2] == pytest.approx(-60, abs=2.0)


def test_mild_blur_still_measures_and_lowers_sharpness(tex, ex):
    a, b = View(700, 450, W, H), View(750, 450, W, H)
    est = _estimate(tex, ex, a, b, blur_b=1.5)
    assert est.percent == pytest.approx(100 * true_overlap(a, b), abs=1.0)
    sharp = cv2.cvtColor(render(tex, b), cv2.COLOR_BGR2GRAY)
    blurred = cv2.cvtColor(render(tex, b, blur_sigma=1.5), cv2.COLOR_BGR2GRAY)
    assert laplacian_variance(blurred) < 0.5 * laplacian_variance(sharp)


def test_bad_inputs_name_the_fix(tex, ex):
    img = render(tex, View(700, 450, W, H))
    with pytest.raises(CompanionError, match="mask"):
        ex.extract(img, np.zeros((10, 10), np.uint8))
    with pytest.raises(CompanionError, match="dtype"):
        ex.extract(img.astype(np.float32))
    with pytest.raises(CompanionError, match="empty"):
        ex.extract(np.zeros((0, 0, 3), np.uint8))
    with pytest.raises(CompanionError, match="method"):
        OverlapConfig(method="magic")
    other = FeatureExtractor(FeatureConfig(long_side_px=480)).extract(cv2.resize(img, (320, 240)))
    with pytest.raises(CompanionError, match="size"):
        OverlapEstimator().estimate(ex.extract(img), other)


REAL = Path("/work/shared/data/real-uav-facade")


@pytest.mark.skipif(not (REAL / "DJI_0977_rgb.JPG").exists(), reason="real photos not present")
def test_real_low_texture_photos_are_handled():
    """Two real 4056x3040 photos of a plain clad wall: either a plausible R or an explicit unknown, no crash."""
    a = cv2.imread(str(REAL / "DJI_0977_rgb.JPG"))
    b = cv2.imread(str(REAL / "DJI_0981_rgb.JPG"))
    ex = FeatureExtractor(FeatureConfig(long_side_px=960))
    est = OverlapEstimator().estimate(ex.extract(a), ex.extract(b))
    if est.known:
        assert 0.0 <= est.R <= 100.0 and est.inliers >= 12
    else:
        assert est.status != OverlapStatus.OK
    same = OverlapEstimator().estimate(ex.extract(a), ex.extract(a))
    assert same.percent == pytest.approx(100.0, abs=0.1)


def test_the_gates_matches_do_not_depend_on_what_used_the_rng_before(tex, ex):
    """FLANN's randomised trees draw from OpenCV's per-thread RNG: unseeded, the keyframe's index (and so the
    matches, R and the keyframes) depended on whatever drew from it earlier in the process (an earlier cull, a
    resumed one, another bench rule). Seeded, the same frames give the same matches."""
    a, b = View(700, 450, W, H), View(760, 470, W, H)
    fa, fb = ex.extract(render(tex, a)), ex.extract(render(tex, b))
    answers = []
    for earlier in (1, 2, 3):
        cv2.setRNGSeed(earlier)
        est = OverlapEstimator(OverlapConfig()).estimate(fa, fb)
        answers.append((est.matches, est.inliers, est.matched_points.tobytes()))
    assert len(fa) > 500 and answers[0] == answers[1] == answers[2]

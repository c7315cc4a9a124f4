"""ROI extraction (paper Eq. 1) on synthetic disparity maps with known boundaries."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from companion.depth.roi import RoiParams, apply_mask, extract_roi, otsu_threshold, pixel_error_ratio
from companion.errors import CompanionError

H, W = 96, 320
WALL, FAR = 0.25, 0.03  # disparity of a wall at 4 m and a background at ~33 m (same units)


def _scene(truth: np.ndarray, seed: int = 0, blur: int = 5, noise: float = 0.004) -> np.ndarray:
    """Disparity with the wall where ``truth`` is True, blurred edges and noise like a network output."""
    rng = np.random.default_rng(seed)
    d = np.where(truth, WALL, FAR).astype(np.float32)
    # a little depth variation inside each part (tilted wall, uneven background)
    d += np.linspace(0, 0.02, W, dtype=np.float32)[None, :] * truth
    d = cv2.GaussianBlur(d, (blur, blur), 0)
    return d + rng.normal(0, noise, d.shape).astype(np.float32)


def _grid():
    return np.mgrid[0:H, 0:W]


@pytest.mark.parametrize(
    "name",
    ["wall_end_right", "wall_end_left", "roof_on_top", "ground_below", "diagonal", "wall_between_two_backgrounds"],
)
def test_boundaries_of_any_orientation(name):
    yy, xx = _grid()
    truth = {
        "wall_end_right": xx < 200,  # background right of the wall's end
        "wall_end_left": xx >= 90,
        "roof_on_top": yy >= 30,  # sky above the roof line
        "ground_below": yy < 70,
        "diagonal": (xx + 2 * yy) > 250,
        "wall_between_two_backgrounds": (xx > 60) & (xx < 250),
    }[name]
    d = _scene(truth)
    res = extract_roi(d)
    assert not res.empty and not res.no_boundary
    err = pixel_error_ratio(res.mask, np.where(truth, 255, 0).astype(np.uint8))
    assert err < 0.01, f"{name}: error ratio {err:.4f}"
    assert res.roi_nearer is True


def test_several_background_regions_sky_and_side():
    yy, xx = _grid()
    truth = (yy >= 25) & (xx < 240)  # sky above the roof and a far street beyond the wall's end
    d = _scene(truth, seed=3)
    d[:25, :] = 0.005  # sky is even farther than the street
    res = extract_roi(d)
    assert res.n_regions >= 2 and res.n_kept == 1
    assert pixel_error_ratio(res.mask, np.where(truth, 255, 0).astype(np.uint8)) < 0.01


def test_no_boundary_keeps_whole_frame():
    rng = np.random.default_rng(1)
    # a tilted, slightly bumpy wall: smooth disparity change, no depth boundary
    d = (0.22 + np.linspace(0, 0.05, W)[None, :] + rng.normal(0, 0.003, (H, W))).astype(np.float32)
    res = extract_roi(d)
    assert res.no_boundary and not res.empty
    assert res.roi_fraction == 1.0
    assert res.roi_nearer is None


def test_near_step_on_the_wall_is_not_a_background_boundary():
    # a balcony / recess: a real boundary, but both sides are near (ratio 0.8 > near_ratio 0.6)
    yy, xx = _grid()
    d = np.where(xx < 160, 0.25, 0.20).astype(np.float32)
    res = extract_roi(d)
    assert res.roi_fraction == 1.0


def test_whole_frame_background_is_flagged_empty():
    rng = np.random.default_rng(2)
    d = (0.01 + rng.normal(0, 0.001, (H, W))).astype(np.float32)
    res = extract_roi(d, out_size=(640, 192), params=RoiParams(min_roi_disparity=0.05))
    assert res.empty and res.roi_fraction == 0.0
    assert res.mask.shape == (192, 640) and not res.mask.any()
    # the same frame is kept when there is no absolute scale to judge it by
    assert not extract_roi(d).empty


def test_mask_at_full_resolution_and_masked_frame():
    yy, xx = _grid()
    truth = xx < 200
    res = extract_roi(_scene(truth), out_size=(1280, 384))
    assert res.mask.shape == (384, 1280) and res.mask.dtype == np.uint8
    full_truth = cv2.resize(np.where(truth, 255, 0).astype(np.uint8), (1280, 384), interpolation=cv2.INTER_NEAREST)
    assert pixel_error_ratio(res.mask, full_truth) < 0.01
    image = np.full((384, 1280, 3), 200, np.uint8)
    masked = apply_mask(image, res.mask)
    assert masked[:, :700].min() == 200 and masked[:, 900:].max() == 0
    with pytest.raises(CompanionError):
        apply_mask(image[:100], res.mask)


def test_pepper_noise_does_not_punch_holes():
    yy, xx = _grid()
    truth = xx < 200
    d = _scene(truth)
    rng = np.random.default_rng(5)
    ys, xs = rng.integers(0, H, 60), rng.integers(0, 190, 60)
    d[ys, xs] = FAR  # isolated far pixels inside the wall (salt-and-pepper from the network)
    res = extract_roi(d)
    assert pixel_error_ratio(res.mask, np.where(truth, 255, 0).astype(np.uint8)) < 0.01


@pytest.mark.parametrize("bad", [np.zeros((4, 4)), np.zeros((2, 3, 50, 50)), np.full((20, 20), np.nan)])
def test_bad_disparity_raises(bad):
    with pytest.raises(CompanionError):
        extract_roi(bad)


def test_otsu_splits_bimodal_values():
    v = np.concatenate([np.full(100, 1.0), np.full(50, 5.0)])
    assert 1.0 <= otsu_threshold(v) < 5.0


def test_surface_running_into_the_distance_is_cut_by_depth():
    # a roof seen from above: disparity falls smoothly from the wall top (row 60) to far away at the top edge,
    # with no jump anywhere; what is more than 2x farther than the wall goes, the wall and near roof stay
    yy, xx = _grid()
    d = np.full((H, W), WALL, np.float32)
    roof = yy < 60
    d[roof] = (WALL * np.exp(-(60 - yy[roof]) / 15.0)).astype(np.float32)  # halves every ~10 rows
    res = extract_roi(d)
    assert not res.no_boundary
    assert res.mask[60:].min() == 255 and res.mask[d > 0.8 * WALL].min() == 255
    assert res.mask[d < 0.5 * WALL].max() == 0


def test_far_cut_without_any_boundary():
    # a gentle slope (no gradient above the floor, so no boundary) that still reaches 3x the wall's depth
    d = np.tile(np.linspace(0.09, 0.27, W, dtype=np.float32), (H, 1))
    res = extract_roi(d)
    assert res.n_regions == 1
    cut = RoiParams().far_cut_ratio * 0.27  # the default: more than 2.5x farther than the facade is cut
    assert res.mask[:, d[0] >= cut + 0.005].min() == 255 and res.mask[:, d[0] < cut - 0.005].max() == 0
    assert extract_roi(d, params=RoiParams(far_cut_ratio=0.0)).roi_fraction == 1.0  # the paper's method alone


def test_small_wall_joined_to_the_sky_is_not_dropped_as_background():
    # The start of a strip: a quarter of the frame is wall (bottom right), the rest far sky and ground. The wall's
    # left end fades smoothly into the ground (no boundary there), so wall, ground and sky are one region whose
    # mean disparity is the sky's. The frame must still be kept, and only the wall with it.
    yy, xx = _grid()
    d = np.full((H, W), 0.002, np.float32)  # sky / far ground: ~50x the wall's distance
    wall = (yy >= 60) & (xx >= 200)
    d[wall] = WALL
    fade = (yy >= 60) & (xx >= 140) & (xx < 200)
    d[fade] = (WALL * np.exp(-(200 - xx[fade]) / 8.0)).astype(np.float32)  # wall end into the ground, no jump
    res = extract_roi(d, params=RoiParams(min_roi_disparity=0.05))
    assert res.n_regions == 1  # one region, as described
    assert not res.empty
    assert res.mask[wall].min() == 255 and res.mask[d < (RoiParams().far_cut_ratio - 0.02) * WALL].max() == 0

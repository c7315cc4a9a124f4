"""The warp renderer's far scenery layers (``_FarLayer``): re-used for a sub-pixel move, rendered again after a
large one, and in both cases the frame's truth is the ray caster's up to boundary pixels."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from sim.camera.render import FAR, SKY, TARGET, Renderer
from sim.camera.scene import Scene
from sim.camera.warp_render import WarpRenderer
from tests.test_camera_warp_render import CAM, FRAME, H, L, _boundaries, pose_at

KW = dict(noise=False, blur=False)
START = pose_at(-1.0, 4.0, 6.0)  # off the wall's left end: far buildings, trees, ground and sky beside the wall


@pytest.fixture(scope="module")
def scene():
    return Scene.build(L, H, seed=0)


def _counts(r: WarpRenderer) -> tuple[int, int]:
    got = r.layer_counts()
    return sum(v[0] for v in got.values()), sum(v[1] for v in got.values())


def _depth_edges(depth: np.ndarray) -> np.ndarray:
    """Pixels within one pixel of a depth step of over 5 % (one far building's silhouette on another's: the same
    surface id, a different object)."""
    inv = np.where(np.isfinite(depth), 1.0 / depth, 0.0).astype(np.float32)
    k = np.ones((3, 3), np.uint8)
    hi, lo = cv2.dilate(inv, k), cv2.erode(inv, k)
    return hi > lo * 1.05


def _agrees(got, ref, depth_rel: float) -> None:
    """Surfaces differ only on the reference's boundary pixels (few of them), the ROI mask likewise, sky where the
    reference has sky, depth within ``depth_rel`` where the surfaces agree off depth steps."""
    edge = _boundaries(ref.surface)
    differ = got.surface != ref.surface
    assert not (differ & ~edge).any(), "surfaces differ off the boundaries"
    assert differ.mean() < 0.003
    roi_differ = got.roi_mask != ref.roi_mask
    assert not (roi_differ & ~edge).any() and roi_differ.mean() < 0.003
    assert (np.isinf(got.depth) == np.isinf(ref.depth))[~differ].all()
    steps = _depth_edges(ref.depth)
    same = ~differ & np.isfinite(ref.depth) & ~steps
    rel = np.abs(got.depth[same] - ref.depth[same]) / ref.depth[same]
    assert rel.max() < depth_rel


def test_a_layer_is_reused_for_a_sub_pixel_move_and_keeps_the_truth(scene):
    layered = WarpRenderer(scene, FRAME, CAM, **KW)
    layered.render(START)
    renders, reuses = _counts(layered)
    assert renders >= 2 and reuses == 0  # the first frame renders every layer in view (bands and sky)
    nxt = pose_at(-1.0, 4.0, 6.024)  # 1/30 s later at the scan's climb of 0.72 m/s
    got = layered.render(nxt)
    assert _counts(layered)[0] == renders and _counts(layered)[1] >= 2, "the layers were not re-used"
    fresh = WarpRenderer(scene, FRAME, CAM, **KW).render(nxt)
    assert np.array_equal(got.roi_mask, fresh.roi_mask)  # the wall is drawn every frame
    assert {FAR, SKY} <= set(np.unique(got.surface).tolist())
    _agrees(got, fresh, 2e-3)  # a re-used far point's depth is its render pose's: 2.4 cm of 20 m or more
    _agrees(got, Renderer(scene, FRAME, CAM, **KW).render(nxt), 2e-3)
    diff = np.abs(got.image.astype(np.int16) - fresh.image).max(axis=-1)
    assert float(np.mean(diff > 1)) < 0.03  # a sub-pixel move: all but silhouettes and sharp texture within 1 DN
    assert float(np.mean(diff)) < 0.5


def test_a_stale_layer_is_rendered_again_after_a_large_move(scene):
    layered = WarpRenderer(scene, FRAME, CAM, **KW)
    before = layered.render(START)
    moved = pose_at(-3.0, 4.0, 7.0)  # 2 m along and 1 m up: the far buildings move several pixels
    renders = _counts(layered)[0]
    got = layered.render(moved)
    assert _counts(layered)[0] > renders, "no layer was rendered again"
    fresh = WarpRenderer(scene, FRAME, CAM, **KW).render(moved)
    # the move matters: the old frame's far surfaces are not where the new pose sees them
    far_now = fresh.surface == FAR
    assert float(np.mean((before.surface == FAR) != far_now)) > 0.003
    _agrees(got, fresh, 2e-3)  # (a distant object may still qualify for re-use: its render pose's depth)
    _agrees(got, Renderer(scene, FRAME, CAM, **KW).render(moved), 2e-3)
    assert float(np.abs(got.image.astype(np.int16) - fresh.image).mean()) < 0.2


def test_layers_off_draws_every_frame_in_full(scene):
    """``layers=False`` is the per-frame reference path: no layer, everything drawn as before."""
    plain = WarpRenderer(scene, FRAME, CAM, layers=False, **KW)
    assert plain.layer_counts() == {}
    got = plain.render(START)
    assert (got.surface == TARGET).any() and (got.surface == FAR).any()

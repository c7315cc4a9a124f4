"""Training-data randomisation: the plain-wall and overcast-sky changes touch only their regions, keep the geometry,
and do what they are for (less wall texture; a sky that is flat but never the wall's exact shade; bright grey
cladding, off unless asked for)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from companion.depth.training.data import (
    FrameSet,
    augment_crop,
    bright_cladding,
    overcast_sky,
    plain_wall,
    randomise,
    sample_batch,
)


def _scene(h: int = 96, w: int = 160) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Textured wall below a blue sky: float BGR image, facade mask, sky mask."""
    rng = np.random.default_rng(0)
    img = np.empty((h, w, 3), np.float32)
    img[:] = (0.85, 0.6, 0.4)  # sky (BGR: blue)
    facade = np.zeros((h, w), bool)
    facade[h // 3 :] = True
    img[facade] = 0.4 + 0.3 * rng.random((int(facade.sum()), 3)).astype(np.float32)  # busy brick-like texture
    return img, facade, ~facade


def _texture(image: np.ndarray, where: np.ndarray) -> float:
    """High-frequency spread, the low-frequency light field excluded."""
    return float((image - cv2.GaussianBlur(image, (0, 0), 2.0))[where].std())


def test_plain_wall_flattens_only_the_facade():
    img, facade, sky = _scene()

    for seed in range(20):
        out = plain_wall(img, facade, np.random.default_rng(seed))
        assert out.shape == img.shape and out.dtype == np.float32
        np.testing.assert_array_equal(out[sky], img[sky])  # the sky is untouched
        changed = np.abs(out - img).max(axis=2) > 1e-6
        assert changed.any() and not (changed & sky).any()
        inner = changed & (cv2.erode(changed.astype(np.uint8), np.ones((9, 9), np.uint8)) > 0)
        if inner.sum() > 100:
            assert _texture(out, inner) < 0.6 * _texture(img, inner)


def test_overcast_sky_is_flat_and_never_the_walls_shade():
    img, facade, sky = _scene()
    wall_level = float(img[facade].mean())
    for seed in range(30):
        out = overcast_sky(img, sky, np.random.default_rng(seed))
        np.testing.assert_array_equal(out[facade], img[facade])
        deck = out[sky]
        grey = np.abs(deck - deck.mean(axis=1, keepdims=True)).max()
        assert grey < 0.05  # near-neutral: a cloud deck, not the blue sky
        ratio = float(deck.mean()) / wall_level
        assert ratio >= 1.1 or ratio <= 0.9, ratio


def test_regions_too_small_are_left_alone():
    img, facade, sky = _scene()
    tiny = np.zeros_like(facade)
    tiny[0, :10] = True
    rng = np.random.default_rng(1)
    np.testing.assert_array_equal(plain_wall(img, tiny, rng), img)
    np.testing.assert_array_equal(overcast_sky(img, tiny, rng), img)


@pytest.mark.parametrize("seed", range(3))
def test_sample_batch_uses_truth_masks_and_keeps_depth(seed):
    img, facade, _ = _scene()
    depth = np.where(facade, 6.0, 100.0).astype(np.float16)
    frames = FrameSet(
        np.repeat((img * 255).astype(np.uint8)[None], 4, axis=0),
        np.repeat(depth[None], 4, axis=0),
        np.repeat((facade * 255).astype(np.uint8)[None], 4, axis=0),
    )
    x, d, f = sample_batch(frames, 5, (64, 128), np.random.default_rng(seed), max_depth=100.0)
    assert x.shape == (5, 3, 64, 128) and d.shape == (5, 1, 64, 128)
    assert x.dtype == np.float32 and x.min() >= 0.0 and x.max() <= 1.0
    assert set(np.unique(d)) <= {6.0, 100.0}  # randomisation never touches the depth


def test_randomise_without_masks_still_works():
    img, _, _ = _scene()
    out = randomise((img * 255).astype(np.uint8), np.random.default_rng(0))
    assert out.shape == img.shape and out.dtype == np.uint8


def test_bright_cladding_makes_the_facade_bright_grey_and_plain_and_leaves_the_rest():
    img, facade, sky = _scene()
    img[facade] *= 0.6  # a dark textured wall, the labelled photos' common case
    for seed in range(20):
        out = bright_cladding(img, facade, np.random.default_rng(seed))
        assert out.shape == img.shape and out.dtype == np.float32
        np.testing.assert_array_equal(out[sky], img[sky])
        changed = np.abs(out - img).max(axis=2) > 1e-6
        if changed.sum() < 200:  # a patch that missed most of the wall
            continue
        wall = out[changed]
        assert wall.mean() > 0.45 > img[changed].mean()  # bright
        assert np.abs(wall.mean(axis=0) - wall.mean()).max() < 0.08 * wall.mean()  # grey (at most a faint tint)
        inner = changed & (cv2.erode(changed.astype(np.uint8), np.ones((9, 9), np.uint8)) > 0)
        assert _texture(out, inner) < 0.5 * _texture(img, inner)  # plain (light field and seams aside)


def test_bright_walls_off_draws_nothing_and_on_keeps_the_geometry():
    img, facade, sky = _scene()
    image = (img * 255).astype(np.uint8)
    for seed in range(10):
        np.testing.assert_array_equal(
            randomise(image, np.random.default_rng(seed), facade=facade, sky=sky),
            randomise(image, np.random.default_rng(seed), facade=facade, sky=sky, bright_walls=0.0),
        )
    depth = np.where(facade, 6.0, 100.0).astype(np.float32)
    for seed in range(10):
        x, d, f = augment_crop(image, depth, (facade * 255).astype(np.uint8), sky, np.random.default_rng(seed),
                               (64, 96), bright_walls=1.0)
        assert x.shape == (3, 64, 96)
        np.testing.assert_array_equal(d[0] == 6.0, f[0])  # the facade crop and its depth still agree

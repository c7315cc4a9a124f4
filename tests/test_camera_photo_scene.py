"""Real photos as simulator textures: exact truth masks, depth, texture coordinates and true overlap."""

from __future__ import annotations

import math

import numpy as np
import pytest

from companion.errors import CompanionError
from sim.camera.model import CameraModel
from sim.camera.photo_passes import RECIPES, PassRecipe, build_pass
from sim.camera.photo_scene import PhotoPass, PhotoPassRenderer, PhotoTexture, true_overlap

CAM = CameraModel(width=480, height=270, hfov_deg=69.0)


def _checker(h: int, w: int, cell: int) -> np.ndarray:
    yy, xx = np.mgrid[0:h, 0:w]
    g = np.where(((yy // cell) + (xx // cell)) % 2 == 0, 200, 60).astype(np.uint8)
    return np.dstack([g, g, g])


def _pass(alpha=None, **kw) -> PhotoPass:
    wall = PhotoTexture("wall", _checker(400, 800, 20), 12.0, alpha)
    bg = PhotoTexture("bg", np.full((300, 400, 3), (250, 180, 90), np.uint8), 1.0)
    return PhotoPass("t", wall, bg, camera=CAM, frames=kw.pop("frames", 40), background_frames=kw.pop("bg", 6), **kw)


def test_frames_go_from_wall_only_to_background_only_with_exact_depth():
    r = PhotoPassRenderer(_pass())
    first, last = r.render(0), r.render(len(r) - 1)
    assert first.wall_fraction == 1.0  # left image edge on the wall's left end, whole view inside the wall
    assert last.wall_fraction == 0.0
    assert sum(r.render(i).wall_fraction == 0.0 for i in range(len(r))) == 6
    assert np.all(first.depth == 4.0) and np.all(last.depth == 124.0)
    mid = r.render(30)
    assert 0 < mid.wall_fraction < 1
    # the wall's right end (along 12 m) projects where the truth mask ends
    col = int(np.argmax(mid.roi_mask[135] == 0))
    x_end = (12.0 - mid.along_m) / 4.0 * CAM.fx + CAM.width / 2
    assert abs(col - x_end) <= 1.0


def test_texture_coordinates_map_pixels_to_the_wall_and_give_the_true_overlap():
    r = PhotoPassRenderer(_pass())
    a, b = r.render(2), r.render(3)
    centre = a.wall_from_image @ np.array([CAM.width / 2 - 0.5, CAM.height / 2 - 0.5, 1.0])
    assert centre[:2] == pytest.approx([a.along_m, a.up_m], abs=1e-9)
    footprint = 2 * 4.0 * math.tan(math.radians(34.5))
    expected = 1 - (b.along_m - a.along_m) / footprint
    assert true_overlap(a, b, (CAM.height, CAM.width)) == pytest.approx(expected, abs=0.01)


def test_label_background_is_a_hole_in_the_wall():
    alpha = np.full((400, 800), 255, np.uint8)
    alpha[:100] = 0  # the photo's top quarter is sky in its labels
    spec = _pass(alpha, strips_up_m=(5.6,))  # camera near the top: the view reaches above the facade
    f = PhotoPassRenderer(spec).render(0)
    top_of_facade = 6.0 * 0.75  # wall is 6 m tall, the facade ends 1.5 m below its top
    row = int(np.argmax(f.roi_mask[:, 240] > 0))
    expected = (5.6 - top_of_facade) / 4.0 * CAM.fx + CAM.height / 2
    assert abs(row - expected) <= 1.0
    assert np.all(f.depth[: row - 1] == 124.0)
    assert np.abs(f.image[: row - 2].astype(int) - (250, 180, 90)).max() <= 12  # background shows through


def test_bad_specs_are_refused():
    with pytest.raises(CompanionError, match="background"):
        _pass(background_distance_m=-5.0)
    with pytest.raises(CompanionError, match="alpha"):
        PhotoTexture("w", _checker(10, 10, 2), 1.0, np.zeros((5, 5), np.uint8))


def test_passes_use_held_out_photos_only():
    spec = build_pass(RECIPES["cmp-balconies"], frames=10, background_frames=2)
    assert spec.wall.alpha is not None and 0.8 < (spec.wall.alpha > 0).mean() < 1.0
    with pytest.raises(CompanionError, match="training split"):
        build_pass(PassRecipe("x", "cmp_b0001.jpg", 10.0, RECIPES["cmp-balconies"].background_photo))


def test_custom_pass_from_photo_files(tmp_path):
    import cv2

    from sim.camera.photo_passes import parse_recipe

    cv2.imwrite(str(tmp_path / "wall.png"), _checker(300, 400, 10))
    cv2.imwrite(str(tmp_path / "bg.png"), np.full((200, 300, 3), 90, np.uint8))
    recipe = parse_recipe(f"mine:{tmp_path / 'wall.png'}:8:{tmp_path / 'bg.png'}:300")
    spec = build_pass(recipe, frames=10, background_frames=2)
    assert spec.wall.width_m == 8.0 and spec.wall.height_m == 6.0 and spec.background_distance_m == 300.0
    assert spec.wall.alpha is None  # no labels: the whole photo is wall
    with pytest.raises(CompanionError, match="NAME:WALL_PHOTO"):
        parse_recipe("mine:wall.png")
    with pytest.raises(CompanionError, match="not found"):
        build_pass(parse_recipe("x:nope.png:8:bg.png"))

"""Procedural facade texture: seamless tiles, consistent with point evaluation, cracks where the truth says."""

from __future__ import annotations

import numpy as np
import pytest

from sim.camera.noise import fbm, grid_coords, value_noise
from sim.camera.textures import FacadeStyle, FacadeTexture


def test_noise_is_a_deterministic_function_of_position():
    x = np.linspace(-0.5, 0.5, 1001)  # 1 mm steps
    y = np.linspace(3.0, 3.5, 1001)
    a = value_noise(x, y, 0.3, 5)
    assert np.array_equal(a, value_noise(x, y, 0.3, 5))
    assert a.min() >= 0.0 and a.max() < 1.0
    assert not np.array_equal(a, value_noise(x, y, 0.3, 6))
    # continuous: neighbours 1 mm apart differ little at 0.3 m features
    assert np.abs(np.diff(a)).max() < 0.05
    assert np.abs(fbm(x, y, 1.0, 2, octaves=4)).max() <= 1.0


def test_grid_noise_is_bit_identical_to_point_noise():
    """Tiles evaluate noise separably on their regular grid (lattice hashed once); every value must equal the
    per-point evaluation exactly, for any origin (negative coordinates wrap the lattice hash), spacing and cell."""
    rng = np.random.default_rng(7)
    used_grid = 0
    for _ in range(60):
        px = float(10 ** rng.uniform(-3.5, 1.0))
        xs = rng.uniform(-3000, 3000) + (np.arange(int(rng.integers(2, 200))) + 0.5) * px
        ys = rng.uniform(-3000, 3000) + (np.arange(int(rng.integers(2, 200))) + 0.5) * px
        cell, seed = float(10 ** rng.uniform(-3, 2)), int(rng.integers(0, 1000))
        grid, full = grid_coords(xs, ys), np.meshgrid(xs, ys)
        assert np.array_equal(value_noise(*grid, cell, seed), value_noise(*full, cell, seed))
        assert np.array_equal(fbm(*grid, cell, seed, octaves=4, min_cell=px), fbm(*full, cell, seed, octaves=4,
                                                                                  min_cell=px))
        used_grid += cell > px
    assert used_grid > 10  # the separable path was taken (cells coarser than the grid spacing)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_tiles_join_seamlessly_and_match_point_evaluation(seed):
    tex = FacadeTexture(FacadeStyle.from_seed(seed, 26.5, 12.0))
    level = 3  # 8 mm texels
    px = 0.008
    patch, a0, u0, got_px = tex.patch(1.0, 2.0, 3.5, 3.0, level)  # spans several tiles
    assert got_px == pytest.approx(px)
    assert patch.shape[1] == tex.TILE * (int(3.5 / (tex.TILE * px)) - int(1.0 / (tex.TILE * px)) + 1)
    # texels straddling a tile border equal a direct evaluation at the same centres
    col = tex.TILE - 1
    aa = a0 + (np.array([col, col + 1]) + 0.5) * px
    uu = np.full(2, u0 + 10.5 * px)
    direct = (tex.evaluate(aa, uu, px) * 255 + 0.5).astype(np.uint8)
    assert np.abs(patch[10, col : col + 2].astype(int) - direct.astype(int)).max() <= 1


def test_cracks_are_recorded_and_drawn():
    style = FacadeStyle.from_seed(4, 26.5, 12.0, n_cracks=3)
    assert len(style.cracks) == 3
    tex = FacadeTexture(style)
    for c in style.cracks:
        assert 0.0005 <= c.width_m <= 0.004 and 0.3 < c.length_m < 2.0
        p = np.asarray(c.points)
        mid = p[len(p) // 2]
        on = tex.evaluate(np.array([mid[0]]), np.array([mid[1]]), 0.0005).mean()
        off = tex.evaluate(np.array([mid[0] + 0.05]), np.array([mid[1]]), 0.0005).mean()
        assert on < off * 0.6
    truth = style.to_json()["cracks"]
    assert [t["width_m"] for t in truth] == [c.width_m for c in style.cracks]


def test_full_image_orientation():
    style = FacadeStyle.from_seed(0, 10.0, 6.0, n_cracks=0)
    img = FacadeTexture(style).full_image(50)
    assert img.shape == (120, 200, 3)
    # the parapet coping is at the top (row 0), the darker plinth at the bottom
    assert img[:3].mean() > img[-3:].mean()

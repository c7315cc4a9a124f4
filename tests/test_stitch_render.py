"""The OpenCV renderer (per-cell warpPerspective, blending in OpenCV) draws the same map as the per-pixel numpy
reference it replaced (evaluation/stitch/reference_render.py), on hand-made meshes (every cell its own homography,
masks with holes, tile borders) and end to end on a synthetic spool with noisy telemetry."""

from __future__ import annotations

import shutil

import cv2
import numpy as np
import pytest

from companion.stitch import StitchConfig, load_input, stitch
from companion.stitch.mesh import WarpedMesh
from companion.stitch.render import MapGrid, SourceCache, place, render_tile
from companion.stitch.render_plan import best_order, decodes, needs_by_box
from companion.stitch.worker import Stitcher
from evaluation.stitch.reference_render import render_map_pullback, render_tile_pullback
from evaluation.stitch.synthetic import SyntheticWall, make_spool

W, H = 320, 180


def _keyframe(seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    img = cv2.resize(rng.integers(0, 255, (H // 4, W // 4, 3), dtype=np.uint8), (W, H), interpolation=cv2.INTER_CUBIC)
    img = cv2.add(img, rng.integers(0, 40, (H, W, 3), dtype=np.uint8))  # fine detail: interpolation shows
    mask = np.full((H, W), 255, np.uint8)
    cv2.circle(mask, (int(rng.integers(60, 260)), int(rng.integers(40, 140))), 30, 0, -1)  # a tree in front
    mask[:, : int(rng.integers(0, 40))] = 0  # background beyond the wall's end
    return img, mask


def _placed(grid: MapGrid, n: int = 4):
    placed = []
    rng = np.random.default_rng(7)
    for k in range(n):
        xs, ys = np.linspace(0, W, 9), np.linspace(0, H, 6)
        src = np.stack(np.meshgrid(xs, ys), axis=-1)
        # a rotated, scaled placement per keyframe plus a different small offset at every vertex: each cell has
        # its own homography, as after the APAP mesh
        a = np.radians(3.0 * (k - 1.5))
        R = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]) * 1.07
        dst_px = src @ R.T + np.array([30.0 + 95.0 * k, 20.0 + 9.0 * k]) + rng.normal(0, 1.5, src.shape)
        dst_plane = grid.to_plane(dst_px)
        placed.append(place(k, WarpedMesh(src, dst_plane, True), grid))
    return placed


@pytest.mark.parametrize("tile_px", [700, 128])
def test_the_opencv_renderer_draws_the_reference_map(tile_px):
    grid = MapGrid(0.0, 1.0, 0.005, 700, 260)
    placed = sorted(_placed(grid), key=lambda p: p.bbox[0])
    maps = {}
    for renderer in (render_tile_pullback, render_tile):
        sources = SourceCache(_keyframe, size=2)
        img = np.zeros((grid.height, grid.width, 3), np.uint8)
        cov = np.zeros((grid.height, grid.width), np.uint8)
        for y0 in range(0, grid.height, tile_px):
            for x0 in range(0, grid.width, tile_px):
                w, h = min(tile_px, grid.width - x0), min(tile_px, grid.height - y0)
                t, c = renderer(x0, y0, w, h, placed, sources)
                img[y0 : y0 + h, x0 : x0 + w], cov[y0 : y0 + h, x0 : x0 + w] = t, c
        maps[renderer] = img, cov
    (ref, ref_cov), (new, new_cov) = maps[render_tile_pullback], maps[render_tile]
    assert 0.5 < np.count_nonzero(ref_cov) / ref_cov.size < 0.95  # holes and ends are really left out
    assert np.count_nonzero(ref_cov != new_cov) <= 1e-4 * ref_cov.size  # nearest-pixel mask ties at most
    both = (ref_cov > 0) & (new_cov > 0)
    diff = np.abs(ref.astype(int) - new.astype(int)).max(axis=2)[both]
    assert diff.max() <= 2 and diff.mean() < 0.01
    assert new[new_cov == 0].max() == 0  # nothing drawn outside the ROI


def test_tile_order_decodes_each_keyframe_once_when_the_cache_allows():
    # keyframes in vertical strips, as the planner's vertical pattern flies them
    boxes = [(x, y, x + 380, y + 220) for x in range(0, 4000, 300) for y in range(0, 1000, 180)]
    rows = [(x, y) for y in range(0, 1200, 256) for x in range(0, 4400, 256)]
    needs = needs_by_box(4400, 1200, 256, dict(enumerate(boxes)))
    order = best_order(4400, 1200, 256, needs, cache_size=14)
    assert sorted(order) == sorted(rows)
    assert decodes(order, needs, 14) == len(boxes)
    assert decodes(rows, needs, 14) > len(boxes)  # row by row re-decodes strips


@pytest.fixture(scope="module")
def noisy_spool(tmp_path_factory):
    d = tmp_path_factory.mktemp("spool")
    make_spool(d, SyntheticWall(length_m=8.0, height_m=4.0, seed=2), pose_noise_m=0.1, yaw_noise_deg=0.5, seed=2)
    return d


class _KeepsRenderInputs(Stitcher):
    """The stitcher, keeping what its render stage was given (the reference draws the same layout)."""

    def render(self, found, aligned, layout, out):
        self.render_inputs = (found.input, aligned, layout)
        return super().render(found, aligned, layout, out)


def test_end_to_end_maps_of_both_renderers_agree(noisy_spool, noisy_cache, tmp_path):
    # from the module's features and pairs (keyed by the files and settings): what is compared is the drawing
    shutil.copytree(noisy_cache, tmp_path / "out" / "cache")
    stitcher = _KeepsRenderInputs(StitchConfig(), progress=False)
    new = stitcher.stitch(load_input(noisy_spool), tmp_path / "out")
    # the product's render stage (render plan, blend-weight cut, LUT gains, prefetch, drawing threads) against the
    # reference drawing the same layout row by row with every keyframe that reaches a tile
    ref_map, ref_cov = render_map_pullback(*stitcher.render_inputs, stitcher.config)
    assert new.report["alignment"]["local_residual_px"]["median"] is not None
    assert 0.5 < np.count_nonzero(ref_cov) / ref_cov.size < 1.0
    assert np.count_nonzero(new.coverage != ref_cov) <= 1e-4 * ref_cov.size
    both = (new.coverage > 0) & (ref_cov > 0)
    diff = np.abs(new.map_image.astype(int) - ref_map.astype(int)).max(axis=2)[both]
    assert diff.max() <= 2 and diff.mean() < 0.01


def test_the_cache_with_the_plan_decodes_what_the_plan_counts_and_less_than_lru():
    boxes = [(x, y, x + 380, y + 220) for x in range(0, 4000, 300) for y in range(0, 1000, 180)]
    needs = needs_by_box(4400, 1200, 256, dict(enumerate(boxes)))
    rows = [(x, y) for y in range(0, 1200, 256) for x in range(0, 4400, 256)]
    seq = [k for t in rows for k in sorted(needs[t])]
    counts = {}
    for name, schedule in (("lru", None), ("plan", seq)):
        cache = SourceCache(lambda k: (np.zeros((2, 2, 3), np.uint8), np.full((2, 2), 255, np.uint8)), 8, schedule)
        for k in seq:
            assert cache.get(k)[1].shape == (2, 2)
        counts[name] = cache.decoded
    assert counts["plan"] == decodes(rows, needs, 8) < counts["lru"]


@pytest.fixture(scope="module")
def noisy_cache(noisy_spool, tmp_path_factory):
    """Features and pairs of the noisy spool, computed once for the runs that differ only in how they draw."""
    out = tmp_path_factory.mktemp("cached")
    stitch(load_input(noisy_spool), out, StitchConfig(workers=1), progress=False)
    return out / "cache"


def test_tiles_drawn_on_threads_are_the_tiles_drawn_on_one(noisy_spool, noisy_cache, tmp_path):
    runs = {}
    # one worker: every tile drawn on the stage's thread; three: on a pool of drawing threads, in memory and as
    # tile files
    for workers, max_in_memory_px in ((1, 6e7), (3, 6e7), (3, 1000)):
        out = tmp_path / f"w{workers}_{max_in_memory_px:g}"
        shutil.copytree(noisy_cache, out / "cache")  # the same features and pairs: only the drawing differs
        cfg = StitchConfig(workers=workers, tile_px=128, max_in_memory_px=max_in_memory_px)
        res = stitch(load_input(noisy_spool), out, cfg, progress=False)
        assert res.report["render"]["tiles"] > 8 and res.coverage_fraction > 0.5
        if res.map_image is not None:
            runs[workers, "memory"] = np.dstack((res.map_image, res.coverage))
            continue
        tiled = np.zeros((res.grid.height, res.grid.width, 4), np.uint8)
        for p in (out / "tiles").glob("tile_y*_x*.png"):
            y0, x0 = int(p.stem.split("_")[1][1:]), int(p.stem.split("_")[2][1:])
            tile = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
            assert tile.shape == (min(128, res.grid.height - y0), min(128, res.grid.width - x0), 4)
            tiled[y0 : y0 + tile.shape[0], x0 : x0 + tile.shape[1]] = tile
        runs[workers, "tiles"] = tiled
    one = runs[1, "memory"]
    assert np.array_equal(runs[3, "memory"], one)  # pixel for pixel
    assert np.array_equal(runs[3, "tiles"], one)


def test_a_blank_tile_file_is_a_transparent_png_of_the_tile_size(tmp_path):
    from types import SimpleNamespace

    from companion.stitch.canvas import _MapSink

    layout = SimpleNamespace(grid=SimpleNamespace(width=300, height=200))
    sink = _MapSink(layout, StitchConfig(tile_px=128, max_in_memory_px=1000), tmp_path / "tiles")
    drawn = np.zeros((72, 128, 3), np.uint8)
    drawn[5, 7] = (1, 2, 3)
    cov = np.zeros((72, 128), np.uint8)
    cov[5, 7] = 255
    for x0, img, c in ((0, np.zeros((72, 128, 3), np.uint8), np.zeros((72, 128), np.uint8)), (128, drawn, cov)):
        sink.write_tile(x0, 128, img, c)
        sink.write_tile(x0, 128, img, c)  # rewritten: the same file
    blank = cv2.imread(str(tmp_path / "tiles" / "tile_y0000128_x0000000.png"), cv2.IMREAD_UNCHANGED)
    assert blank.shape == (72, 128, 4) and not blank.any()
    one = cv2.imread(str(tmp_path / "tiles" / "tile_y0000128_x0000128.png"), cv2.IMREAD_UNCHANGED)
    assert tuple(one[5, 7]) == (1, 2, 3, 255) and np.count_nonzero(one.any(axis=2)) == 1



@pytest.mark.parametrize("shape", [(1, 1), (1, 2), (3, 1), (5, 7)])
def test_weights_of_a_one_pixel_box_are_compared_like_any_other(shape):
    """A keyframe whose blend weight reaches the threshold at one pixel of a tile gives a 1 x 1 box. OpenCV's Python
    binding reads a 1 x 1 array as a scalar, so ``cv2.compare(box, threshold)`` raised "neither 'array op array' nor
    'array op scalar'" and the fresh-clone demo's stitch stopped with no map (2026-12-02)."""
    from companion.stitch.render import MIN_BLEND_WEIGHT, _compare

    e = np.random.default_rng(3).uniform(0.0, 2.0 * MIN_BLEND_WEIGHT, shape).astype(np.float32)
    got = _compare(e, MIN_BLEND_WEIGHT, cv2.CMP_GE)
    assert got.shape == shape and got.dtype == np.uint8
    assert np.array_equal(got > 0, e >= MIN_BLEND_WEIGHT)

"""A map kept as tiles drawn as render tasks (``canvas.render_batch``, what the site's Dask cluster runs) is the map
the stitcher draws on its own threads: the same tile files pixel for pixel, the same preview and coverage. The
batches go through pickle, as to a worker: they carry paths, meshes and gains, never pixels. And the map-size
guard: refused by default over ``max_map_px``, with the option that allows it named in the fix."""

from __future__ import annotations

import argparse
import pickle
import shutil

import cv2
import numpy as np
import pytest

from companion.errors import CompanionError
from companion.stitch import StitchConfig, stitch
from companion.stitch.canvas import render_batch
from companion.stitch.commands import add_map_arguments, config_from_args
from companion.stitch.merge import merge_spools


class _Pickled:
    """A tile runner in this process: every batch and result pickled, as a Dask worker gets and returns them."""

    slots = 2

    def __init__(self):
        self.batches = 0

    def map(self, fn, items):
        for item in items:
            assert fn is render_batch
            self.batches += 1
            yield pickle.loads(pickle.dumps(fn(pickle.loads(pickle.dumps(item)))))


def _tiles(folder):
    return {p.name: cv2.imread(str(p), cv2.IMREAD_UNCHANGED) for p in sorted((folder / "tiles").glob("tile_*.png"))}


TILED = StitchConfig(tile_px=128, max_in_memory_px=1e4, workers=2)


@pytest.fixture(scope="module")
def own(site_face, tmp_path_factory):
    """The face's map kept as tiles, drawn on the stitcher's own threads: the map both tests compare with, stitched
    once (read-only: a test copies its cache)."""
    return stitch(merge_spools(list(site_face))[0], tmp_path_factory.mktemp("own"), TILED, progress=False)


def test_render_tasks_draw_the_tiles_the_stitcher_draws(site_face, own, tmp_path):
    main, refly = site_face
    shutil.copytree(own.out_dir / "cache", tmp_path / "tasks" / "cache")  # the same features, pairs, masks
    runner = _Pickled()
    tasks = stitch(merge_spools([main, refly])[0], tmp_path / "tasks", TILED, progress=False, tiles=runner)
    assert own.report["render"]["tiles"] > 8 and runner.batches == tasks.report["render"]["render_tasks"] > 1
    a, b = _tiles(own.out_dir), _tiles(tmp_path / "tasks")
    assert a.keys() == b.keys() and all(np.array_equal(a[k], b[k]) for k in a)
    assert not list((tmp_path / "tasks" / "tiles").glob(".*"))  # no temporary file left: each written atomically
    for name in ("map_preview.jpg", "coverage_preview.png"):
        pa, pb = (cv2.imread(str(d / name), cv2.IMREAD_UNCHANGED) for d in (own.out_dir, tmp_path / "tasks"))
        assert np.array_equal(pa, pb), name
    assert tasks.coverage_fraction == own.coverage_fraction and tasks.uncovered == own.uncovered


def test_a_coarser_plan_on_a_larger_map_draws_the_same_tiles(site_face, own, tmp_path, monkeypatch):
    """Maps over ``PLAN_MAX_BLOCKS`` plan on coarser blocks (a gigapixel map: 16 px), so the plan's memory does not
    grow with the map; the tiles are the same pixels (here: this map's plan forced onto 32 px blocks)."""
    from companion.stitch import canvas

    fine = own  # drawn on the default plan
    assert canvas.plan_block_px(fine.grid.width, fine.grid.height) == 8
    monkeypatch.setattr(canvas, "PLAN_MAX_BLOCKS", 1e3)
    assert canvas.plan_block_px(fine.grid.width, fine.grid.height) == 32
    monkeypatch.setattr(canvas, "PLAN_MAX_BLOCKS", 4e6)
    assert canvas.plan_block_px(40000, 25000) == 16  # a gigapixel map, at the default limit
    monkeypatch.setattr(canvas, "PLAN_MAX_BLOCKS", 1e3)
    shutil.copytree(own.out_dir / "cache", tmp_path / "coarse" / "cache")
    stitch(merge_spools(list(site_face))[0], tmp_path / "coarse", TILED, progress=False)
    a, b = _tiles(own.out_dir), _tiles(tmp_path / "coarse")
    assert a.keys() == b.keys() and all(np.array_equal(a[k], b[k]) for k in a)


def test_a_map_over_the_limit_is_refused_naming_the_option_that_allows_it(site_face, tmp_path):
    with pytest.raises(CompanionError) as err:
        stitch(merge_spools(list(site_face))[0], tmp_path / "big", StitchConfig(max_map_px=1e5), progress=False)
    assert "688x421 px (0.29 MP)" in err.value.problem and "over the limit of 0.1 MP" in err.value.problem
    assert "--max-map-px 3e5" in err.value.fix  # the face's map at its native scale
    parser = argparse.ArgumentParser()
    add_map_arguments(parser)
    assert config_from_args(parser.parse_args(["--max-map-px", "2e9"])).max_map_px == 2e9
    assert config_from_args(parser.parse_args([])).max_map_px == StitchConfig().max_map_px == 4e8
    with pytest.raises(CompanionError, match="must be at least 1 pixel"):
        config_from_args(parser.parse_args(["--max-map-px", "0"]))


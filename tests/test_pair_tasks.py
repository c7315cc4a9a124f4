"""Pair matching as tasks (``pairs.match_batch``, what the site's Dask cluster runs) gives the pairs and the map the
stitcher's own threads give, whether the tasks matched every pair or none (the face's thread matches what they did
not): the batches go through pickle, as to a worker (keyframe paths, priors, settings; never features), their
results through the content-keyed pair cache; a rerun after a task died part-way matches only the pairs missing
from the cache."""

from __future__ import annotations

import pickle
import shutil

import cv2
import numpy as np

from companion.stitch import StitchConfig, stitch
from companion.stitch.merge import merge_spools
from companion.stitch.pairs import match_batch


class _Pickled:
    """A pair runner in this process: every batch and result pickled, as a Dask worker gets and returns them."""

    slots = 2

    def __init__(self):
        self.batches, self.matched = 0, 0

    def start(self, fn, items):
        """Every task run before the face's thread goes on (a cluster with free workers): it then finds every pair
        in the cache."""
        for item in items:
            assert fn is match_batch
            self.batches += 1
            self.matched += pickle.loads(pickle.dumps(fn(pickle.loads(pickle.dumps(item)))))
        return lambda: None


class _Cancelled:
    """Tasks that never started (no free worker): the face's own thread matches every pair."""

    slots = 2

    def __init__(self):
        self.cancelled = 0

    def start(self, fn, items):
        assert items

        def cancel():
            self.cancelled += len(items)

        return cancel


def _pairs(folder):
    return {p.name: dict(np.load(p)) for p in sorted((folder / "cache" / "pairs").glob("*.npz"))}


def test_pair_tasks_give_the_pairs_and_map_of_the_stitchers_threads(site_face, tmp_path):
    cfg = StitchConfig(workers=2)
    own = stitch(merge_spools(list(site_face))[0], tmp_path / "own", cfg, progress=False)
    runner = _Pickled()
    tasks = stitch(merge_spools(list(site_face))[0], tmp_path / "tasks", cfg, progress=False, pair_tasks=runner)
    tried = own.report["pairs_tried"]
    assert runner.batches > 1 and runner.matched == tried == tasks.report["pairs_tried"]
    assert own.report["pairs"] == tasks.report["pairs"] and own.report["pairs_rejected"] == tasks.report[
        "pairs_rejected"]
    a, b = _pairs(tmp_path / "own"), _pairs(tmp_path / "tasks")
    assert a.keys() == b.keys() and all(
        all(np.array_equal(a[k][f], b[k][f]) for f in a[k]) and a[k].keys() == b[k].keys() for k in a)
    assert not list((tmp_path / "tasks" / "cache" / "pairs").glob(".*"))  # written atomically
    ma, mb = (cv2.imread(str(tmp_path / d / "map.png"), cv2.IMREAD_UNCHANGED).astype(int) for d in ("own", "tasks"))
    assert np.array_equal(ma, mb)

    # a task that died part-way: the rerun's tasks match only the pairs missing from the cache
    rerun = tmp_path / "rerun"
    shutil.copytree(tmp_path / "tasks" / "cache", rerun / "cache")
    lost = sorted((rerun / "cache" / "pairs").glob("*.npz"))[::3]
    for p in lost:
        p.unlink()
    again = _Pickled()
    stitch(merge_spools(list(site_face))[0], rerun, cfg, progress=False, pair_tasks=again)
    assert again.matched == len(lost) > 0 and _pairs(rerun).keys() == a.keys()
    mc = cv2.imread(str(rerun / "map.png"), cv2.IMREAD_UNCHANGED).astype(int)
    assert np.array_equal(ma, mc)

    # no task started: the face's thread matched them all, the same pairs and map
    none = _Cancelled()
    alone = stitch(merge_spools(list(site_face))[0], tmp_path / "alone", cfg, progress=False, pair_tasks=none)
    assert none.cancelled > 1 and alone.report["pairs"] == own.report["pairs"] and _pairs(tmp_path / "alone").keys(
    ) == a.keys()
    md = cv2.imread(str(tmp_path / "alone" / "map.png"), cv2.IMREAD_UNCHANGED).astype(int)
    assert np.array_equal(ma, md)

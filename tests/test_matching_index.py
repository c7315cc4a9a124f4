"""DescriptorIndex: the keyframe's FLANN index built once and queried by every candidate (issue 17)."""

from __future__ import annotations

import numpy as np
import pytest

from companion.errors import CompanionError
from companion.keyframes import FeatureConfig, FeatureExtractor, OverlapConfig, OverlapEstimator
from companion.keyframes.synthetic import View, render, textured_wall, true_overlap
from companion.matching import DescriptorIndex

W, H = 480, 360


@pytest.fixture(scope="module")
def features():
    tex = textured_wall(1800, 900, seed=1)
    ex = FeatureExtractor(FeatureConfig(long_side_px=480))
    views = [View(700 + dx, 450, W, H) for dx in (0, 30, 60, 90)]
    return views, [ex.extract(render(tex, v)) for v in views]


def test_ratio_test_on_squared_distances_keeps_lowes_threshold():
    # Two indexed points 10 apart on one axis; a query at x has distances x and 10 - x. FLANN reports squared
    # distances, so comparing them with the plain ratio would let x = 4.4 (ratio 0.786 > 0.75) through.
    base = np.zeros((2, 128), np.float32)
    base[1, 0] = 10.0
    for kind in ("flann", "bf"):
        index = DescriptorIndex(base, kind)
        query = np.zeros((2, 128), np.float32)
        query[0, 0], query[1, 0] = 4.2, 4.4  # ratios 0.724 (kept) and 0.786 (rejected)
        qi, ti = index.ratio_test(query, 0.75)
        assert qi.tolist() == [0] and ti.tolist() == [0], kind


def test_flann_index_finds_the_exact_matches(features):
    _, feats = features
    p, q = feats[0], feats[1]
    flann_q, flann_p = DescriptorIndex(p.descriptors, "flann", checks=32).ratio_test(q.descriptors, 0.75)
    bf_q, bf_p = DescriptorIndex(p.descriptors, "bf").ratio_test(q.descriptors, 0.75)
    assert len(bf_q) > 100
    exact = set(zip(bf_q.tolist(), bf_p.tolist(), strict=True))
    approx = set(zip(flann_q.tolist(), flann_p.tolist(), strict=True))
    assert len(exact & approx) >= 0.95 * len(exact)
    assert len(approx - exact) <= 0.05 * len(exact)


def test_estimator_builds_the_reference_index_once_and_measures_true_overlap(features, monkeypatch):
    views, feats = features
    built = []
    real_init = DescriptorIndex.__init__

    def counting_init(self, *args, **kwargs):
        built.append(1)
        real_init(self, *args, **kwargs)

    monkeypatch.setattr(DescriptorIndex, "__init__", counting_init)
    est = OverlapEstimator()
    for v, f in zip(views[1:], feats[1:], strict=True):
        e = est.estimate(feats[0], f)
        assert e.known and abs(e.R - 100 * true_overlap(views[0], v)) < 0.5
    assert len(built) == 1  # one keyframe, three candidates: one index
    est.estimate(feats[1], feats[2])
    assert len(built) == 2  # a new reference gets its own index


def test_fewer_than_two_indexed_descriptors_never_match():
    query = np.ones((3, 128), np.float32)
    for kind in ("flann", "bf"):
        for base in (None, np.zeros((0, 128), np.float32), np.ones((1, 128), np.float32)):
            qi, ti = DescriptorIndex(base, kind).ratio_test(query, 0.75)
            assert len(qi) == 0 and len(ti) == 0


def test_bad_index_settings_are_refused():
    d = np.zeros((4, 128), np.float32)
    with pytest.raises(ValueError, match="unknown matcher"):
        DescriptorIndex(d, "orb")
    with pytest.raises(ValueError, match="checks"):
        DescriptorIndex(d, "flann", checks=0)
    with pytest.raises(CompanionError, match="flann_checks"):
        OverlapConfig(flann_checks=0)

"""companion/matching.py, the one matching path: a frame's descriptor index built once and queried by every frame
matched against it (gate: the keyframe's index, each candidate; stitcher: keyframe j's index, every pair (i, j)),
with each user's settings named, and the matches OpenCV's own FLANN matcher finds with the same settings."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from companion.errors import CompanionError
from companion.keyframes import FeatureConfig, FeatureExtractor, OverlapConfig, OverlapEstimator
from companion.keyframes.overlap import GATE_MATCHING
from companion.matching import DescriptorIndex, MatcherSettings, match_descriptors
from companion.stitch.config import STITCH_MATCHING
from evaluation.keyframes.synthetic import View, render, textured_wall, true_overlap
from evaluation.stitch.evaluate import EVALUATION_MATCHING

W, H = 480, 360


@pytest.fixture(scope="module")
def features():
    tex = textured_wall(1800, 900, seed=1)
    ex = FeatureExtractor(FeatureConfig(long_side_px=480))
    views = [View(700 + dx, 450, W, H) for dx in (0, 30, 60, 90)]
    return views, [ex.extract(render(tex, v)) for v in views]


def _opencv_matcher_pairs(query, indexed, settings: MatcherSettings, seed: int) -> set[tuple[int, int]]:
    """The per-pair matcher the code used before this module was the only path: OpenCV's FlannBasedMatcher with
    the same trees and checks, Lowe's test on its DMatch distances, OpenCV's RNG seeded the same way."""
    cv2.setRNGSeed(seed)
    m = cv2.FlannBasedMatcher({"algorithm": 1, "trees": settings.trees}, {"checks": settings.checks})
    knn = m.knnMatch(query, indexed, k=2)
    return {(a.queryIdx, a.trainIdx) for a, *b in knn if b and a.distance < settings.ratio * b[0].distance}


def test_each_users_settings_are_named_and_explicit():
    for settings in (GATE_MATCHING, STITCH_MATCHING, EVALUATION_MATCHING):
        assert settings.kind == "flann" and settings.trees == 4 and settings.ratio == 0.75
    assert GATE_MATCHING.checks == STITCH_MATCHING.checks == 32 and EVALUATION_MATCHING.checks == 64
    assert OverlapConfig().matching is GATE_MATCHING


@pytest.mark.parametrize("settings", [STITCH_MATCHING, EVALUATION_MATCHING, MatcherSettings(ratio=0.8, trees=2)])
def test_the_index_finds_the_matches_of_opencvs_flann_matcher_with_the_same_settings(features, settings):
    _, feats = features
    p, q = feats[0], feats[2]
    reference = _opencv_matcher_pairs(q.descriptors, p.descriptors, settings, seed=7)
    found = match_descriptors(q.descriptors, p.descriptors, settings, seed=7)
    assert len(found) > 100 and found.query.dtype == found.indexed.dtype == np.intp
    assert set(zip(found.query.tolist(), found.indexed.tolist(), strict=True)) == reference
    # one index, queried by another frame after the first, still gives that frame's own matches
    index = DescriptorIndex(p.descriptors, settings, seed=7)
    index.match(feats[1].descriptors)
    again = index.match(q.descriptors)
    assert set(zip(again.query.tolist(), again.indexed.tolist(), strict=True)) == reference


def test_ratio_test_on_squared_distances_keeps_lowes_threshold():
    # Two indexed points 10 apart on one axis; a query at x has distances x and 10 - x. FLANN reports squared
    # distances, so comparing them with the plain ratio would let x = 4.4 (ratio 0.786 > 0.75) through.
    base = np.zeros((2, 128), np.float32)
    base[1, 0] = 10.0
    for kind in ("flann", "bf"):
        index = DescriptorIndex(base, MatcherSettings(ratio=0.75, kind=kind))
        query = np.zeros((2, 128), np.float32)
        query[0, 0], query[1, 0] = 4.2, 4.4  # ratios 0.724 (kept) and 0.786 (rejected)
        found = index.match(query)
        assert found.query.tolist() == [0] and found.indexed.tolist() == [0], kind


def test_flann_index_finds_the_exact_matches(features):
    _, feats = features
    p, q = feats[0], feats[1]
    approx = match_descriptors(q.descriptors, p.descriptors, GATE_MATCHING)
    exact = match_descriptors(q.descriptors, p.descriptors, MatcherSettings(kind="bf"))
    assert len(exact) > 100
    exact_set = set(zip(exact.query.tolist(), exact.indexed.tolist(), strict=True))
    approx_set = set(zip(approx.query.tolist(), approx.indexed.tolist(), strict=True))
    assert len(exact_set & approx_set) >= 0.95 * len(exact_set)
    assert len(approx_set - exact_set) <= 0.05 * len(exact_set)


def test_estimator_builds_the_reference_index_once_and_measures_true_overlap(features, monkeypatch):
    views, feats = features
    built = []
    real_init = DescriptorIndex.__init__

    def counting_init(self, *args, **kwargs):
        built.append(args[1] if len(args) > 1 else kwargs["settings"])
        real_init(self, *args, **kwargs)

    monkeypatch.setattr(DescriptorIndex, "__init__", counting_init)
    est = OverlapEstimator()
    for v, f in zip(views[1:], feats[1:], strict=True):
        e = est.estimate(feats[0], f)
        assert e.known and abs(e.R - 100 * true_overlap(views[0], v)) < 0.5
    assert built == [GATE_MATCHING]  # one keyframe, three candidates: one index, with the gate's settings
    est.estimate(feats[1], feats[2])
    assert len(built) == 2  # a new reference gets its own index
    exact = OverlapEstimator(OverlapConfig(matching=MatcherSettings(kind="bf"))).estimate(feats[0], feats[1])
    assert built[-1].kind == "bf" and abs(exact.R - 100 * true_overlap(views[0], views[1])) < 0.5


def test_fewer_than_two_indexed_descriptors_never_match():
    query = np.ones((3, 128), np.float32)
    for kind in ("flann", "bf"):
        for base in (None, np.zeros((0, 128), np.float32), np.ones((1, 128), np.float32)):
            found = DescriptorIndex(base, MatcherSettings(kind=kind)).match(query)
            assert len(found) == 0 and len(found.indexed) == 0
    assert len(match_descriptors(None, np.ones((4, 128), np.float32), GATE_MATCHING)) == 0


@pytest.mark.parametrize(
    "bad, named",
    [
        (dict(kind="orb"), "unknown matcher 'orb'"),
        (dict(ratio=1.0), "ratio=1.0"),
        (dict(ratio=0.0), "ratio=0.0"),
        (dict(checks=0), "checks=0"),
        (dict(trees=0), "trees=0"),
    ],
)
def test_bad_matcher_settings_are_refused_with_the_fix(bad, named):
    with pytest.raises(CompanionError, match=named) as err:
        MatcherSettings(**bad)
    assert err.value.fix


def test_the_gate_measures_the_r_opencvs_per_pair_flann_matcher_gives(features, monkeypatch):
    """The gate's estimator through the index with GATE_MATCHING: the same matches, inliers and R, candidate by
    candidate, as with OpenCV's FlannBasedMatcher trained on the keyframe with the same trees, checks, ratio, seed."""
    from companion.keyframes import overlap as overlap_module
    from companion.matching import Matches

    class OpenCVFlannIndex:
        def __init__(self, descriptors, settings, *, seed=None):
            if seed is not None:  # the gate seeds its trees (GATE_INDEX_SEED): the same draw here
                cv2.setRNGSeed(seed)
            self.settings = settings
            self.matcher = cv2.FlannBasedMatcher({"algorithm": 1, "trees": settings.trees}, {"checks": settings.checks})
            self.matcher.add([descriptors])
            self.matcher.train()  # the trees drawn now, as the index draws them when the keyframe is set

        def match(self, query):
            knn = self.matcher.knnMatch(query, k=2)
            good = [a for a, *b in knn if b and a.distance < self.settings.ratio * b[0].distance]
            return Matches(np.array([a.queryIdx for a in good], np.intp), np.array([a.trainIdx for a in good], np.intp))

    views, feats = features

    def run():
        cv2.setRNGSeed(5)
        est = OverlapEstimator()
        return [est.estimate(feats[0], f) for f in feats[1:]]

    ours = run()
    monkeypatch.setattr(overlap_module, "DescriptorIndex", OpenCVFlannIndex)
    theirs = run()
    for a, b in zip(ours, theirs, strict=True):
        assert a.known and (a.matches, a.inliers, a.R, a.dx, a.dy) == (b.matches, b.inliers, b.R, b.dx, b.dy)

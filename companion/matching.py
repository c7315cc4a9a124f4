"""SIFT descriptor matching: descriptors in, Lowe's ratio-tested matches out. The one matching path of the keyframe
gate, the stitcher and the stitch evaluation.

A :class:`DescriptorIndex` is a search structure over one frame's descriptors (FLANN randomised kd-trees, or exact
brute force), built once and queried by every frame matched against it: the gate queries the current keyframe's
index with each candidate, the stitcher keyframe j's with every pair (i, j). :func:`match_descriptors` is the same
path for a pair matched once. How a user matches (ratio, trees, checks) is its own named :class:`MatcherSettings`
(the gate's ``keyframes.overlap.GATE_MATCHING``, the stitcher's ``stitch.config.STITCH_MATCHING``), not a constant
hidden here. Model fits on the matches are ``companion.ransac``'s job.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from companion.errors import CompanionError

MATCHERS = ("flann", "bf")
_FLANN_KDTREE = 1  # FLANN's randomised kd-tree forest (FLANN_INDEX_KDTREE)


@dataclass(frozen=True)
class MatcherSettings:
    """How one user matches SIFT descriptors.

    ``ratio``: Lowe's ratio test, a match is kept when its nearest neighbour is closer than ``ratio`` x the second
    nearest (repeated texture fails it and gives no match rather than a wrong one). ``kind``: ``"flann"``
    (randomised kd-trees, approximate and fast) or ``"bf"`` (exact brute force L2, the reference). ``trees``: kd-trees
    in the FLANN forest. ``checks``: leaves FLANN visits per query; on SIFT 32 finds the ratio-test matches that 64
    finds at about half the search time (measured on the gate's frames and the stitcher's 4K pairs: the dated runs
    in `git show 2510c03:docs/BENCHMARKS.md`, "Cost per measured frame")."""

    ratio: float = 0.75
    kind: str = "flann"
    trees: int = 4
    checks: int = 32

    def __post_init__(self) -> None:
        if self.kind not in MATCHERS:
            raise CompanionError(f"unknown matcher {self.kind!r}", f"use one of {', '.join(MATCHERS)}")
        if not 0.0 < self.ratio < 1.0:
            raise CompanionError(f"matcher ratio={self.ratio} is outside (0, 1)", "use about 0.7-0.8 (Lowe: 0.75)")
        if self.trees < 1 or self.checks < 1:
            raise CompanionError(
                f"matcher trees={self.trees}, checks={self.checks}: FLANN needs at least one tree and one check",
                "use about 4 trees and 32 checks",
            )


@dataclass(frozen=True)
class Matches:
    """Ratio-tested matches as index arrays: ``query[k]`` (a query descriptor) matches ``indexed[k]`` (a descriptor
    of the index); one entry per query descriptor at most."""

    query: np.ndarray  # (M,) intp
    indexed: np.ndarray  # (M,) intp

    def __len__(self) -> int:
        return int(self.query.shape[0])


_NO_MATCHES = Matches(np.zeros(0, dtype=np.intp), np.zeros(0, dtype=np.intp))


class DescriptorIndex:
    """A search structure over one frame's SIFT descriptors, built once and queried by many frames.

    Why: building FLANN's kd-trees is about a fifth of a 2000 x 2000 match (a sixth of a 4K stitcher pair), and
    the gate and the stitcher match many frames against one keyframe, so they build its trees once. Queries return
    numpy index arrays (no per-match DMatch objects). FLANN's randomised trees draw from OpenCV's RNG: ``seed``
    (when given) seeds it first, so the trees, and the matches, are the same whatever ran before on this thread.
    """

    def __init__(self, descriptors: np.ndarray | None, settings: MatcherSettings, *, seed: int | None = None):
        self.settings = settings
        self.descriptors = np.ascontiguousarray(
            np.zeros((0, 128), np.float32) if descriptors is None else descriptors, dtype=np.float32
        )
        self._flann = None
        self._bf = None
        if len(self) < 2:  # a ratio test needs two neighbours; fewer never match
            return
        if settings.kind == "flann":
            if seed is not None:
                cv2.setRNGSeed(seed)
            self._flann = cv2.flann_Index(self.descriptors, {"algorithm": _FLANN_KDTREE, "trees": settings.trees})
        else:
            self._bf = cv2.BFMatcher(cv2.NORM_L2)

    def __len__(self) -> int:
        return int(self.descriptors.shape[0])

    def match(self, query: np.ndarray | None) -> Matches:
        """The query descriptors whose nearest indexed neighbour is clearly closer than the second nearest."""
        if len(self) < 2 or query is None or len(query) == 0:
            return _NO_MATCHES
        query = np.ascontiguousarray(query, dtype=np.float32)
        ratio = self.settings.ratio
        if self._flann is not None:
            idx, dist_sq = self._flann.knnSearch(query, 2, params={"checks": self.settings.checks})
            # FLANN's L2 gives squared distances: d1 < r d2  <=>  d1^2 < r^2 d2^2. A query FLANN could not
            # answer twice comes back with index -1.
            good = (dist_sq[:, 0] < (ratio * ratio) * dist_sq[:, 1]) & (idx[:, 1] >= 0) & (idx[:, 0] >= 0)
            return Matches(np.flatnonzero(good).astype(np.intp), idx[good, 0].astype(np.intp))
        knn = self._bf.knnMatch(query, self.descriptors, k=2)
        good = [m[0] for m in knn if len(m) == 2 and m[0].distance < ratio * m[1].distance]
        return Matches(
            np.array([m.queryIdx for m in good], dtype=np.intp), np.array([m.trainIdx for m in good], dtype=np.intp)
        )


def match_descriptors(
    query: np.ndarray | None, indexed: np.ndarray | None, settings: MatcherSettings, *, seed: int | None = None
) -> Matches:
    """A pair matched once: ``indexed``'s index built and queried by ``query`` (the index path, not a second one)."""
    return DescriptorIndex(indexed, settings, seed=seed).match(query)

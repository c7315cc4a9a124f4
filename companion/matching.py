"""SIFT descriptor matching with Lowe's ratio test, and RANSAC model fits: one home for the keyframe gate and the
stitcher, so both read matches and inliers the same way (index arrays and boolean inlier masks).

Feature extraction itself is ``companion.keyframes.features.FeatureExtractor`` (also shared). What differs
between the two users stays with them as arguments: the gate fits a homography by plain RANSAC with a
similarity fallback (speed, the paper's model); the stitcher uses MAGSAC with a 6-dof affine fallback.
"""

from __future__ import annotations

import cv2
import numpy as np

MATCHERS = ("flann", "bf")
_FLANN_KDTREE = 1
_FLANN_TREES = 4


def make_matcher(kind: str = "flann") -> cv2.DescriptorMatcher:
    """A matcher for float SIFT descriptors: FLANN kd-trees (fast, approximate) or brute force L2 (exact)."""
    if kind == "flann":
        return cv2.FlannBasedMatcher({"algorithm": _FLANN_KDTREE, "trees": _FLANN_TREES}, {"checks": 64})
    if kind == "bf":
        return cv2.BFMatcher(cv2.NORM_L2)
    raise ValueError(f"unknown matcher {kind!r}: use one of {', '.join(MATCHERS)}")


def ratio_test_matches(
    matcher: cv2.DescriptorMatcher, desc_a: np.ndarray, desc_b: np.ndarray, ratio: float
) -> tuple[np.ndarray, np.ndarray]:
    """Indices (into a, into b) of the matches whose best neighbour is clearly closer than the second best
    (Lowe's ratio test); repeated texture fails it and gives no match rather than a wrong one."""
    knn = matcher.knnMatch(desc_a, desc_b, k=2)
    good = [m[0] for m in knn if len(m) == 2 and m[0].distance < ratio * m[1].distance]
    query = np.array([m.queryIdx for m in good], dtype=np.intp)
    train = np.array([m.trainIdx for m in good], dtype=np.intp)
    return query, train


class DescriptorIndex:
    """A search structure over one frame's descriptors, built once and queried by many frames.

    Why: ``ratio_test_matches`` builds FLANN's kd-trees over its second argument on every call, about a fifth of
    a 2000 x 2000 match; the keyframe gate matches every candidate against the same keyframe, so it builds the
    keyframe's trees once here. Queries return numpy index arrays (no per-match DMatch objects), and ``checks``
    (leaves FLANN visits per query) is a parameter: 32 finds the same ratio-test matches as 64 on SIFT at half
    the search time (docs/BENCHMARKS.md, Keyframe gate, "Cost per measured frame"). ``kind="bf"`` is exact.
    """

    def __init__(self, descriptors: np.ndarray, kind: str = "flann", checks: int = 32):
        if kind not in MATCHERS:
            raise ValueError(f"unknown matcher {kind!r}: use one of {', '.join(MATCHERS)}")
        if checks < 1:
            raise ValueError(f"checks={checks} must be at least 1 (FLANN leaves visited per query)")
        self.descriptors = np.ascontiguousarray(
            np.zeros((0, 128), np.float32) if descriptors is None else descriptors, dtype=np.float32
        )
        self.kind = kind
        self._checks = checks
        self._flann = None
        self._bf = None
        if kind == "flann" and len(self) >= 2:  # a ratio test needs two neighbours; fewer never match
            self._flann = cv2.flann_Index(self.descriptors, {"algorithm": _FLANN_KDTREE, "trees": _FLANN_TREES})
        elif kind == "bf":
            self._bf = cv2.BFMatcher(cv2.NORM_L2)

    def __len__(self) -> int:
        return int(self.descriptors.shape[0])

    def ratio_test(self, query: np.ndarray, ratio: float) -> tuple[np.ndarray, np.ndarray]:
        """Indices (into ``query``, into the indexed descriptors) of the query descriptors whose nearest indexed
        neighbour is clearly closer than the second nearest (Lowe's ratio test, as ``ratio_test_matches``)."""
        empty = np.zeros(0, dtype=np.intp)
        if len(self) < 2 or query is None or len(query) == 0:
            return empty, empty
        query = np.ascontiguousarray(query, dtype=np.float32)
        if self._flann is not None:
            idx, dist_sq = self._flann.knnSearch(query, 2, params={"checks": self._checks})
            # FLANN's L2 gives squared distances: d1 < r d2  <=>  d1^2 < r^2 d2^2. A query FLANN could not
            # answer twice comes back with index -1.
            good = (dist_sq[:, 0] < (ratio * ratio) * dist_sq[:, 1]) & (idx[:, 1] >= 0) & (idx[:, 0] >= 0)
            qi = np.flatnonzero(good).astype(np.intp)
            return qi, idx[good, 0].astype(np.intp)
        knn = self._bf.knnMatch(query, self.descriptors, k=2)
        good = [m[0] for m in knn if len(m) == 2 and m[0].distance < ratio * m[1].distance]
        return (np.array([m.queryIdx for m in good], dtype=np.intp),
                np.array([m.trainIdx for m in good], dtype=np.intp))


def ransac_homography(
    src: np.ndarray, dst: np.ndarray, *, method: int, threshold_px: float, max_iters: int, confidence: float
) -> tuple[np.ndarray | None, np.ndarray]:
    """Homography src -> dst by a robust method (``cv2.RANSAC``, ``cv2.USAC_MAGSAC``) and its inlier mask
    (all False when no model was found)."""
    if len(src) < 4:
        return None, np.zeros(len(src), dtype=bool)
    H, mask = cv2.findHomography(src, dst, method, threshold_px, maxIters=max_iters, confidence=confidence)
    if H is None or mask is None:
        return None, np.zeros(len(src), dtype=bool)
    return H, mask.ravel().astype(bool)


def ransac_affine(
    src: np.ndarray, dst: np.ndarray, *, threshold_px: float, partial: bool, max_iters: int = 2000
) -> tuple[np.ndarray | None, np.ndarray]:
    """A 6-dof affine (``partial=False``) or a 4-dof similarity (``partial=True``) src -> dst by RANSAC, as a 3x3
    matrix, and its inlier mask (all False when no model was found)."""
    estimate = cv2.estimateAffinePartial2D if partial else cv2.estimateAffine2D
    A, mask = estimate(src, dst, method=cv2.RANSAC, ransacReprojThreshold=threshold_px, maxIters=max_iters)
    if A is None or mask is None:
        return None, np.zeros(len(src), dtype=bool)
    return np.vstack((A, [0.0, 0.0, 1.0])), mask.ravel().astype(bool)

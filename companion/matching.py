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


def make_matcher(kind: str = "flann") -> cv2.DescriptorMatcher:
    """A matcher for float SIFT descriptors: FLANN kd-trees (fast, approximate) or brute force L2 (exact)."""
    if kind == "flann":
        return cv2.FlannBasedMatcher({"algorithm": _FLANN_KDTREE, "trees": 4}, {"checks": 64})
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

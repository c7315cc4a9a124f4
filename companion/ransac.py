"""Robust model fits on point matches: a homography or an affine transform by RANSAC-family estimators, each
returned with a boolean inlier mask, so the keyframe gate, the stitcher and the evaluation read inliers the same
way. What differs between the users stays with them as arguments: the gate fits a homography by plain RANSAC with
a similarity fallback (speed, the paper's model); the stitcher uses MAGSAC with a 6-dof affine fallback.
"""

from __future__ import annotations

import cv2
import numpy as np


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

"""Map accuracy against a ground-truth facade texture: alignment error (px, mm), SSIM, coverage.

Used by the tests (synthetic walls) and bench/stitch_eval.py (simulator recordings). The truth is resampled
onto the map's own grid, so an error is a true position error on the wall, not just a seam mismatch.
"""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np

from companion.keyframes.features import FeatureConfig, FeatureExtractor
from companion.matching import MatcherSettings, match_descriptors
from companion.ransac import ransac_homography
from companion.stitch.render import MapGrid


def truth_on_grid(
    texture: np.ndarray,
    texture_m_per_px: float,
    height_m: float,
    grid: MapGrid,
    along0_m: float = 0.0,
    pixel_centre: float = 0.0,
) -> np.ndarray:
    """The texture (top-left = along ``along0_m``, up ``height_m``) resampled onto the map grid.

    ``pixel_centre``: texture pixel i sits at (i + pixel_centre) * scale (0 for synthetic.py, 0.5 for the
    simulator's texture).
    """
    ratio = grid.m_per_px / texture_m_per_px
    src = texture
    if ratio > 1.0:  # anti-alias before downsampling
        src = cv2.GaussianBlur(texture, (0, 0), sigmaX=0.45 * ratio)
    # map px (u, v) -> texture px: tx = (along0 + u s - along0_t) / st, ty = (H - (top - v s)) / st
    A = np.array(
        [
            [ratio, 0.0, (grid.along0_m - along0_m) / texture_m_per_px - pixel_centre],
            [0.0, ratio, (height_m - grid.up_top_m) / texture_m_per_px - pixel_centre],
        ]
    )
    return cv2.warpAffine(
        src,
        A,
        (grid.width, grid.height),
        flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
        borderMode=cv2.BORDER_CONSTANT,
        borderValue=0,
    )


def patch_displacements(
    image: np.ndarray,
    truth: np.ndarray,
    valid: np.ndarray,
    *,
    patch: int = 64,
    step: int | None = None,
    min_response: float = 0.2,
) -> tuple[np.ndarray, np.ndarray]:
    """(centres (N, 2), shifts (N, 2)) px of each fully valid, textured patch of ``image`` relative to
    ``truth``, by phase correlation."""
    step = step or patch
    g1 = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY).astype(np.float32) if image.ndim == 3 else image.astype(np.float32)
    g2 = cv2.cvtColor(truth, cv2.COLOR_BGR2GRAY).astype(np.float32) if truth.ndim == 3 else truth.astype(np.float32)
    win = cv2.createHanningWindow((patch, patch), cv2.CV_32F)
    centres, shifts = [], []
    for y in range(0, g1.shape[0] - patch + 1, step):
        for x in range(0, g1.shape[1] - patch + 1, step):
            if valid[y : y + patch, x : x + patch].min() == 0:
                continue
            a, b = g1[y : y + patch, x : x + patch], g2[y : y + patch, x : x + patch]
            if b.std() < 4.0:
                continue  # featureless: no measurable shift
            (dx, dy), resp = cv2.phaseCorrelate(b, a, win)
            if resp >= min_response:
                centres.append((x + patch / 2, y + patch / 2))
                shifts.append((dx, dy))
    return np.asarray(centres, float).reshape(-1, 2), np.asarray(shifts, float).reshape(-1, 2)


def ssim(image: np.ndarray, truth: np.ndarray, valid: np.ndarray) -> float:
    """Mean structural similarity (Gaussian window, sigma 1.5) over valid pixels, on grey levels."""
    a = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY).astype(np.float64) if image.ndim == 3 else image.astype(np.float64)
    b = cv2.cvtColor(truth, cv2.COLOR_BGR2GRAY).astype(np.float64) if truth.ndim == 3 else truth.astype(np.float64)
    c1, c2 = (0.01 * 255) ** 2, (0.03 * 255) ** 2

    def blur(x):
        return cv2.GaussianBlur(x, (11, 11), 1.5)

    ma, mb = blur(a), blur(b)
    va, vb, cov = blur(a * a) - ma**2, blur(b * b) - mb**2, blur(a * b) - ma * mb
    s = ((2 * ma * mb + c1) * (2 * cov + c2)) / ((ma**2 + mb**2 + c1) * (va + vb + c2))
    m = cv2.erode(valid.astype(np.uint8), np.ones((11, 11), np.uint8)) > 0
    return float(s[m].mean()) if m.any() else float("nan")


def map_accuracy(image: np.ndarray, coverage: np.ndarray, truth: np.ndarray, m_per_px: float) -> dict:
    """Absolute error (where on the wall things are drawn) and relative error (after removing the best single
    homography between map and truth: what is left is seams, ghosting and warping; a global offset, tilt or
    keystone from telemetry error is removed, the same way a peer stitcher's panorama is registered).

    Two passes: patch shifts -> robust homography (RANSAC) -> map warped onto the truth by it -> patch shifts
    again, now small, where phase correlation is reliable. Absolute error = fitted homography + residual.
    """
    valid = (coverage > 0) & (truth.max(axis=2) > 0 if truth.ndim == 3 else truth > 0)
    centres, shifts = patch_displacements(image, truth, valid.astype(np.uint8))
    res: dict = {"patches": len(shifts), "ssim": ssim(image, truth, valid)}
    if len(shifts) < 8:
        return res
    H, _ = cv2.findHomography(centres + shifts, centres, cv2.RANSAC, 1.5)  # map position -> truth position
    if H is None:
        H = np.eye(3)
    size = (truth.shape[1], truth.shape[0])
    aligned = cv2.warpPerspective(image, H, size, flags=cv2.INTER_LINEAR)
    aligned_valid = cv2.warpPerspective(valid.astype(np.uint8), H, size, flags=cv2.INTER_NEAREST)
    c2, s2 = patch_displacements(aligned, truth, aligned_valid & valid.astype(np.uint8))
    if len(s2) == 0:
        return res
    # where the map draws the truth point c2: through H^-1, plus the residual shift
    Hinv = np.linalg.inv(H)
    drawn = cv2.perspectiveTransform((c2 + s2).reshape(-1, 1, 2), Hinv).reshape(-1, 2)
    d = np.linalg.norm(drawn - c2, axis=1)
    rel = np.linalg.norm(s2, axis=1)
    mm = m_per_px * 1000.0
    res.update(
        patches=len(s2),
        median_px=float(np.median(d)),
        p95_px=float(np.percentile(d, 95)),
        median_mm=float(np.median(d)) * mm,
        p95_mm=float(np.percentile(d, 95)) * mm,
        rel_median_px=float(np.median(rel)),
        rel_p95_px=float(np.percentile(rel, 95)),
        rel_median_mm=float(np.median(rel)) * mm,
        rel_p95_mm=float(np.percentile(rel, 95)) * mm,
        ssim_registered=ssim(aligned, truth, (aligned_valid > 0) & valid),
    )
    return res


# The evaluation's matcher: 64 checks, the per-pair matcher every recorded map figure was measured with.
EVALUATION_MATCHING = MatcherSettings(ratio=0.75, kind="flann", trees=4, checks=64)
# The evaluation's features: the gate's plain-wall extraction at full resolution, up to 8000 features, keypoints
# anywhere the map is drawn (no ROI erosion); ``equalize=False`` is plain SIFT (OpenCV's contrast threshold).
_EVALUATION_FEATURES = FeatureConfig(long_side_px=0, max_features=8000, mask_erode_px=0)
_PLAIN_SIFT = replace(_EVALUATION_FEATURES, contrast_threshold=0.04, equalize=False)


def truth_homography(image: np.ndarray, truth: np.ndarray, *, equalize: bool = False) -> np.ndarray | None:
    """The best homography from a map with no known geometry (a peer stitcher's panorama) onto the truth grid,
    by SIFT + RANSAC (seeded: the same map always scores the same). ``equalize``: CLAHE and a low contrast
    threshold, the gate's and stitcher's settings; with OpenCV's defaults a plain wall gives features only at its
    few strong edges (a window frame), and a homography fitted to one corner of the map extrapolates badly."""
    extractor = FeatureExtractor(_EVALUATION_FEATURES if equalize else _PLAIN_SIFT)
    grey = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    f1 = extractor.extract(grey, (grey > 0).astype(np.uint8) * 255)
    f2 = extractor.extract(truth)
    if f1.descriptors is None or f2.descriptors is None or len(f1) < 8 or len(f2) < 8:
        return None
    found = match_descriptors(f1.descriptors, f2.descriptors, EVALUATION_MATCHING, seed=7)
    if len(found) < 8:
        return None
    p1, p2 = f1.points[found.query], f2.points[found.indexed]
    H, inl = ransac_homography(p1, p2, method=cv2.USAC_MAGSAC, threshold_px=3.0, max_iters=2000, confidence=0.995)
    if H is None or inl.sum() < 8:
        return None
    return H


def register_to_truth(
    image: np.ndarray,
    truth: np.ndarray,
    *,
    erode_px: int = 5,
    equalize: bool = False,
    H: np.ndarray | None = None,
    drawn: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray] | None:
    """Best homography placement of a map with no known geometry (a peer stitcher's panorama) onto the truth
    grid (``truth_homography``, or ``H`` when given). Returns (warped image, warped coverage eroded by
    ``erode_px``, so interpolated borders do not count) or None when it cannot be registered. Coverage is the
    map's own (``drawn``, 0/255) where it has one, else its non-black pixels (a black wall texel is drawn too)."""
    if H is None:
        H = truth_homography(image, truth, equalize=equalize)
    if H is None:
        return None
    size = (truth.shape[1], truth.shape[0])
    warped = cv2.warpPerspective(image, H, size, flags=cv2.INTER_LINEAR)
    drawn = (image.max(axis=2) > 0).astype(np.uint8) * 255 if drawn is None else drawn
    cov = cv2.warpPerspective(drawn, H, size, flags=cv2.INTER_NEAREST)
    return warped, cv2.erode(cov, np.ones((erode_px, erode_px), np.uint8)) if erode_px > 1 else cov

"""Overlap ratio R between a reference frame Ip and a later frame Iq from matched SIFT features.

Two estimators, both on the same RANSAC inliers:

* ``displacement`` (paper Eq. 2): mean inlier displacement (dx, dy) in full-resolution pixels,
  R = 100 (H - |dy|)(W - |dx|) / (H W). Exact for pure translation at constant standoff, the paper's assumption.
* ``polygon``: the frame rectangle of Iq mapped into Ip by the inverse RANSAC homography, intersected with Ip's
  rectangle; R = 100 * area / (H W). Also right when the camera rotates or the standoff (scale) changes.

Both measure the share of Ip's picture that Iq still shows (the simulator's ``true_overlap(p, q)``).
Too few matches or inliers is not an overlap of zero: the estimate is returned with ``R = None`` and a status
saying why, and the gate treats it as "unknown".
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

import cv2
import numpy as np

from companion.errors import CompanionError
from companion.keyframes.features import FeatureSet

METHODS = ("displacement", "polygon")


class OverlapStatus(StrEnum):
    OK = "ok"
    TOO_FEW_FEATURES = "too_few_features"  # one of the frames has (almost) no texture inside its ROI
    TOO_FEW_MATCHES = "too_few_matches"  # descriptors do not agree: different scene, blur, or too far apart
    TOO_FEW_INLIERS = "too_few_inliers"  # matches do not agree on one geometry
    DEGENERATE = "degenerate"  # RANSAC model folds, mirrors or scales implausibly


@dataclass(frozen=True)
class OverlapConfig:
    method: str = "displacement"
    ratio_test: float = 0.75  # Lowe's ratio
    ransac_reproj_px: float = 3.0  # in working pixels
    min_matches: int = 12
    min_inliers: int = 12
    min_inlier_share: float = 0.15  # inliers / matches; repeated texture gives many wrong matches
    max_scale_change: float = 2.0  # homography area change allowed between neighbouring frames
    matcher: str = "flann"  # "flann" or "bf"

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise CompanionError(f"unknown overlap method {self.method!r}", f"use one of {', '.join(METHODS)}")
        if self.matcher not in ("flann", "bf"):
            raise CompanionError(f"unknown matcher {self.matcher!r}", "use 'flann' or 'bf'")
        if not 0.0 < self.ratio_test < 1.0:
            raise CompanionError(f"ratio_test={self.ratio_test} is outside (0, 1)", "use about 0.7-0.8")
        if self.min_inliers < 4:
            raise CompanionError("min_inliers must be at least 4 (a homography needs 4 points)", "use 12 or more")


@dataclass(frozen=True)
class OverlapEstimate:
    """R(Ip, Iq). ``R`` is percent (0..100) or None when unknown; dx, dy are Iq minus Ip, full-resolution px."""

    status: OverlapStatus
    R: float | None
    method: str
    matches: int = 0
    inliers: int = 0
    dx: float | None = None
    dy: float | None = None
    H: np.ndarray | None = None  # full-resolution homography mapping Ip pixels to Iq pixels
    R_displacement: float | None = None
    R_polygon: float | None = None
    model: str = ""  # "homography", or "similarity" when the homography was ill-posed

    @property
    def known(self) -> bool:
        return self.R is not None

    @property
    def percent(self) -> float | None:
        """Same as ``R`` (lower-case name for comparisons; linters read ``R`` as a constant)."""
        return self.R

    @property
    def ratio(self) -> float | None:
        """R as a fraction 0..1 (the unit of the mission's ``overlap`` and of simulator truth)."""
        return None if self.R is None else self.R / 100.0


def eq2_overlap(dx: float, dy: float, width: int, height: int) -> float:
    """Paper Eq. 2 in percent; displacements beyond the frame give 0."""
    return 100.0 * max(0.0, height - abs(dy)) * max(0.0, width - abs(dx)) / (height * width)


def _area(poly: np.ndarray) -> float:
    x, y = poly[:, 0], poly[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))


def convex_intersection_area(subject: np.ndarray, clip: np.ndarray) -> float:
    """Area of subject polygon clipped by a convex polygon (Sutherland-Hodgman, float64).

    Written out because cv2.intersectConvexConvex misreports coincident edges (identical frames gave 53 %).
    """
    clip = np.asarray(clip, dtype=np.float64)
    if _area(clip) < 0:
        clip = clip[::-1]
    out = [tuple(p) for p in np.asarray(subject, dtype=np.float64)]
    for k in range(len(clip)):
        a, b = clip[k], clip[(k + 1) % len(clip)]
        ex, ey = b - a

        def inside(p, a=a, ex=ex, ey=ey):
            return ex * (p[1] - a[1]) - ey * (p[0] - a[0]) >= -1e-9

        src, out = out, []
        for i, cur in enumerate(src):
            prev = src[i - 1]
            cin, pin = inside(cur), inside(prev)
            if cin != pin:
                dx, dy = cur[0] - prev[0], cur[1] - prev[1]
                den = ex * dy - ey * dx
                t = (ey * (prev[0] - a[0]) - ex * (prev[1] - a[1])) / den
                out.append((prev[0] + t * dx, prev[1] + t * dy))
            if cin:
                out.append(cur)
        if len(out) < 3:
            return 0.0
    return abs(_area(np.array(out)))


def polygon_overlap(H: np.ndarray, width: int, height: int) -> float | None:
    """Percent of Ip's rectangle covered by Iq's rectangle, with H mapping Ip px -> Iq px. None if degenerate."""
    try:
        Hinv = np.linalg.inv(H)
    except np.linalg.LinAlgError:
        return None
    rect = np.array([[0, 0], [width, 0], [width, height], [0, height]], dtype=np.float64)
    homog = np.hstack([rect, np.ones((4, 1))]) @ Hinv.T
    if np.any(homog[:, 2] <= 1e-9):  # Iq's corner maps behind Ip's camera: not a plane-to-plane view
        return None
    q_in_p = homog[:, :2] / homog[:, 2:3]
    if not cv2.isContourConvex(q_in_p.astype(np.float32).reshape(-1, 1, 2)):
        return None
    return 100.0 * convex_intersection_area(q_in_p, rect) / (width * height)


def _plausible(H_work: np.ndarray, max_scale_change: float, work_w: float, work_h: float) -> bool:
    a = H_work[:2, :2] / H_work[2, 2]
    det = float(np.linalg.det(a))
    if not np.isfinite(det) or det <= 0.0:  # mirrored or collapsed
        return False
    if not (1.0 / max_scale_change**2 <= det <= max_scale_change**2):
        return False
    # Strong perspective between neighbouring frames of a wall is a wrong fit to repeated texture.
    tilt = (abs(H_work[2, 0]) * work_w + abs(H_work[2, 1]) * work_h) / abs(H_work[2, 2])
    return tilt < 0.5


class OverlapEstimator:
    """Matches two FeatureSets and returns an OverlapEstimate. Holds the matcher so it is built once."""

    def __init__(self, config: OverlapConfig | None = None):
        self.config = config or OverlapConfig()
        if self.config.matcher == "flann":
            self._matcher = cv2.FlannBasedMatcher({"algorithm": 1, "trees": 4}, {"checks": 64})
        else:
            self._matcher = cv2.BFMatcher(cv2.NORM_L2)

    def estimate(self, p: FeatureSet, q: FeatureSet) -> OverlapEstimate:
        cfg = self.config
        if p.full_size != q.full_size:
            raise CompanionError(
                f"frames differ in size ({p.full_size} vs {q.full_size})",
                "feed one camera stream at one resolution through the gate",
            )
        if abs(p.scale - q.scale) > 1e-9:
            raise CompanionError("feature sets were extracted at different working scales", "use one extractor")
        unknown = dict(R=None, method=cfg.method)
        if len(p) < cfg.min_matches or len(q) < cfg.min_matches or p.descriptors is None or q.descriptors is None:
            return OverlapEstimate(OverlapStatus.TOO_FEW_FEATURES, **unknown)
        pairs = self._matcher.knnMatch(p.descriptors, q.descriptors, k=2)
        good = [m[0] for m in pairs if len(m) == 2 and m[0].distance < cfg.ratio_test * m[1].distance]
        if len(good) < cfg.min_matches:
            return OverlapEstimate(OverlapStatus.TOO_FEW_MATCHES, matches=len(good), **unknown)
        src = p.points[[m.queryIdx for m in good]]
        dst = q.points[[m.trainIdx for m in good]]
        H_work, inlier_mask = cv2.findHomography(
            src, dst, cv2.RANSAC, cfg.ransac_reproj_px, maxIters=2000, confidence=0.995
        )
        if H_work is None or inlier_mask is None:
            return OverlapEstimate(OverlapStatus.TOO_FEW_INLIERS, matches=len(good), **unknown)
        inl = inlier_mask.ravel().astype(bool)
        n_in = int(inl.sum())
        if n_in < cfg.min_inliers or n_in < cfg.min_inlier_share * len(good):
            return OverlapEstimate(OverlapStatus.TOO_FEW_INLIERS, matches=len(good), inliers=n_in, **unknown)
        s = p.scale
        w, h = p.full_size
        model = "homography"
        if not _plausible(H_work, cfg.max_scale_change, w * s, h * s):
            # Inliers bunched in a small ROI (a wall edge just entering view) leave the projective part of H
            # unconstrained; a similarity (shift, rotation, scale) is well-posed there and is what a
            # constant-standoff pass does between neighbouring frames.
            A, sim_mask = cv2.estimateAffinePartial2D(
                src, dst, method=cv2.RANSAC, ransacReprojThreshold=cfg.ransac_reproj_px, maxIters=2000
            )
            if A is None or sim_mask is None:
                return OverlapEstimate(OverlapStatus.DEGENERATE, matches=len(good), inliers=n_in, **unknown)
            H_work = np.vstack([A, [0.0, 0.0, 1.0]])
            inl = sim_mask.ravel().astype(bool)
            n_in = int(inl.sum())
            model = "similarity"
            if n_in < cfg.min_inliers or not _plausible(H_work, cfg.max_scale_change, w * s, h * s):
                return OverlapEstimate(OverlapStatus.DEGENERATE, matches=len(good), inliers=n_in, **unknown)
        scale_m = np.diag([s, s, 1.0])
        H_full = np.linalg.inv(scale_m) @ H_work @ scale_m
        vectors = (dst[inl] - src[inl]) / s
        dx, dy = (float(v) for v in vectors.mean(axis=0))
        r_disp = eq2_overlap(dx, dy, w, h)
        r_poly = polygon_overlap(H_full, w, h)
        r = r_disp if cfg.method == "displacement" else r_poly
        if r is None:
            return OverlapEstimate(OverlapStatus.DEGENERATE, matches=len(good), inliers=n_in, **unknown)
        return OverlapEstimate(
            OverlapStatus.OK,
            R=r,
            method=cfg.method,
            matches=len(good),
            inliers=n_in,
            dx=dx,
            dy=dy,
            H=H_full,
            R_displacement=r_disp,
            R_polygon=r_poly,
            model=model,
        )

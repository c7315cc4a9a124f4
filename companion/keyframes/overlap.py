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

from dataclasses import dataclass, field, replace
from enum import StrEnum
from typing import TYPE_CHECKING

import cv2
import numpy as np

from companion.errors import CompanionError
from companion.keyframes.features import FeatureSet
from companion.matching import DescriptorIndex, MatcherSettings
from companion.polygons import convex_intersection_area
from companion.ransac import ransac_affine, ransac_homography
from companion.records import OverlapSource

if TYPE_CHECKING:
    from companion.keyframes.motion import WallMotion

METHODS = ("displacement", "polygon")
# The gate's matcher: Lowe's 0.75, 4 kd-trees, 32 checks (64 found the same matches at twice the search time).
GATE_MATCHING = MatcherSettings(ratio=0.75, kind="flann", trees=4, checks=32)
# the seed of every keyframe index's randomised trees: the gate's matches depend on the frames alone
GATE_INDEX_SEED = 104729


class OverlapStatus(StrEnum):
    OK = "ok"
    TOO_FEW_FEATURES = "too_few_features"  # one of the frames has (almost) no texture inside its ROI
    TOO_FEW_MATCHES = "too_few_matches"  # descriptors do not agree: different scene, blur, or too far apart
    TOO_FEW_INLIERS = "too_few_inliers"  # matches do not agree on one geometry
    DEGENERATE = "degenerate"  # RANSAC model folds, mirrors or scales implausibly
    NO_WALL_MOTION = "no_wall_motion"  # models found, but none moves like the wall the telemetry predicts


@dataclass(frozen=True)
class OverlapConfig:
    method: str = "displacement"
    matching: MatcherSettings = GATE_MATCHING  # ratio test and FLANN search ("bf": exact brute force)
    ransac_reproj_px: float = 3.0  # in working pixels
    min_matches: int = 12
    min_inliers: int = 12
    min_inlier_share: float = 0.15  # inliers / matches; repeated texture gives many wrong matches
    max_scale_change: float = 2.0  # homography area change allowed between neighbouring frames
    # With a telemetry prior (the wall's predicted motion): how many RANSAC models to try one after the other,
    # and how far (median, full-resolution px) a model's inliers may land from where the wall should be:
    # the larger of prior_floor x frame width and prior_tolerance x the predicted shift. A static background
    # misses by about the whole predicted shift; relative pose error over a second is a few % of the frame.
    max_hypotheses: int = 4
    prior_tolerance: float = 0.35
    prior_floor: float = 0.05

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise CompanionError(f"unknown overlap method {self.method!r}", f"use one of {', '.join(METHODS)}")
        if self.min_inliers < 4:
            raise CompanionError("min_inliers must be at least 4 (a homography needs 4 points)", "use 12 or more")
        if self.max_hypotheses < 1:
            raise CompanionError(f"max_hypotheses={self.max_hypotheses} must be at least 1", "use about 4")
        if not (0.0 < self.prior_tolerance < 1.0 and 0.0 < self.prior_floor < 1.0):
            raise CompanionError(
                f"prior_tolerance={self.prior_tolerance} / prior_floor={self.prior_floor} must be fractions in (0, 1)",
                "use about 0.35 and 0.05",
            )


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
    # Set when a telemetry prior was used (see KeyframeGate): where R came from and how the image agreed.
    source: OverlapSource = OverlapSource.IMAGE
    R_image: float | None = None  # the image's own R when the telemetry replaced it
    R_telemetry: float | None = None  # overlap predicted from the two poses (percent)
    prediction_miss_px: float | None = None  # median distance of the chosen inliers from the predicted wall
    hypotheses: int = 0  # RANSAC models tried against the prediction
    rejected_matches: int = 0  # inliers of models that did not move like the wall (background)
    # Every distinctive match, N x 4 (x, y in Ip, x, y in Iq; full-resolution px), for a measurement that selects
    # its own inliers (the standoff: companion.keyframes.standoff). The gate hands it on and does not keep it.
    matched_points: np.ndarray | None = field(default=None, repr=False, compare=False)

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


@dataclass
class _Fit:
    """One RANSAC model on a set of matches (working pixels). ``inliers`` index the matches it was fitted on."""

    H_work: np.ndarray | None
    inliers: np.ndarray  # bool mask over the matches given to the fit
    model: str
    status: OverlapStatus


class OverlapEstimator:
    """Matches two FeatureSets and returns an OverlapEstimate.

    The reference frame's descriptor index (FLANN kd-trees) is built once and kept while the same reference is
    compared with new frames (the gate compares every frame with the current keyframe): each frame's descriptors
    query the keyframe's index, so a comparison costs the search, not the build.
    Its randomised trees are seeded (``GATE_INDEX_SEED``), so the matches depend on the two frames only, not on
    what drew from OpenCV's RNG earlier in the process (a resumed cull keeps the keyframes an uninterrupted one
    keeps).
    """

    def __init__(self, config: OverlapConfig | None = None):
        self.config = config or OverlapConfig()
        self._ref: FeatureSet | None = None  # the FeatureSet whose index is cached (held: identity is the key)
        self._ref_index: DescriptorIndex | None = None

    def _index_of(self, p: FeatureSet) -> DescriptorIndex:
        if self._ref is not p or self._ref_index is None:
            self._ref_index = DescriptorIndex(p.descriptors, self.config.matching, seed=GATE_INDEX_SEED)
            self._ref = p
        return self._ref_index

    def estimate(self, p: FeatureSet, q: FeatureSet, prior: WallMotion | None = None) -> OverlapEstimate:
        """R(Ip, Iq). With ``prior`` (the wall's motion predicted from telemetry) R is measured on the RANSAC
        hypothesis that moves like the wall; a cluster that does not (a static far background) cannot decide R,
        and when no hypothesis does the status is NO_WALL_MOTION (R unknown). Without it: one RANSAC model on all
        matches, the paper's method."""
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
        # Iq's descriptors query Ip's index (built once per reference): one entry per distinctive match.
        found = self._index_of(p).match(q.descriptors)
        in_q, in_p = found.query, found.indexed
        good = in_q
        if len(good) < cfg.min_matches:
            return OverlapEstimate(OverlapStatus.TOO_FEW_MATCHES, matches=len(good), **unknown)
        src = p.points[in_p]
        dst = q.points[in_q]
        matched = np.hstack([src, dst]).astype(np.float64) / p.scale
        if prior is None:
            fit = self._fit(src, dst, p)
            if fit.status != OverlapStatus.OK:
                return OverlapEstimate(fit.status, matches=len(good), inliers=int(fit.inliers.sum()),
                                       matched_points=matched, **unknown)
            return replace(self._result(fit, src, dst, p, len(good)), matched_points=matched)
        return replace(self._estimate_with_prior(src, dst, p, prior, len(good)), matched_points=matched)

    def _fit(self, src: np.ndarray, dst: np.ndarray, p: FeatureSet, min_share: float | None = None) -> _Fit:
        """RANSAC homography, or a similarity where the homography is ill-posed (the paper's model, guarded)."""
        cfg = self.config
        share = cfg.min_inlier_share if min_share is None else min_share
        none = np.zeros(len(src), dtype=bool)
        if len(src) < 4:
            return _Fit(None, none, "", OverlapStatus.TOO_FEW_INLIERS)
        H_work, inl = ransac_homography(
            src, dst, method=cv2.RANSAC, threshold_px=cfg.ransac_reproj_px, max_iters=2000, confidence=0.995
        )
        if H_work is None:
            return _Fit(None, none, "", OverlapStatus.TOO_FEW_INLIERS)
        n_in = int(inl.sum())
        if n_in < cfg.min_inliers or n_in < share * len(src):
            return _Fit(None, inl, "", OverlapStatus.TOO_FEW_INLIERS)
        s = p.scale
        w, h = p.full_size
        if _plausible(H_work, cfg.max_scale_change, w * s, h * s):
            return _Fit(H_work, inl, "homography", OverlapStatus.OK)
        # Inliers bunched in a small ROI (a wall edge just entering view) leave the projective part of H
        # unconstrained; a similarity (shift, rotation, scale) is well-posed there and is what a
        # constant-standoff pass does between neighbouring frames.
        H_sim, sim_inl = ransac_affine(src, dst, threshold_px=cfg.ransac_reproj_px, partial=True, max_iters=2000)
        if H_sim is None:
            return _Fit(None, inl, "", OverlapStatus.DEGENERATE)
        if int(sim_inl.sum()) < cfg.min_inliers or not _plausible(H_sim, cfg.max_scale_change, w * s, h * s):
            return _Fit(None, inl, "", OverlapStatus.DEGENERATE)
        return _Fit(H_sim, sim_inl, "similarity", OverlapStatus.OK)

    def _estimate_with_prior(
        self, src: np.ndarray, dst: np.ndarray, p: FeatureSet, prior: WallMotion, n_matches: int
    ) -> OverlapEstimate:
        """Sequential RANSAC: fit, set the inliers aside, fit again on the rest (up to ``max_hypotheses``); keep
        the hypothesis whose inliers land where the telemetry puts the wall (median distance within tolerance)."""
        cfg = self.config
        s = p.scale
        w, _ = p.full_size
        predicted = prior.map_points(src / s)  # full-resolution px in Iq where the wall points should land
        src_full = src.astype(np.float64) / s
        expected_shift = float(np.median(np.linalg.norm(predicted - src_full, axis=1)))
        tolerance = max(cfg.prior_floor * w, cfg.prior_tolerance * expected_shift)
        remaining = np.arange(len(src))
        best: tuple[float, _Fit, np.ndarray] | None = None
        hypotheses = 0
        explained = 0
        for _ in range(cfg.max_hypotheses):
            if len(remaining) < cfg.min_inliers:
                break
            # No inlier-share rule here: agreement with the predicted wall motion is the stronger guard.
            fit = self._fit(src[remaining], dst[remaining], p, min_share=0.0)
            idx = remaining[fit.inliers]
            if len(idx) == 0:
                break
            remaining = remaining[~fit.inliers]
            if fit.status != OverlapStatus.OK:
                if len(idx) < cfg.min_inliers:
                    break
                continue  # an implausible model's matches are set aside; the rest may still hold the wall
            hypotheses += 1
            explained += len(idx)
            miss = float(np.median(np.linalg.norm(dst[idx].astype(np.float64) / s - predicted[idx], axis=1)))
            if best is None or miss < best[0]:
                best = (miss, fit, idx)
        common = dict(matches=n_matches, hypotheses=hypotheses, R_telemetry=prior.overlap_percent)
        if best is None:
            return OverlapEstimate(OverlapStatus.TOO_FEW_INLIERS, R=None, method=cfg.method, **common)
        miss, fit, idx = best
        if miss > tolerance:
            return OverlapEstimate(
                OverlapStatus.NO_WALL_MOTION, R=None, method=cfg.method, inliers=len(idx), prediction_miss_px=miss,
                rejected_matches=explained, **common,
            )
        chosen = np.zeros(len(src), dtype=bool)
        chosen[idx] = True
        chosen_fit = _Fit(fit.H_work, chosen, fit.model, fit.status)
        est = self._result(chosen_fit, src, dst, p, n_matches)
        return replace(est, prediction_miss_px=miss, rejected_matches=explained - len(idx), **common)

    def _result(self, fit: _Fit, src: np.ndarray, dst: np.ndarray, p: FeatureSet, n_matches: int) -> OverlapEstimate:
        cfg = self.config
        s = p.scale
        w, h = p.full_size
        inl = fit.inliers
        n_in = int(inl.sum())
        scale_m = np.diag([s, s, 1.0])
        H_full = np.linalg.inv(scale_m) @ fit.H_work @ scale_m
        vectors = (dst[inl] - src[inl]) / s
        dx, dy = (float(v) for v in vectors.mean(axis=0))
        r_disp = eq2_overlap(dx, dy, w, h)
        r_poly = polygon_overlap(H_full, w, h)
        r = r_disp if cfg.method == "displacement" else r_poly
        if r is None:
            return OverlapEstimate(OverlapStatus.DEGENERATE, R=None, method=cfg.method, matches=n_matches,
                                   inliers=n_in)
        return OverlapEstimate(
            OverlapStatus.OK,
            R=r,
            method=cfg.method,
            matches=n_matches,
            inliers=n_in,
            dx=dx,
            dy=dy,
            H=H_full,
            R_displacement=r_disp,
            R_polygon=r_poly,
            model=fit.model,
        )

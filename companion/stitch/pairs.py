"""Pairwise registration: SIFT matches -> DLT/RANSAC homography (paper Eq. 3), telemetry gate, affine fallback.

Repetitive facades (rows of identical windows) make wrong-but-consistent matches one window apart. Where both
keyframes have a telemetry prior, a match whose two ends land more than ``pose_gate_m`` apart on the wall is
dropped before RANSAC, and a model that moves the image more than that from where telemetry puts it is rejected.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path

import cv2
import numpy as np

from companion.files import atomic_path
from companion.stitch.features import Features
from companion.stitch.geometry import apply_h, is_sane_homography


@dataclass
class PairResult:
    i: int  # position in the keyframe list (not the spool index)
    j: int
    accepted: bool
    model: str  # "homography", "affine" or "none"
    reason: str  # why rejected, or "" when accepted
    matches: int = 0
    inliers: int = 0
    rms_px: float | None = None
    H: np.ndarray | None = None  # full-resolution pixels of i -> pixels of j
    pts_i: np.ndarray | None = None  # (N, 2) inlier points
    pts_j: np.ndarray | None = None
    lum_ratio: float | None = None  # median log(grey_i / grey_j) at the inliers: relative exposure

    def summary(self) -> dict:
        d = asdict(self)
        for k in ("H", "pts_i", "pts_j"):
            d.pop(k)
        return d


@dataclass(frozen=True)
class PairSettings:
    ratio: float = 0.75
    ransac_px: float = 3.0
    min_inliers: int = 15
    min_inliers_affine: int = 8
    pose_gate_m: float = 1.0
    max_points: int = 400  # inliers kept per pair for the global adjustment and the mesh
    min_inlier_area: float = 0.01  # inliers' convex hull / image area: below this the model is extrapolation


def candidate_pairs(
    n: int,
    priors: list[np.ndarray | None],
    corners: np.ndarray,
    *,
    neighbours: int = 2,
    min_prior_overlap: float = 0.15,
    max_per_frame: int = 6,
) -> list[tuple[int, int]]:
    """Sequence neighbours plus keyframes whose telemetry footprints overlap (adjacent scan legs)."""
    pairs = {(i, j) for i in range(n) for j in range(i + 1, min(n, i + neighbours + 1))}
    boxes = []
    for P in priors:
        if P is None:
            boxes.append(None)
            continue
        q = apply_h(P, corners)
        boxes.append((q[:, 0].min(), q[:, 0].max(), q[:, 1].min(), q[:, 1].max()) if np.all(np.isfinite(q)) else None)
    extra: dict[int, list[tuple[float, int]]] = {}
    for i in range(n):
        if boxes[i] is None:
            continue
        ax0, ax1, ay0, ay1 = boxes[i]
        area_i = (ax1 - ax0) * (ay1 - ay0)
        for j in range(i + 1, n):
            if boxes[j] is None or (i, j) in pairs:
                continue
            bx0, bx1, by0, by1 = boxes[j]
            inter = max(0.0, min(ax1, bx1) - max(ax0, bx0)) * max(0.0, min(ay1, by1) - max(ay0, by0))
            frac = inter / max(1e-9, min(area_i, (bx1 - bx0) * (by1 - by0)))
            if frac >= min_prior_overlap:
                extra.setdefault(i, []).append((frac, j))
    for i, lst in extra.items():
        for _, j in sorted(lst, reverse=True)[:max_per_frame]:
            pairs.add((i, j))
    return sorted(pairs)


def match_pair(
    i: int,
    j: int,
    fi: Features,
    fj: Features,
    *,
    settings: PairSettings,
    prior_i: np.ndarray | None = None,
    prior_j: np.ndarray | None = None,
    pixel_to_norm: np.ndarray | None = None,
) -> PairResult:
    """Registers keyframe i onto keyframe j. Priors are image-normalised -> plane homographies."""
    if len(fi.keypoints) < settings.min_inliers_affine or len(fj.keypoints) < settings.min_inliers_affine:
        return PairResult(i, j, False, "none", "too few features inside the ROI masks")
    matcher = cv2.FlannBasedMatcher({"algorithm": 1, "trees": 4}, {"checks": 64})
    knn = matcher.knnMatch(fi.descriptors, fj.descriptors, k=2)
    good = [m[0] for m in knn if len(m) == 2 and m[0].distance < settings.ratio * m[1].distance]
    if len(good) < settings.min_inliers_affine:
        return PairResult(i, j, False, "none", f"only {len(good)} distinctive matches", matches=len(good))
    qi, tj = np.array([m.queryIdx for m in good]), np.array([m.trainIdx for m in good])
    pi = fi.keypoints[qi].astype(np.float64)
    pj = fj.keypoints[tj].astype(np.float64)
    li = fi.luminance[qi].astype(np.float64)
    lj = fj.luminance[tj].astype(np.float64)
    gated = prior_i is not None and prior_j is not None and pixel_to_norm is not None
    if gated:
        wi = apply_h(prior_i @ pixel_to_norm, pi)
        wj = apply_h(prior_j @ pixel_to_norm, pj)
        keep = np.linalg.norm(wi - wj, axis=1) < settings.pose_gate_m
        pi, pj, li, lj = pi[keep], pj[keep], li[keep], lj[keep]
        if len(pi) < settings.min_inliers_affine:
            return PairResult(
                i,
                j,
                False,
                "none",
                "matches contradict telemetry (repetitive pattern or no overlap)",
                matches=len(good),
            )
    w, h = fi.image_size
    corners = np.array([[0, 0], [w, 0], [w, h], [0, h]], dtype=float)
    model, H, inl = "none", None, None
    cv2.setRNGSeed(1000003 * i + j)  # RANSAC draws: the same keyframes always give the same map
    if len(pi) >= settings.min_inliers:
        Hh, m = cv2.findHomography(pi, pj, cv2.USAC_MAGSAC, settings.ransac_px, maxIters=5000, confidence=0.999)
        if (
            Hh is not None
            and m is not None
            and int(m.sum()) >= settings.min_inliers
            and is_sane_homography(Hh, corners)
            and _spread(pi[m.ravel().astype(bool)], w, h) >= settings.min_inlier_area
        ):
            model, H, inl = "homography", Hh, m.ravel().astype(bool)
    if H is None:
        # degenerate for a homography (few/collinear inliers, implausible warp): a 6-dof affine is still safe
        A, m = cv2.estimateAffine2D(pi, pj, method=cv2.RANSAC, ransacReprojThreshold=settings.ransac_px)
        if A is not None and m is not None and int(m.sum()) >= settings.min_inliers_affine:
            Ha = np.vstack((A, [0.0, 0.0, 1.0]))
            if (
                is_sane_homography(Ha, corners)
                and _spread(pi[m.ravel().astype(bool)], w, h) >= settings.min_inlier_area
            ):
                model, H, inl = "affine", Ha, m.ravel().astype(bool)
    if H is None:
        return PairResult(i, j, False, "none", "no consistent homography or affine model", matches=len(good))
    pi, pj = pi[inl], pj[inl]
    ok = (li[inl] > 5) & (lj[inl] > 5)  # log of near-black is noise
    lum_ratio = float(np.median(np.log(li[inl][ok] / lj[inl][ok]))) if ok.sum() >= 5 else None
    err = np.linalg.norm(apply_h(H, pi) - pj, axis=1)
    rms = float(np.sqrt(np.mean(err**2)))
    if gated:
        moved = np.linalg.norm(
            apply_h(prior_j @ pixel_to_norm, apply_h(H, pi)) - apply_h(prior_i @ pixel_to_norm, pi), axis=1
        )
        # and where it puts the image corners (an extrapolating model, e.g. from a repeated ledge, fails here)
        moved_c = np.linalg.norm(
            apply_h(prior_j @ pixel_to_norm, apply_h(H, corners)) - apply_h(prior_i @ pixel_to_norm, corners), axis=1
        )
        if float(np.median(moved)) > settings.pose_gate_m or float(moved_c.max()) > 2 * settings.pose_gate_m:
            return PairResult(i, j, False, model, "model contradicts telemetry", len(good), len(pi), rms)
    if len(pi) > settings.max_points:
        sel = np.random.default_rng(i * 100003 + j).choice(len(pi), settings.max_points, replace=False)
        pi, pj = pi[sel], pj[sel]
    return PairResult(i, j, True, model, "", len(good), int(inl.sum()), rms, H, pi, pj, lum_ratio)


def _spread(pts: np.ndarray, w: int, h: int) -> float:
    """Area of the inliers' convex hull as a fraction of the image (collinear or clustered inliers ~ 0)."""
    if len(pts) < 3:
        return 0.0
    return float(cv2.contourArea(cv2.convexHull(pts.astype(np.float32)))) / float(w * h)


def save_pair(path: Path, r: PairResult) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    arrays = {"summary": np.array(json.dumps(r.summary()))}
    if r.accepted:
        arrays.update(H=r.H, pts_i=r.pts_i, pts_j=r.pts_j)
    with atomic_path(path) as tmp:
        np.savez(tmp, **arrays)


def load_pair(path: Path) -> PairResult | None:
    if not path.exists():
        return None
    try:
        z = np.load(path)
        d = json.loads(str(z["summary"]))
        r = PairResult(**d)
        if r.accepted:
            r.H, r.pts_i, r.pts_j = z["H"], z["pts_i"], z["pts_j"]
        return r
    except (OSError, ValueError, KeyError, TypeError):
        path.unlink(missing_ok=True)
        return None

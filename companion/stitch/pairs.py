"""Pairwise registration: SIFT matches -> DLT/RANSAC homography (paper Eq. 3), affine fallback, far-plane check.

Images first, telemetry as a loose prior: real GNSS next to a building is off by metres and jumps, so a pair is
accepted by geometric verification (a sane homography well supported by matches spread over the image), not
by how close the poses put the two images. Telemetry only removes the absurd: a match whose two ends land more
than ``pose_gate_m`` (a few metres) apart on the wall, or a model that moves the image that far from where the
poses put it.

Far, static scenery (a background the mask kept, or raw frames with no mask) is rejected by what it is, not by
pose distance: between two frames a baseline apart, a point 120 m behind a wall at 4 m moves ~30x less than the
wall. After the first model, a second is fitted to the remaining matches; where one of the two moves far less
than the other (``far_motion_ratio``), it is the background and the nearer plane (the wall) is the pair's model.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Protocol

import cv2
import numpy as np

from companion.errors import CompanionError
from companion.keyframes.features import FeatureConfig
from companion.matching import DescriptorIndex, MatcherSettings
from companion.progress import progress_bar
from companion.ransac import ransac_affine, ransac_homography
from companion.stitch.config import STITCH_MATCHING, StitchConfig, worker_count
from companion.stitch.features import Features, KeyframeFeatures, cached_features
from companion.stitch.geometry import apply_h, is_sane_homography
from companion.stitch.inputs import KeyframeInput
from companion.stitch.priors import PlanePriors


@dataclass(frozen=True)
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
    background_matches: int = 0  # matches of a far plane (background) found beside the wall's model and dropped

    def summary(self) -> dict:
        d = asdict(self)
        for k in ("H", "pts_i", "pts_j"):
            d.pop(k)
        return d


@dataclass(frozen=True)
class PairSettings:
    matching: MatcherSettings = STITCH_MATCHING
    ransac_px: float = 3.0
    min_inliers: int = 15
    min_inliers_affine: int = 8
    pose_gate_m: float = 4.0
    far_motion_ratio: float = 0.25  # a plane moving less than this fraction of another is far (background)
    max_points: int = 400  # inliers kept per pair for the global adjustment and the mesh
    min_inlier_area: float = 0.01  # inliers' convex hull / image area: below this the model is extrapolation


def candidate_pairs(
    n: int,
    priors: list[np.ndarray | None],
    corners: np.ndarray,
    *,
    neighbours: int = 2,
    min_prior_overlap: float = 0.15,
    max_per_frame: int = 2,
    return_margin: float = 0.1,
) -> list[tuple[int, int]]:
    """Sequence neighbours along the path, plus the keyframes the path comes back to (an adjacent scan leg).

    Along the path, the ``neighbours`` next keyframes tie each keyframe to the ones after it; matching it also to
    every later keyframe still inside its footprint (5-6 more at 85 % overlap) costs most of the matching and
    adds no new link. A later keyframe j is a revisit when the telemetry footprints say the path left keyframe
    i's view and came back: its overlap with i is at least ``min_prior_overlap`` and above the lowest overlap
    of a keyframe between them by ``return_margin`` (so telemetry noise on a straight leg rarely makes one).
    Each keyframe keeps its ``max_per_frame`` revisits of largest overlap: the two nearest keyframes of the
    adjacent leg tie the legs together (each keyframe is also tied by the previous leg's); the next four were
    half of the demo's 2160 pairs (1017), matched, aligned and wall-checked, for links the map did not need."""
    pairs = {(i, j) for i in range(n) for j in range(i + 1, min(n, i + neighbours + 1))}
    boxes = []
    for P in priors:
        if P is None:
            boxes.append(None)
            continue
        q = apply_h(P, corners)
        boxes.append((q[:, 0].min(), q[:, 0].max(), q[:, 1].min(), q[:, 1].max()) if np.all(np.isfinite(q)) else None)

    def overlap(a, b) -> float:
        ax0, ax1, ay0, ay1 = a
        bx0, bx1, by0, by1 = b
        inter = max(0.0, min(ax1, bx1) - max(ax0, bx0)) * max(0.0, min(ay1, by1) - max(ay0, by0))
        return inter / max(1e-9, min((ax1 - ax0) * (ay1 - ay0), (bx1 - bx0) * (by1 - by0)))

    for i in range(n):
        if boxes[i] is None:
            continue
        revisits, lowest = [], math.inf
        for j in range(i + 1, n):
            if boxes[j] is None:
                continue
            frac = overlap(boxes[i], boxes[j])
            if j > i + neighbours and frac >= min_prior_overlap and frac >= lowest + return_margin:
                revisits.append((frac, j))
            lowest = min(lowest, frac)
        for _, j in sorted(revisits, reverse=True)[:max_per_frame]:
            pairs.add((i, j))
    return sorted(pairs)


@dataclass(frozen=True)
class _Matches:
    """Ratio-test matches of a pair: full-resolution points in both keyframes and the grey level at each."""

    pts_i: np.ndarray
    pts_j: np.ndarray
    lum_i: np.ndarray
    lum_j: np.ndarray
    distinctive: int  # matches that passed the ratio test (before the telemetry gate)

    def subset(self, keep: np.ndarray) -> _Matches:
        return _Matches(self.pts_i[keep], self.pts_j[keep], self.lum_i[keep], self.lum_j[keep], self.distinctive)


@dataclass(frozen=True)
class _PairPrior:
    """The telemetry of both keyframes: keyframe pixels -> plane metres for each."""

    plane_from_px_i: np.ndarray
    plane_from_px_j: np.ndarray

    def gap_m(self, pts_i: np.ndarray, pts_j: np.ndarray) -> np.ndarray:
        """How far apart on the wall telemetry puts each pair of points."""
        return np.linalg.norm(apply_h(self.plane_from_px_i, pts_i) - apply_h(self.plane_from_px_j, pts_j), axis=1)


def keyframe_index(j: int, fj: Features, settings: PairSettings) -> DescriptorIndex:
    """The search structure over keyframe j's descriptors that every pair (i, j) queries: built once per keyframe,
    not once per pair (a sixth of a pair's matching at 4K). FLANN's randomised kd-trees draw from OpenCV's RNG,
    seeded by the keyframe, so the trees (and the matches) are the same whichever thread builds them, and the
    same as ``match_pair`` builds when given none."""
    return DescriptorIndex(fj.descriptors, settings.matching, seed=7919 * j + 17)


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
    index_j: DescriptorIndex | None = None,
) -> PairResult:
    """Registers keyframe i onto keyframe j. Priors are image-normalised -> plane homographies. ``index_j``:
    keyframe j's :func:`keyframe_index`, when the caller matches several keyframes against j."""
    if len(fi.keypoints) < settings.min_inliers_affine or len(fj.keypoints) < settings.min_inliers_affine:
        return PairResult(i, j, False, "none", "too few features inside the ROI masks")
    if index_j is None:
        index_j = keyframe_index(j, fj, settings)
    found = _distinctive_matches(fi, fj, index_j)
    n_good = found.distinctive
    if n_good < settings.min_inliers_affine:
        return PairResult(i, j, False, "none", f"only {n_good} distinctive matches", matches=n_good)
    prior = None
    if prior_i is not None and prior_j is not None and pixel_to_norm is not None:
        prior = _PairPrior(prior_i @ pixel_to_norm, prior_j @ pixel_to_norm)
        found = found.subset(prior.gap_m(found.pts_i, found.pts_j) < settings.pose_gate_m)
        if len(found.pts_i) < settings.min_inliers_affine:
            why = "matches contradict telemetry (repetitive pattern or no overlap)"
            return PairResult(i, j, False, "none", why, matches=n_good)
    w, h = fi.image_size
    corners = np.array([[0, 0], [w, 0], [w, h], [0, h]], dtype=float)
    # RANSAC draws from OpenCV's RNG: seeded per pair, so the same keyframes always give the same map, whatever
    # ran before on this thread (earlier pairs, pairs taken from the cache in follow mode)
    cv2.setRNGSeed(1000003 * i + j)
    model, H, inl = _fit_model(found.pts_i, found.pts_j, corners, settings, (w, h))
    if H is None:
        return PairResult(i, j, False, "none", "no consistent homography or affine model", matches=n_good)
    model, H, inl, n_far = _nearer_plane(found, (model, H, inl), corners, settings, (w, h))
    inliers = found.subset(inl)
    pi, pj = inliers.pts_i, inliers.pts_j
    rms = float(np.sqrt(np.mean(np.linalg.norm(apply_h(H, pi) - pj, axis=1) ** 2)))
    if prior is not None and _model_contradicts(prior, H, pi, corners, settings.pose_gate_m):
        return PairResult(i, j, False, model, "model contradicts telemetry", n_good, len(pi), rms)
    if len(pi) > settings.max_points:
        sel = np.random.default_rng(i * 100003 + j).choice(len(pi), settings.max_points, replace=False)
        pi, pj = pi[sel], pj[sel]
    return PairResult(
        i, j, True, model, "", n_good, int(inl.sum()), rms, H, pi, pj, _exposure_ratio(inliers), n_far
    )


def _nearer_plane(
    found: _Matches, first: tuple, corners: np.ndarray, settings: PairSettings, size: tuple[int, int]
) -> tuple[str, np.ndarray, np.ndarray, int]:
    """The model of the nearer of two planes seen in the pair, and how many matches the far one had.

    A second model is fitted to the matches the first left out. Where one of the two moves the image far less
    than the other (a far point moves ``baseline / distance``: 30x less at 120 m than at 4 m), it is the
    background and the other is the wall; otherwise (one plane, a repeated pattern, two walls at similar
    distances) the first model stands. Motion is the median displacement of a model's own inliers."""
    model, H, inl = first
    rest = ~inl
    if int(rest.sum()) < settings.min_inliers:
        return model, H, inl, 0
    model2, H2, inl2_rest = _fit_model(found.pts_i[rest], found.pts_j[rest], corners, settings, size)
    if H2 is None:
        return model, H, inl, 0
    inl2 = np.zeros_like(inl)
    inl2[np.flatnonzero(rest)[inl2_rest]] = True
    m1 = _motion_px(H, found.pts_i[inl])
    m2 = _motion_px(H2, found.pts_i[inl2])
    wall_motion_floor = 3.0 * settings.ransac_px  # below this neither plane shows measurable parallax
    if m1 < settings.far_motion_ratio * m2 and m2 > wall_motion_floor:
        return model2, H2, inl2, int(inl.sum())  # the first (largest) set was the background
    if m2 < settings.far_motion_ratio * m1 and m1 > wall_motion_floor:
        return model, H, inl, int(inl2.sum())
    return model, H, inl, 0


def _motion_px(H: np.ndarray, pts: np.ndarray) -> float:
    """Median displacement of ``pts`` under ``H`` (px)."""
    return float(np.median(np.linalg.norm(apply_h(H, pts) - pts, axis=1)))


def _distinctive_matches(fi: Features, fj: Features, index_j: DescriptorIndex) -> _Matches:
    found = index_j.match(fi.descriptors)
    qi, tj = found.query, found.indexed
    return _Matches(
        fi.keypoints[qi].astype(np.float64),
        fj.keypoints[tj].astype(np.float64),
        fi.luminance[qi].astype(np.float64),
        fj.luminance[tj].astype(np.float64),
        len(qi),
    )


def _fit_model(
    pi: np.ndarray, pj: np.ndarray, corners: np.ndarray, settings: PairSettings, size: tuple[int, int]
) -> tuple[str, np.ndarray | None, np.ndarray | None]:
    """A homography (MAGSAC) where it is well supported; else a 6-dof affine, still safe where the inliers are
    few or collinear or the homography's warp is implausible. Each must keep the image sane and its inliers
    spread over it (clustered inliers make the model an extrapolation)."""
    w, h = size

    def plausible(H: np.ndarray | None, inl: np.ndarray, min_count: int) -> bool:
        return (
            H is not None
            and int(inl.sum()) >= min_count
            and is_sane_homography(H, corners)
            and _spread(pi[inl], w, h) >= settings.min_inlier_area
        )

    if len(pi) >= settings.min_inliers:
        H, inl = ransac_homography(
            pi, pj, method=cv2.USAC_MAGSAC, threshold_px=settings.ransac_px, max_iters=5000, confidence=0.999
        )
        if plausible(H, inl, settings.min_inliers):
            return "homography", H, inl
    A, inl = ransac_affine(pi, pj, threshold_px=settings.ransac_px, partial=False)
    if plausible(A, inl, settings.min_inliers_affine):
        return "affine", A, inl
    return "none", None, None


def _model_contradicts(prior: _PairPrior, H: np.ndarray, pts_i: np.ndarray, corners: np.ndarray, gate_m: float) -> bool:
    """The model moves the inliers (median), or the image corners (an extrapolating model, e.g. from a repeated
    ledge, fails here), further on the wall than telemetry allows."""
    moved = prior.gap_m(pts_i, apply_h(H, pts_i))
    moved_corners = prior.gap_m(corners, apply_h(H, corners))
    return float(np.median(moved)) > gate_m or float(moved_corners.max()) > 2 * gate_m


def _exposure_ratio(inliers: _Matches) -> float | None:
    """Median log grey-level ratio at the inliers (relative exposure); near-black levels are noise."""
    ok = (inliers.lum_i > 5) & (inliers.lum_j > 5)
    if ok.sum() < 5:
        return None
    return float(np.median(np.log(inliers.lum_i[ok] / inliers.lum_j[ok])))


def _spread(pts: np.ndarray, w: int, h: int) -> float:
    """Area of the inliers' convex hull as a fraction of the image (collinear or clustered inliers ~ 0)."""
    if len(pts) < 3:
        return 0.0
    return float(cv2.contourArea(cv2.convexHull(pts.astype(np.float32)))) / float(w * h)


def save_pair(path: Path, r: PairResult) -> None:
    """Written atomically under a temporary name of this process and thread: a pair task and the face's own thread
    may write the same pair at once (the same content; the last rename wins)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    arrays = {"summary": np.array(json.dumps(r.summary()))}
    if r.accepted:
        arrays.update(H=r.H, pts_i=r.pts_i, pts_j=r.pts_j)
    tmp = path.with_name(f".{path.stem}.{os.getpid()}-{threading.get_ident()}.tmp{path.suffix}")
    try:
        np.savez(tmp, **arrays)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def load_pair(path: Path) -> PairResult | None:
    if not path.exists():
        return None
    try:
        z = np.load(path)
        d = json.loads(str(z["summary"]))
        r = PairResult(**d)
        return replace(r, H=z["H"], pts_i=z["pts_i"], pts_j=z["pts_j"]) if r.accepted else r
    except (OSError, ValueError, KeyError, TypeError):
        path.unlink(missing_ok=True)
        return None


@dataclass(frozen=True)
class RegisteredPairs:
    """The pairs stage's output: every candidate pair tried, accepted or with the reason it was not."""

    results: tuple[PairResult, ...]
    settings: PairSettings

    @property
    def accepted(self) -> list[PairResult]:
        return [r for r in self.results if r.accepted]


class PairRunner(Protocol):
    """Runs pair tasks elsewhere (the site's cluster): ``slots`` of them at a time. ``start`` submits ``fn`` of each
    item, in their order, and returns at once a function that cancels those not started."""

    slots: int

    def start(self, fn: Callable, items: list) -> Callable[[], None]: ...


BATCHES_PER_SLOT = 4  # the pairs still to match are cut into this many tasks per slot: balance, against re-reads


@dataclass(frozen=True)
class PairBatch:
    """A pair task: the pairs (i, j) of a run of keyframes j, matched as ``register_pairs`` matches them on its
    threads, each written to its cache file. It carries the keyframes' inputs (paths), the feature cache they are
    read from (the face's, filled before), the priors (3x3 each) and the settings: never features or pixels."""

    groups: tuple[tuple[int, tuple[int, ...]], ...]  # (j, the i's of the pairs (i, j)), keyframe positions
    keyframes: dict[int, KeyframeInput]  # by position: those the groups name
    priors: dict[int, np.ndarray | None]
    paths: dict[tuple[int, int], Path]  # where each pair's result goes (the content-keyed pair cache)
    feature_dir: Path
    features: FeatureConfig
    settings: PairSettings
    pixel_to_norm: np.ndarray
    threads: int = 0  # OpenCV's threads in the task (0: its default)


def match_batch(batch: PairBatch) -> int:
    """Matches the batch's pairs not in the cache yet and writes each result there (atomically, so a task rerun
    after its worker died redoes only the pairs it had not written). Returns how many pairs it matched; the results
    go through the cache, not the scheduler."""
    if batch.threads > 0:
        cv2.setNumThreads(batch.threads)
    feats: dict[int, Features] = {}

    def features(k: int) -> Features:
        if k not in feats:
            feats[k] = cached_features(batch.keyframes[k], batch.feature_dir, batch.features)
        return feats[k]

    matched = 0
    for j, group in batch.groups:
        index_j = None
        for i in group:
            path = batch.paths[(i, j)]
            if path.exists():
                continue
            if index_j is None:
                index_j = keyframe_index(j, features(j), batch.settings)
            r = match_pair(i, j, features(i), features(j), settings=batch.settings, prior_i=batch.priors[i],
                           prior_j=batch.priors[j], pixel_to_norm=batch.pixel_to_norm, index_j=index_j)
            save_pair(path, r)
            matched += 1
    return matched


def _batches(groups: dict[int, list[int]], paths: dict[tuple[int, int], Path], count: int) -> list[list[int]]:
    """The keyframes j whose pairs are not all cached, cut into at most ``count`` runs of consecutive j with about
    as many pairs each (a keyframe's neighbours are near it in the list: a run reads few feature files)."""
    todo = [j for j, group in groups.items() if any(not paths[(i, j)].exists() for i in group)]
    if not todo:
        return []
    total = sum(len(groups[j]) for j in todo)
    per = max(1, math.ceil(total / max(1, count)))
    runs, run, size = [], [], 0
    for j in todo:
        run.append(j)
        size += len(groups[j])
        if size >= per:
            runs.append(run)
            run, size = [], 0
    return runs + ([run] if run else [])


def register_pairs(
    found: KeyframeFeatures, priors: PlanePriors, cfg: StitchConfig, cache_dir: Path, *, progress: bool,
    runner: PairRunner | None = None, feature_dir: Path | None = None,
) -> RegisteredPairs:
    """Registers the candidate pairs (sequence neighbours and telemetry-overlapping keyframes), each cached on
    disk under a key of both keyframes' features and the settings, so a resumed or follow-mode run re-matches
    only new pairs. Without telemetry, no registered pair at all is an error (nothing could place the images).

    ``runner`` (the site's cluster), with ``feature_dir`` (the feature cache the features stage filled): the pairs
    not cached yet are also submitted as pair tasks (:func:`match_batch`, runs of keyframes from the first) that
    write the same cache files, while this process's threads go through the pairs from the last keyframe: a pair
    a task has written is read from the cache (as a rerun reads it), one it has not is matched here, and the tasks
    not started when this is done are cancelled. So the face's task never waits on its pair tasks, never hands its
    thread to another face, and a worker with a free thread takes part of its matching; every pair is the same
    whoever matched it (each seeds its own RNG), so the map is the one this process's threads make."""
    cam = found.input.camera
    W, H = cam.width, cam.height
    to_norm = np.linalg.inv(cam.K)
    settings = PairSettings(
        matching=cfg.matching,
        ransac_px=cfg.ransac_threshold_px(W),
        min_inliers=cfg.min_inliers,
        pose_gate_m=cfg.pose_gate(priors.plane_unit_m * found.input.camera.focal_px),
        far_motion_ratio=cfg.far_motion_ratio,
    )
    corners = np.array([[-W / 2, -H / 2], [W / 2, -H / 2], [W / 2, H / 2], [-W / 2, H / 2]]) / cam.focal_px
    n = len(found.features)
    candidates = candidate_pairs(n, list(priors.priors), corners, neighbours=cfg.neighbours)
    gate_tag = f"{priors.use_poses}-{settings}"
    kfs, feats, keys, P = found.input.keyframes, found.features, found.keys, priors.priors

    def pair_path(i: int, j: int) -> Path:
        tag = hashlib.sha1(f"{keys[i]}|{keys[j]}|{gate_tag}".encode()).hexdigest()[:16]
        return cache_dir / f"{kfs[i].index:06d}-{kfs[j].index:06d}-{tag}.npz"

    def register(j: int, group: list[int]) -> list[PairResult]:
        """The pairs (i, j) of one keyframe j, each from the cache or matched against j's index (built once)."""
        index_j, out = None, []
        for i in group:
            path = pair_path(i, j)
            r = load_pair(path)
            if r is None:
                if index_j is None:
                    index_j = keyframe_index(j, feats[j], settings)
                r = match_pair(
                    i, j, feats[i], feats[j], settings=settings, prior_i=P[i], prior_j=P[j], pixel_to_norm=to_norm,
                    index_j=index_j,
                )
                save_pair(path, r)
            out.append(replace(r, i=i, j=j))  # the cache names spool indices; positions may have moved
        return out

    groups: dict[int, list[int]] = {}
    for i, j in candidates:
        groups.setdefault(j, []).append(i)
    if runner is not None and feature_dir is not None:
        paths = {(i, j): pair_path(i, j) for i, j in candidates}
        runs = _batches(groups, paths, BATCHES_PER_SLOT * max(1, runner.slots))
        batches = []
        for run in runs:
            used = sorted({k for j in run for k in (j, *groups[j])})
            batches.append(PairBatch(
                tuple((j, tuple(groups[j])) for j in run), {k: kfs[k] for k in used}, {k: P[k] for k in used},
                {(i, j): paths[(i, j)] for j in run for i in groups[j]}, feature_dir, cfg.features, settings, to_norm,
                worker_count(cfg),
            ))
        if batches:
            cache_dir.mkdir(parents=True, exist_ok=True)
            cancel = runner.start(match_batch, batches)
            try:  # this thread matches too, from the other end (below): it never waits on the tasks
                return _registered(candidates, groups, register, cfg, progress, priors, n, settings, reverse=True)
            finally:
                cancel()
    return _registered(candidates, groups, register, cfg, progress, priors, n, settings)


def _registered(candidates, groups, register, cfg, progress, priors, n, settings, *, reverse=False
                ) -> RegisteredPairs:
    """Every candidate pair, from the cache or matched on this process's threads (``reverse``: the last keyframes
    first, so pair tasks started from the first meet them in the middle)."""
    order = sorted(groups, reverse=reverse)
    # keyframes side by side in threads: matching and RANSAC run in OpenCV without the GIL, and every index and
    # pair seeds its own thread's RNG, so the results do not depend on the thread or the order
    with ThreadPoolExecutor(worker_count(cfg)) as pool:
        done = pool.map(register, order, [groups[j] for j in order])
        bar = progress_bar(done, total=len(groups), desc="matching", disable=not progress, leave=False, unit="kf")
        by_pair = {(r.i, r.j): r for rs in bar for r in rs}
    results = [by_pair[pair] for pair in candidates]
    if n >= 2 and not any(r.accepted for r in results) and not priors.use_poses:
        raise CompanionError(
            "no two keyframes could be registered (no shared features inside the ROI masks)",
            "check that keyframes overlap (gate threshold) and that the masks keep the facade",
        )
    return RegisteredPairs(tuple(results), settings)

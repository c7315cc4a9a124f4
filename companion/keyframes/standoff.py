"""The camera-to-wall distance measured from the wall's image motion between two frames (issue 26).

Why: the flight and the map trust GNSS absolute position, and a non-RTK receiver is off by a slowly varying bias
of 1-2 m for minutes: the drone then flies at 2.5 or 5.5 m from the wall while every log says 4.0. The estimator's
RELATIVE motion is good to centimetres even then (a bias cancels between two poses a second apart). A sideways
camera translation t moves the image of a wall at distance d by about f t / d pixels, plus the rotation's part,
which the attitude gives. So the wall's measured image motion against the vehicle's relative motion over the same
baseline measures d, whatever the absolute position says.

``measure_standoff`` fits d for one frame pair: the wall's plane homography predicted from the two poses' relative
motion and attitude (``companion.keyframes.motion``: both cameras shifted together so that their mean distance to
the wall is d) is scored against the matched points for every d on a grid in inverse depth, robustly (MSAC: a
match further than a few pixels from the prediction costs the same whatever its miss, so background and wrong
matches do not pull), then refined by least squares on the inliers. Its sigma adds the point scatter (the inliers'
residuals through the fit's sensitivity) and what the poses cannot know better than their noise: the two poses'
relative attitude and relative position, each propagated through the same sensitivity. A pair whose translation
moves the wall less than ``min_translation_share`` of the frame (a hover, motion along the optical axis) or whose
sigma is above ``max_relative_sigma`` of d gives None: no measurement is better than a useless one.

``StandoffEstimator`` combines the measurements of the last ``window_s`` seconds into the current estimate.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from companion.errors import CompanionError
from companion.geo import FacadeFrame
from companion.keyframes.motion import intrinsics, pose_camera, wall_to_image
from companion.records import Pose, StandoffEstimate


@dataclass(frozen=True)
class StandoffFitConfig:
    """Thresholds of one pair's fit. Pixel figures are shares of the image width, so they mean the same on the
    640 px working copy and on a 4K frame (``inlier_share`` 0.015 is 9.6 px at 640 px: the poses' own relative
    error, 1 cm and 0.1 degree, moves the whole predicted wall by 2-3 px at 2.5 m, and a 2-3 sigma draw of it
    must not throw the wall out; wrong matches land anywhere in the frame, so the margin keeps few of them)."""

    inlier_share: float = 0.015  # a match within this of the predicted wall position is an inlier
    min_points: int = 12
    min_translation_share: float = 0.03  # the wall's image motion from translation alone: 19 px at 640 px
    max_relative_sigma: float = 0.10  # a pair whose sigma is above this share of d says too little to keep
    min_distance_m: float = 0.5
    max_distance_m: float = 30.0  # the search range (a far background beyond it cannot be taken for the wall)
    grid_steps: int = 240
    # what the poses cannot tell better (one sigma of the RELATIVE error between the two frames, per axis):
    # the gimbal's reported attitude and the estimator's relative position over a second or so (a clock error
    # between camera and telemetry adds speed x error to the latter)
    attitude_sigma_deg: float = 0.1
    position_sigma_m: float = 0.01

    def __post_init__(self) -> None:
        if not 0.0 < self.min_distance_m < self.max_distance_m:
            raise CompanionError(f"distance range {self.min_distance_m}..{self.max_distance_m} m is empty",
                                 "use e.g. min_distance_m=0.5, max_distance_m=30")
        if self.min_points < 4 or self.grid_steps < 10:
            raise CompanionError(f"min_points={self.min_points}, grid_steps={self.grid_steps}",
                                 "use at least 4 points and 10 grid steps (e.g. 12 and 240)")


@dataclass(frozen=True)
class StandoffMeasurement:
    """One pair's measured camera-to-wall distance (the mean of the two frames'), in metres, with one sigma."""

    distance_m: float
    sigma_m: float
    baseline_m: float  # the camera's travel between the two poses
    n_points: int  # inliers the fit used
    time_s: float  # the pair's middle (the caller's clock: the chain uses capture times)


@dataclass(frozen=True)
class _PairGeometry:
    """The two cameras of a pair in facade coordinates, with the lens matrix."""

    K: np.ndarray
    ca: np.ndarray
    ra: np.ndarray
    cb: np.ndarray
    rb: np.ndarray

    def homographies(self, distances: np.ndarray) -> np.ndarray:
        """(n, 3, 3): frame a -> frame b pixels of the wall plane, both cameras shifted so that their mean
        distance to the wall is each of ``distances``."""
        mean = (self.ca[1] + self.cb[1]) / 2.0
        out = np.empty((len(distances), 3, 3))
        for i, d in enumerate(distances):
            shift = np.array([0.0, d - mean, 0.0])
            Ha = wall_to_image(self.K, self.ca + shift, self.ra)
            Hb = wall_to_image(self.K, self.cb + shift, self.rb)
            out[i] = Hb @ np.linalg.inv(Ha)
        return out

    def rotation_only(self) -> np.ndarray:
        """The wall's motion were it infinitely far: the rotation's part alone."""
        return self.K @ self.rb.T @ self.ra @ np.linalg.inv(self.K)

    @property
    def half_depth_step_m(self) -> float:
        return abs(self.ca[1] - self.cb[1]) / 2.0


def _map(H: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Points (N, 2) through homographies (n, 3, 3) or one (3, 3): (n, N, 2) or (N, 2)."""
    homog = np.concatenate([points, np.ones((len(points), 1))], axis=1)
    mapped = homog @ np.swapaxes(H, -1, -2)
    return mapped[..., :2] / mapped[..., 2:3]


def measure_standoff(points_a: np.ndarray, points_b: np.ndarray, pose_a: Pose, pose_b: Pose, frame: FacadeFrame,
                     hfov_deg: float, width: int, height: int, *, time_s: float | None = None,
                     config: StandoffFitConfig | None = None) -> StandoffMeasurement | None:
    """The camera-to-wall distance that best explains how matched points moved from frame a to frame b.

    ``points_a``/``points_b``: matched pixels (N x 2) of a ``width`` x ``height`` image; they may include
    background and wrong matches (the fit is robust; a majority need not be wall, a plurality must). Only the
    poses' relative position and their attitudes are used. None: too few points, too short a baseline for a
    useful sigma (hover, motion along the optical axis), or no distance in range explains the wall."""
    cfg = config or StandoffFitConfig()
    pa = np.asarray(points_a, dtype=np.float64).reshape(-1, 2)
    pb = np.asarray(points_b, dtype=np.float64).reshape(-1, 2)
    if len(pa) != len(pb) or len(pa) < cfg.min_points:
        return None
    values = (pose_a.lat, pose_a.lon, pose_a.alt_amsl_m, *pose_a.camera_angles(),
              pose_b.lat, pose_b.lon, pose_b.alt_amsl_m, *pose_b.camera_angles())
    if not all(math.isfinite(float(v)) for v in values):
        return None
    (ca, ra), (cb, rb) = pose_camera(frame, pose_a), pose_camera(frame, pose_b)
    geo = _PairGeometry(intrinsics(hfov_deg, width, height), ca, ra, cb, rb)
    tau = cfg.inlier_share * width
    d = _robust_fit(geo, pa, pb, tau, cfg)
    if d is None:
        return None
    inliers = np.linalg.norm(_map(geo.homographies(np.array([d]))[0], pa) - pb, axis=1) < tau
    if int(inliers.sum()) < cfg.min_points:
        return None
    pa, pb = pa[inliers], pb[inliers]
    translation = np.linalg.norm(_map(geo.homographies(np.array([d]))[0], pa) - _map(geo.rotation_only(), pa), axis=1)
    if float(np.median(translation)) < cfg.min_translation_share * width:
        return None
    sigma = _sigma(geo, pa, pb, d, cfg)
    if not math.isfinite(sigma) or sigma > cfg.max_relative_sigma * d:
        return None
    when = (pose_a.time_s + pose_b.time_s) / 2.0 if time_s is None else float(time_s)
    return StandoffMeasurement(round(d, 4), round(sigma, 4), float(np.linalg.norm(cb - ca)), len(pa), when)


def _robust_fit(geo: _PairGeometry, pa: np.ndarray, pb: np.ndarray, tau: float,
                cfg: StandoffFitConfig) -> float | None:
    """The MSAC-best distance on a grid even in inverse depth, refined by least squares on its inliers; None when
    the best lies on the range's edge (nothing in range explains the motion) or has too few inliers."""
    near = max(cfg.min_distance_m, geo.half_depth_step_m + 0.2)  # both cameras in front of the wall
    if near >= cfg.max_distance_m:
        return None
    grid = 1.0 / np.linspace(1.0 / near, 1.0 / cfg.max_distance_m, cfg.grid_steps)
    miss = np.linalg.norm(_map(geo.homographies(grid), pa) - pb[None], axis=2)
    cost = np.minimum(miss, tau) ** 2
    best = int(np.argmin(cost.sum(axis=1)))
    if best in (0, len(grid) - 1) or int((miss[best] < tau).sum()) < cfg.min_points:
        return None
    d = float(grid[best])
    for _ in range(3):  # Gauss-Newton over d on the current inliers, inliers taken again after each step
        r, J = _residuals_and_slope(geo, pa, pb, d)
        inl = np.repeat(np.linalg.norm(r.reshape(-1, 2), axis=1) < tau, 2)
        JJ = float(J[inl] @ J[inl])
        if JJ <= 0.0:
            return None
        d = float(np.clip(d - float(J[inl] @ r[inl]) / JJ, grid[0], grid[-1]))
    return d


def _residuals_and_slope(geo: _PairGeometry, pa: np.ndarray, pb: np.ndarray, d: float) -> tuple[np.ndarray,
                                                                                                 np.ndarray]:
    """Residuals (2N,: predicted minus measured, px) at d and their derivative over d (px per metre)."""
    h = 1e-4 * d
    Hs = geo.homographies(np.array([d, d - h, d + h]))
    r = (_map(Hs[0], pa) - pb).ravel()
    J = ((_map(Hs[2], pa) - _map(Hs[1], pa)) / (2.0 * h)).ravel()
    return r, J


def _sigma(geo: _PairGeometry, pa: np.ndarray, pb: np.ndarray, d: float, cfg: StandoffFitConfig) -> float:
    """One sigma of d: the inliers' scatter, plus the poses' relative attitude and position noise, each a change
    of the predicted motion projected through the fit's sensitivity (the least-squares shift of d it causes)."""
    r, J = _residuals_and_slope(geo, pa, pb, d)
    JJ = float(J @ J)
    if JJ <= 0.0:
        return math.inf
    n = len(pa)
    scatter = float(r @ r) / max(1, 2 * n - 1)
    var = scatter / JJ
    f = geo.K[0, 0]
    centred = (pa - geo.K[:2, 2]) / f  # normalised image coordinates of the points in frame a
    nuisances = [
        # a rotation error shifts the whole image by f x angle, across and along
        np.tile([f * math.radians(cfg.attitude_sigma_deg), 0.0], n),
        np.tile([0.0, f * math.radians(cfg.attitude_sigma_deg)], n),
        # a relative position error along the wall or up it: a shift of f x error / d
        np.tile([f * cfg.position_sigma_m / d, 0.0], n),
        np.tile([0.0, f * cfg.position_sigma_m / d], n),
        # ... towards the wall: a zoom about the image centre by error / d
        (f * centred * cfg.position_sigma_m / d).ravel(),
    ]
    var += sum((float(J @ dr) / JJ) ** 2 for dr in nuisances)
    return math.sqrt(var)


class StandoffEstimator:
    """The current standoff from the measurements of the last ``window_s`` seconds (robust, with its sigma).

    Measurements further than ``reject_sigmas`` robust spreads (and their own sigma) from the window's median are
    left out (a pair on a wrong wall, a pose glitch); the rest are averaged with inverse-variance weights. The
    sigma is that of the weighted mean, scaled up when the measurements scatter more than their sigmas say
    (Birge ratio): pairs that share a keyframe share its pose error, so they are not as independent as their
    count suggests. No measurement in the window (a plain wall, the camera blocked, a hover): None, never the
    last value held."""

    def __init__(self, window_s: float = 5.0, reject_sigmas: float = 3.0, keep: int = 256):
        if window_s <= 0.0:
            raise CompanionError(f"window_s={window_s} must be > 0", "use a few seconds (e.g. 5)")
        self.window_s = window_s
        self.reject_sigmas = reject_sigmas
        self._recent: deque[StandoffMeasurement] = deque(maxlen=keep)
        self.count = 0  # measurements added in all

    def add(self, measurement: StandoffMeasurement) -> None:
        self._recent.append(measurement)
        self.count += 1

    def estimate(self, now_s: float) -> StandoffEstimate | None:
        """The estimate at ``now_s`` (the measurements' clock) from those in (now - window, now]."""
        window = [m for m in self._recent if now_s - self.window_s < m.time_s <= now_s + 1e-9]
        if not window:
            return None
        d = np.array([m.distance_m for m in window])
        s = np.array([m.sigma_m for m in window])
        median = float(np.median(d))
        spread = 1.4826 * float(np.median(np.abs(d - median)))
        keep = np.abs(d - median) <= self.reject_sigmas * np.maximum(spread, s)
        d, s = d[keep], s[keep]
        w = 1.0 / s**2
        mean = float(w @ d / w.sum())
        sigma = math.sqrt(1.0 / float(w.sum()))
        if len(d) > 1:
            birge = float(w @ (d - mean) ** 2) / (len(d) - 1)
            sigma *= math.sqrt(max(1.0, birge))
        return StandoffEstimate(round(mean, 3), round(sigma, 3), int(len(d)), float(now_s))

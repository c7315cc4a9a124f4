"""The wall's distance measured by the images against the telemetry's relative motion: the map's scale.

Why: a non-RTK GNSS receiver is off by a metre or two for minutes at a time. Placed with that position, every
keyframe's footprint on the wall is scaled by (telemetry distance / true distance): a 1 m bias towards a wall at
4 m makes the map 1.33x too large while every image still matches its neighbours (issue 26). What the bias does
not touch is the RELATIVE motion between keyframes (it cancels between two positions), and what the images
measure is how far the wall moved in the image for that motion: for a wall at distance d, a camera moving t along
it moves the wall's image by f t / d. So the images fix d.

How: each connected part of the pair graph is laid out by its images alone (pairwise homographies chained from
its best-connected keyframe, whose telemetry footprint fixes the layout's scale: ``d_root / d`` of the truth).
The telemetry's image centres are then fitted to the chained ones by a scale and a shift (robust least squares,
Cauchy weights, so a GNSS jump on a few keyframes is outvoted): the scale is ``d_root / d``. Long baselines (a
whole strip, strip to strip) decide it, so attitude noise, which moves one keyframe's image by f x angle, counts
for little. The correction is one distance offset for the whole map: a bias that drifts slowly shows as a larger
residual, and so as a larger ``sigma_m``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from companion.stitch.align import chained_layouts, pair_graph
from companion.stitch.geometry import apply_h, camera_distance_to_wall
from companion.stitch.inputs import CameraModel, StitchInput
from companion.stitch.pairs import RegisteredPairs
from companion.stitch.priors import PlanePriors

MIN_KEYFRAMES = 4  # a part of the map with fewer keyframes with telemetry measures nothing
MIN_SPREAD_M = 0.5  # nor one whose keyframes' telemetry spans less than this (rms about their centre)
SIGNIFICANT_SIGMAS = 2.0  # the correction is applied when it is at least this many sigmas from zero
# the measurement's resolution: keypoints placed to a fraction of a pixel over a few hundred pixels of wall motion
# (exact telemetry measures 4.002 m for 4.000); no smaller sigma is claimed, so a correction under twice this is
# not worth making (exact or zero-mean telemetry keeps its map)
MIN_SIGMA_FRACTION = 0.0025


@dataclass(frozen=True)
class WallDistance:
    """The camera-to-wall distance: what the telemetry says, what the images measure, and the correction
    applied to every keyframe's position across the wall (``out_shift_m``, 0 when nothing was measured or the
    measurement does not differ from the telemetry by ``SIGNIFICANT_SIGMAS``)."""

    telemetry_m: float  # median distance the telemetry puts the cameras at
    measured_m: float | None  # the images' measurement of the same median distance; None: not measurable
    sigma_m: float | None  # its standard uncertainty
    out_shift_m: float  # added to every camera's distance from the wall (applied)
    keyframes: int  # keyframes with telemetry in the measured parts
    parts: int  # connected parts of the pair graph that measured
    reason: str | None = None  # why nothing was measured

    @property
    def applied(self) -> bool:
        return self.out_shift_m != 0.0

    @property
    def distance_m(self) -> float:
        """The distance the map's scale stands on."""
        return self.telemetry_m + self.out_shift_m

    @property
    def scale_sigma(self) -> float | None:
        """Relative standard uncertainty of the map's scale (mm/px)."""
        if self.sigma_m is None:
            return None
        return self.sigma_m / self.distance_m

    def summary(self) -> dict:
        return {
            "telemetry_m": round(self.telemetry_m, 3),
            "measured_m": None if self.measured_m is None else round(self.measured_m, 3),
            "sigma_m": None if self.sigma_m is None else round(self.sigma_m, 3),
            "used_m": round(self.distance_m, 3),
            "correction_m": round(self.out_shift_m, 3),
            "applied": self.applied,
            "scale_sigma_percent": None if self.scale_sigma is None else round(100 * self.scale_sigma, 2),
            "keyframes": self.keyframes,
            "parts": self.parts,
            "reason": self.reason,
            "meaning": "camera-to-wall distance: the telemetry's, and the one the images measure from the wall's "
            "image motion against the telemetry's relative motion (a GNSS bias across the wall cancels in the "
            "relative motion); the map's scale stands on used_m, good to scale_sigma_percent",
        }


@dataclass(frozen=True)
class _PartFit:
    """One connected part's measurement: each keyframe's distance correction across the wall."""

    positions: tuple[int, ...]  # keyframe positions, in spool order
    shifts_m: np.ndarray  # measured true distance - telemetry distance, per keyframe
    common_sigma_m: float  # the part's shared uncertainty (the layout scale's fit)


def measure_wall_distance(inp: StitchInput, priors: PlanePriors, pairs: RegisteredPairs) -> WallDistance:
    """The wall distance the accepted pairs measure (see the module's docstring)."""
    if not priors.use_poses:  # no poses, or no wall to measure them against (a spool without spool.json)
        return WallDistance(0.0, None, None, 0.0, 0, 0, "no telemetry poses on a known wall")
    told = [kf.pose for kf in inp.keyframes if kf.pose is not None]
    telemetry = {k: camera_distance_to_wall(kf.pose, inp.facade) for k, kf in enumerate(inp.keyframes)
                 if kf.pose is not None}
    telemetry_m = float(np.median(list(telemetry.values()))) if told else 0.0
    fits = _part_fits(priors, pairs, inp.camera, telemetry)
    if not fits:
        return WallDistance(telemetry_m, None, None, 0.0, 0, 0,
                            f"no part of the map has {MIN_KEYFRAMES} connected keyframes spread over "
                            f"{MIN_SPREAD_M} m")
    shifts = np.concatenate([f.shifts_m for f in fits])
    shift = float(np.median(shifts))
    # the shared part (each part's scale fit) and the keyframes' own scatter (chain drift, telemetry noise
    # across the wall), whose median is known to about 1.25 MAD / sqrt(n)
    common = math.sqrt(1.0 / sum(1.0 / max(f.common_sigma_m, 1e-6) ** 2 for f in fits))
    scatter = 1.4826 * float(np.median(np.abs(shifts - shift))) * 1.2533 / math.sqrt(len(shifts))
    measured = float(np.median([telemetry[k] for f in fits for k in f.positions])) + shift
    sigma = max(math.hypot(common, scatter), MIN_SIGMA_FRACTION * measured)
    applied = shift if abs(shift) >= SIGNIFICANT_SIGMAS * sigma else 0.0
    return WallDistance(telemetry_m, measured, sigma, applied, len(shifts), len(fits))


def _part_fits(priors: PlanePriors, pairs: RegisteredPairs, camera: CameraModel,
               telemetry: dict[int, float]) -> list[_PartFit]:
    """Per connected part: the images' layout against the telemetry's centres gives the layout's scale (the
    root's true distance); each keyframe's footprint in that layout against its telemetry footprint gives its
    own true distance, so one keyframe's GNSS noise across the wall (the root's too) is not passed to the rest."""
    n = len(priors.priors)
    edges = pair_graph(pairs.results, np.linalg.inv(camera.K))
    centre = np.zeros((1, 2))
    fits = []
    for _root, part, chained in chained_layouts(n, edges, list(priors.priors)):
        told = [k for k in sorted(part) if priors.priors[k] is not None and k in telemetry]
        if len(told) < MIN_KEYFRAMES:
            continue
        x = np.array([apply_h(chained[k], centre)[0] for k in told])  # where the images put the centres
        y = np.array([apply_h(priors.priors[k], centre)[0] for k in told])  # where the telemetry does
        spread = float(np.sqrt(np.mean(np.sum((y - y.mean(axis=0)) ** 2, axis=1))))
        if spread < MIN_SPREAD_M:
            continue
        ratio, ratio_sigma = _robust_scale(x, y)
        if ratio is None or ratio <= 0:
            continue
        # true distance / telemetry distance of keyframe k: its footprint in the images' layout, brought to
        # metres (/ ratio), over its telemetry footprint
        d = np.array([telemetry[k] for k in told])
        rel = np.array([_footprint_scale(chained[k]) / _footprint_scale(priors.priors[k]) for k in told]) / ratio
        fits.append(_PartFit(tuple(told), d * (rel - 1.0), float(np.median(d * rel)) * ratio_sigma / ratio))
    return fits


def _footprint_scale(H: np.ndarray) -> float:
    """Metres on the plane per image-normalised unit at the image centre (the square root of the Jacobian's
    determinant): proportional to the camera's distance from the wall."""
    H = H / H[2, 2]
    J = H[:2, :2] - np.outer(H[:2, 2], H[2, :2])
    return math.sqrt(abs(float(np.linalg.det(J))))


def _robust_scale(x: np.ndarray, y: np.ndarray, iterations: int = 20) -> tuple[float | None, float]:
    """Scale a and shift t with x ~ a y + t, Cauchy-weighted (IRLS); returns (a, its standard uncertainty).

    The uncertainty is the slope's least-squares error with the residual spread measured robustly (MAD), so the
    keyframes the weights leave out (a GNSS jump) do not inflate it, and those kept are not assumed better than
    they scatter."""
    w = np.ones(len(x))
    a = None
    for _ in range(iterations):
        ym = np.sum(w[:, None] * y, axis=0) / w.sum()
        xm = np.sum(w[:, None] * x, axis=0) / w.sum()
        dy, dx = y - ym, x - xm
        den = float(np.sum(w * np.sum(dy * dy, axis=1)))
        if den <= 0:
            return None, math.inf
        a_new = float(np.sum(w * np.sum(dx * dy, axis=1)) / den)
        r = np.linalg.norm(x - (a_new * y + (xm - a_new * ym)), axis=1)
        scale = max(1.4826 * float(np.median(r)), 1e-4)
        w = 1.0 / (1.0 + (r / (2.385 * scale)) ** 2)
        done = a is not None and abs(a_new - a) < 1e-7
        a = a_new
        if done:
            break
    kept = w > 0.5  # within about two robust sigmas: the keyframes that decided the fit
    n_kept = int(kept.sum())
    if a is None or n_kept < MIN_KEYFRAMES:
        return None, math.inf
    dy = y[kept] - y[kept].mean(axis=0)
    sigma_r = 1.4826 * float(np.median(r[kept])) / math.sqrt(2.0)  # per axis, from the 2-D residual norm
    sigma_r = max(sigma_r, float(np.sqrt(np.mean(r[kept] ** 2) / 2.0)))
    # 2 dof per keyframe, 3 fitted (scale, shift): the residual spread understates the noise by that much
    sigma_r *= math.sqrt(2 * n_kept / max(2 * n_kept - 3, 1))
    return a, sigma_r / math.sqrt(float(np.sum(dy * dy)))

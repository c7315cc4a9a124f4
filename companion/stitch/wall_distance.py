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
for little.

A receiver's bias is not constant: it wanders by a metre over minutes. So the same fit is also made on windows of
``WINDOW_KEYFRAMES`` consecutive keyframes (about 45 s of a scan), each giving the bias across the wall at its time;
a drift also stretches the telemetry's relative motion over the whole flight, which a window's short baselines
barely see. When the windows disagree with one distance offset beyond their uncertainty (a chi-square test at
``VARYING_SIGMAS``), each keyframe gets the offset of its time (interpolated between the windows); otherwise the
map keeps one offset, and a bias that does not move changes nothing.
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
# a local fit's keyframes: about 45 s of the demo's scan (a keyframe every 1.5 s), two vertical strips; a GNSS bias
# wanders over minutes, so within a window it is close to constant. Windows overlap by half.
WINDOW_KEYFRAMES = 30
# the windows' offsets differ from one offset when their chi-square exceeds its degrees of freedom by this many of
# its standard deviations (sqrt(2 dof)): noise alone almost never does, a drift of decimetres does
VARYING_SIGMAS = 5.0


@dataclass(frozen=True)
class WallDistance:
    """The camera-to-wall distance: what the telemetry says, what the images measure, and the correction
    applied to every keyframe's position across the wall (``out_shift_m``, 0 when nothing was measured or the
    measurement does not differ from the telemetry by ``SIGNIFICANT_SIGMAS``)."""

    telemetry_m: float  # median distance the telemetry puts the cameras at
    measured_m: float | None  # the images' measurement of the same median distance; None: not measurable
    sigma_m: float | None  # its standard uncertainty
    out_shift_m: float  # added to every camera's distance from the wall (applied), or the median of ``varying``
    keyframes: int  # keyframes with telemetry in the measured parts
    parts: int  # connected parts of the pair graph that measured
    reason: str | None = None  # why nothing was measured
    # the bias drifted: each keyframe position's own offset (in spool order), applied instead of ``out_shift_m``
    varying: tuple[float, ...] | None = None
    windows: int = 0  # local fits made (the windows of WINDOW_KEYFRAMES keyframes)

    @property
    def applied(self) -> bool:
        return self.out_shift_m != 0.0 or self.varying is not None

    def shifts(self, n: int) -> tuple[float, ...]:
        """The offset to apply to each of ``n`` keyframe positions."""
        return self.varying if self.varying is not None else (self.out_shift_m,) * n

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
            "windows": self.windows,
            "varying": self.varying is not None,
            "correction_range_m": None if self.varying is None else [round(min(self.varying), 3),
                                                                      round(max(self.varying), 3)],
            "reason": self.reason,
            "meaning": "camera-to-wall distance: the telemetry's, and the one the images measure from the wall's "
            "image motion against the telemetry's relative motion (a GNSS bias across the wall cancels in the "
            "relative motion); the map's scale stands on used_m, good to scale_sigma_percent; varying: the bias "
            "drifted during the flight and each keyframe got the correction of its time (correction_range_m)",
        }


@dataclass(frozen=True)
class _PartFit:
    """One connected part's measurement: each keyframe's distance correction across the wall."""

    positions: tuple[int, ...]  # keyframe positions, in spool order
    shifts_m: np.ndarray  # measured true distance - telemetry distance, per keyframe
    common_sigma_m: float  # the part's shared uncertainty (the layout scale's fit)
    layout: _PartLayout  # what the fit was made from, for the windows' local fits


@dataclass(frozen=True)
class _PartLayout:
    """A part's keyframes as the images lay them out and as the telemetry does, in spool order."""

    chained: np.ndarray  # (n, 2) image centres in the images' layout
    told: np.ndarray  # (n, 2) the same centres where the telemetry puts them (metres on the wall)
    distance_m: np.ndarray  # the telemetry's camera-wall distance per keyframe
    footprint_ratio: np.ndarray  # footprint scale in the images' layout over the telemetry's, per keyframe

    def window(self, sl: slice) -> _PartLayout:
        return _PartLayout(self.chained[sl], self.told[sl], self.distance_m[sl], self.footprint_ratio[sl])

    def fit(self) -> tuple[np.ndarray, float] | None:
        """Each keyframe's measured true distance - telemetry distance, and the uncertainty all of them share (the
        layout scale's fit); None when the keyframes span too little or the fit fails. The images' layout against
        the telemetry's centres gives the layout's scale (the root's true distance); a keyframe's footprint in it,
        brought to metres (/ ratio), over its telemetry footprint gives its own."""
        y = self.told
        if float(np.sqrt(np.mean(np.sum((y - y.mean(axis=0)) ** 2, axis=1)))) < MIN_SPREAD_M:
            return None
        ratio, ratio_sigma = _robust_scale(self.chained, y)
        if ratio is None or ratio <= 0 or not math.isfinite(ratio_sigma):
            return None
        rel = self.footprint_ratio / ratio
        return self.distance_m * (rel - 1.0), float(np.median(self.distance_m * rel)) * ratio_sigma / ratio


@dataclass(frozen=True)
class _Window:
    centre: float  # mean spool position of its keyframes
    shift_m: float  # its median distance offset
    sigma_m: float  # that median's standard uncertainty


def measure_wall_distance(inp: StitchInput, priors: PlanePriors, pairs: RegisteredPairs) -> WallDistance:
    """The wall distance the accepted pairs measure (see the module's docstring)."""
    if not priors.use_poses:  # no poses, or no wall to measure them against (a spool without spool.json)
        return WallDistance(0.0, None, None, 0.0, 0, 0, "no telemetry poses on a known wall")
    telemetry = {k: camera_distance_to_wall(kf.pose, inp.facade) for k, kf in enumerate(inp.keyframes)
                 if kf.pose is not None}
    telemetry_m = float(np.median(list(telemetry.values()))) if telemetry else 0.0
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
    scatter = _median_sigma(shifts)
    told_median = float(np.median([telemetry[k] for f in fits for k in f.positions]))
    measured = told_median + shift
    sigma = max(math.hypot(common, scatter), MIN_SIGMA_FRACTION * measured)
    windows = [w for f in fits for w in _windows(f, MIN_SIGMA_FRACTION * measured)]
    varying = _varying_shifts(fits, windows, len(inp.keyframes))
    if varying is not None:
        values = np.array([varying[k] for f in fits for k in f.positions])
        shift = float(np.median(values))
        measured = told_median + shift
        # what the map's one mm/px stands on: the windows' own uncertainty, not the drift between them
        sigma = max(math.sqrt(1.0 / sum(1.0 / w.sigma_m**2 for w in windows)) * math.sqrt(len(windows)),
                    MIN_SIGMA_FRACTION * measured)
        return WallDistance(telemetry_m, measured, sigma, shift, len(shifts), len(fits), varying=varying,
                            windows=len(windows))
    applied = shift if abs(shift) >= SIGNIFICANT_SIGMAS * sigma else 0.0
    return WallDistance(telemetry_m, measured, sigma, applied, len(shifts), len(fits), windows=len(windows))


def _median_sigma(values: np.ndarray) -> float:
    """Standard uncertainty of a sample's median: about 1.25 robust spreads (1.4826 MAD) / sqrt(n)."""
    median = float(np.median(values))
    return 1.4826 * float(np.median(np.abs(values - median))) * 1.2533 / math.sqrt(len(values))


def _windows(fit: _PartFit, floor_m: float) -> list[_Window]:
    """The part's local fits: windows of WINDOW_KEYFRAMES consecutive keyframes (overlapping by half), each laid
    out against the telemetry on its own, so the offset it measures is the bias of its time."""
    lay = fit.layout
    n = len(fit.positions)
    if n < 2 * MIN_KEYFRAMES:
        return []
    size = min(WINDOW_KEYFRAMES, max(2 * MIN_KEYFRAMES, n // 3))  # a short pass still gets three windows
    starts = sorted({*range(0, n - size + 1, max(size // 2, 1)), n - size})
    out = []
    for a in starts:
        sl = slice(a, a + size)
        fitted = lay.window(sl).fit()
        if fitted is None:
            continue
        shifts, common = fitted
        sigma = max(math.hypot(common, _median_sigma(shifts)), floor_m)
        out.append(_Window(float(np.mean(fit.positions[sl])), float(np.median(shifts)), sigma))
    return out


def _varying_shifts(fits: list[_PartFit], windows: list[_Window], n: int) -> tuple[float, ...] | None:
    """Each keyframe position's offset when the windows disagree with one offset (None when they agree, or
    when there are too few windows to tell): interpolated between the windows' centres, the nearest window's
    beyond them; keyframes outside the measured parts get the median."""
    if len(windows) < 3:
        return None
    shifts = np.array([w.shift_m for w in windows])
    sigmas = np.array([w.sigma_m for w in windows])
    weights = 1.0 / sigmas**2
    mean = float(np.sum(weights * shifts) / np.sum(weights))
    chi2 = float(np.sum(((shifts - mean) / sigmas) ** 2))
    dof = len(windows) - 1
    if chi2 <= dof + VARYING_SIGMAS * math.sqrt(2.0 * dof):
        return None
    order = np.argsort([w.centre for w in windows])
    centres = np.array([windows[i].centre for i in order])
    values = shifts[order]
    measured = {k for f in fits for k in f.positions}
    median = float(np.median(values))
    return tuple(float(np.interp(k, centres, values)) if k in measured else median for k in range(n))


def _part_fits(priors: PlanePriors, pairs: RegisteredPairs, camera: CameraModel,
               telemetry: dict[int, float]) -> list[_PartFit]:
    """Per connected part of the pair graph, its keyframes laid out by the images and fitted to the telemetry
    (``_PartLayout.fit``): each keyframe's own true distance, so one keyframe's GNSS noise across the wall (the
    root's too) is not passed to the rest."""
    n = len(priors.priors)
    edges = pair_graph(pairs.results, np.linalg.inv(camera.K))
    centre = np.zeros((1, 2))
    fits = []
    for _root, part, chained in chained_layouts(n, edges, list(priors.priors)):
        told = [k for k in sorted(part) if priors.priors[k] is not None and k in telemetry]
        if len(told) < MIN_KEYFRAMES:
            continue
        lay = _PartLayout(np.array([apply_h(chained[k], centre)[0] for k in told]),  # where the images put them
                          np.array([apply_h(priors.priors[k], centre)[0] for k in told]),  # where the telemetry does
                          np.array([telemetry[k] for k in told]),
                          np.array([_footprint_scale(chained[k]) / _footprint_scale(priors.priors[k]) for k in told]))
        fitted = lay.fit()
        if fitted is not None:
            fits.append(_PartFit(tuple(told), fitted[0], fitted[1], lay))
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

"""ROI extraction from a disparity image (paper Eq. 1), pure numpy + OpenCV.

disparity -> Sobel gradient magnitude G -> Otsu binarisation -> pepper-noise removal -> boundary ->
regions between boundaries -> keep the nearer (higher disparity) regions -> mask at full frame resolution.

Monocular disparity is only defined up to scale, so every decision here is relative (ratios of disparities,
gradients normalised by the median disparity) except the optional ``min_roi_disparity`` that flags a frame
whose kept ROI is on average still too far to be the facade (the whole frame is background).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from companion.errors import CompanionError


@dataclass(frozen=True)
class RoiParams:
    """Tuning of the ROI extraction, chosen on simulator frames and real-texture passes (see docs/DEPTH.md)."""

    # A region is background when its mean disparity is below ``near_ratio`` x the nearest region's mean
    # (0.4 means: more than 2.5x farther away than the facade). Windows, recesses and balconies a metre or two
    # off the wall plane are at most ~1.5x farther at a 4 m standoff; a background at 20 m or more is 5x.
    # 0.6 (chosen on the simulator alone) cut the windows and balconies a network reads too far on real facades.
    near_ratio: float = 0.4
    # Gradients below this (relative to the median disparity, per pixel) are never a boundary, so a smooth,
    # boundary-free disparity map is not cut by Otsu thresholding its noise.
    min_rel_gradient: float = 0.02
    # Boundary components and regions smaller than this fraction of the frame are pepper noise.
    min_component_frac: float = 0.002
    # Closing kernel (pixels at model resolution) that bridges small gaps in the boundary.
    close_px: int = 3
    # Pixels with disparity below far_cut_ratio x the facade's (95th percentile of the kept side) are cut even
    # without a boundary (0.4: more than 2.5x farther than the facade). 0 disables (pure paper method).
    far_cut_ratio: float = 0.4
    # Mean disparity of the finally kept ROI below this: whole frame background (frame dropped). None: never.
    min_roi_disparity: float | None = None
    # Metric models only: also cut every pixel the network puts farther than the masker's ROI depth limit
    # (``Masker(max_roi_depth_m=15)``), whatever region it lies in, and drop the frame when less than
    # ``min_roi_fraction`` of it is left. A network that reads real background at 30-100 m but a sliver of it at
    # 8-11 m then keeps only that sliver, and a frame with a thin strip of wall at its edge keeps the strip
    # instead of being dropped for the mean depth of everything its regions joined to it.
    pixel_depth_cut: bool = False
    min_pixel_disparity: float | None = None  # set by the masker from its depth limit when pixel_depth_cut
    min_roi_fraction: float = 0.0

    def __post_init__(self) -> None:
        if not 0.0 < self.near_ratio < 1.0:
            raise CompanionError(
                f"near_ratio must be in (0, 1), got {self.near_ratio}", "use e.g. 0.6 (background >= 1.67x farther)"
            )
        if self.min_rel_gradient < 0 or not 0 <= self.min_component_frac < 0.5 or self.close_px < 0 \
                or not 0 <= self.far_cut_ratio < 1:
            raise CompanionError("ROI parameters out of range", "use non-negative values (see RoiParams defaults)")


@dataclass
class RoiResult:
    """Outcome of ROI extraction for one frame.

    ``mask`` is uint8 0/255 at the requested output size (255 = facade). ``empty`` marks a frame with no ROI
    (whole frame background): the pipeline drops it and counts it. ``no_boundary`` marks a frame that is
    facade everywhere (no depth boundary found).
    """

    mask: np.ndarray
    empty: bool
    no_boundary: bool
    roi_fraction: float
    n_regions: int  # regions found between boundaries (after pepper-noise removal)
    n_kept: int  # of which kept as ROI
    roi_mean_disparity: float  # nan when empty
    background_mean_disparity: float  # nan when there is no background
    gradient_threshold: float  # relative gradient threshold used (max of Otsu and the floor)

    @property
    def roi_nearer(self) -> bool | None:
        """True when the ROI's mean disparity is above the background's (nearer); None without both."""
        if self.empty or np.isnan(self.background_mean_disparity):
            return None
        return bool(self.roi_mean_disparity > self.background_mean_disparity)


def gradient_magnitude(disparity: np.ndarray) -> np.ndarray:
    """Paper Eq. 1: G = sqrt((dI'/dx)^2 + (dI'/dy)^2) with 3x3 Sobel derivatives (scaled to per-pixel)."""
    gx = cv2.Sobel(disparity, cv2.CV_32F, 1, 0, ksize=3, borderType=cv2.BORDER_REPLICATE) / 8.0
    gy = cv2.Sobel(disparity, cv2.CV_32F, 0, 1, ksize=3, borderType=cv2.BORDER_REPLICATE) / 8.0
    return np.sqrt(gx * gx + gy * gy)


def otsu_threshold(values: np.ndarray, bins: int = 256) -> float:
    """Otsu's threshold of a float array (maximises the between-class variance of a histogram)."""
    v = values.ravel()
    lo, hi = float(v.min()), float(v.max())
    if hi - lo <= 1e-12:
        return hi
    hist, edges = np.histogram(v, bins=bins, range=(lo, hi))
    hist = hist.astype(np.float64)
    centers = 0.5 * (edges[:-1] + edges[1:])
    w0 = np.cumsum(hist)
    w1 = w0[-1] - w0
    m0 = np.cumsum(hist * centers)
    mu0 = m0 / np.maximum(w0, 1e-12)
    mu1 = (m0[-1] - m0) / np.maximum(w1, 1e-12)
    between = w0 * w1 * (mu0 - mu1) ** 2
    k = int(np.argmax(between[:-1]))
    return float(edges[k + 1])


def otsu_threshold_fast(values: np.ndarray) -> float:
    """Otsu's threshold via OpenCV on values scaled to 0..255 (same result as ``otsu_threshold`` to 1/255)."""
    hi = float(values.max())
    if hi <= 1e-12:
        return hi
    u8 = np.clip(values * (255.0 / hi), 0, 255).astype(np.uint8)
    t, _ = cv2.threshold(u8, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
    return (t + 0.5) * hi / 255.0


def _components(binary: np.ndarray, connectivity: int):
    """Connected components (Spaghetti algorithm: ~2x faster than OpenCV's default for 4-connectivity)."""
    return cv2.connectedComponentsWithStatsWithAlgorithm(
        binary.astype(np.uint8), connectivity, cv2.CV_32S, cv2.CCL_SPAGHETTI
    )


def _remove_small(binary: np.ndarray, min_area: int, connectivity: int = 8) -> np.ndarray:
    """Drop connected components of a 0/1 image smaller than ``min_area`` pixels (pepper noise)."""
    n, labels, stats, _ = _components(binary, connectivity)
    if n <= 1:
        return binary.astype(bool)
    keep = stats[:, cv2.CC_STAT_AREA] >= min_area
    keep[0] = False
    return keep[labels]


def boundary_map(disparity: np.ndarray, params: RoiParams) -> tuple[np.ndarray, float]:
    """Binary boundary image (True = boundary) after Otsu and pepper-noise removal, and the threshold used."""
    d = disparity.astype(np.float32)
    scale = float(np.median(d[::4, ::4]))  # subsampled: the scale need not be exact
    if not np.isfinite(scale) or scale <= 0:
        scale = float(np.max(d)) if np.max(d) > 0 else 1.0
    g = gradient_magnitude(d / scale)
    thr = max(otsu_threshold_fast(g), params.min_rel_gradient)
    edges = g > thr
    min_area = max(4, int(params.min_component_frac * d.size))
    edges = _remove_small(edges, min_area)
    if params.close_px > 1 and edges.any():
        k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (params.close_px, params.close_px))
        edges = cv2.morphologyEx(edges.astype(np.uint8), cv2.MORPH_CLOSE, k).astype(bool)
    return edges, thr


def _disparity_image(disparity: np.ndarray) -> np.ndarray:
    """The disparity as a finite, non-negative float32 H x W image (a network's 1x1xHxW or 1xHxW squeezed)."""
    d = np.asarray(disparity)
    if d.ndim == 4 and d.shape[:2] == (1, 1):
        d = d[0, 0]
    elif d.ndim == 3 and d.shape[0] == 1:
        d = d[0]
    if d.ndim != 2 or min(d.shape) < 8:
        raise CompanionError(
            f"disparity must be a 2-D image of at least 8x8 pixels, got shape {np.shape(disparity)}",
            "pass the depth model's disparity output (H x W)",
        )
    d = d.astype(np.float32)
    if not np.all(np.isfinite(d)):
        raise CompanionError("disparity contains NaN or inf", "check the depth model output (disparity, not depth)")
    return np.maximum(d, 0.0)


@dataclass(frozen=True)
class _Regions:
    """The regions between depth boundaries: a label image (0 = boundary), the ids of the regions large enough
    not to be pepper noise, and per label the disparity sum and pixel count."""

    labels: np.ndarray
    n_labels: int
    ids: list[int]
    sums: np.ndarray
    counts: np.ndarray

    def mean(self, i: int) -> float:
        return self.sums[i] / max(self.counts[i], 1)

    def pooled_mean(self, ids: list[int]) -> float:
        return float(sum(self.sums[i] for i in ids) / sum(self.counts[i] for i in ids))


def _regions_between_boundaries(d: np.ndarray, edges: np.ndarray, params: RoiParams) -> _Regions:
    """4-connected regions of the non-boundary pixels; when the boundary covers everything (pathological noise)
    the whole frame is one region."""
    n, labels, stats, _ = _components(~edges, 4)
    min_area = max(4, int(params.min_component_frac * d.size))
    region_ids = [i for i in range(1, n) if stats[i, cv2.CC_STAT_AREA] >= min_area]
    if not region_ids:
        n, labels, region_ids = 2, np.ones_like(labels), [1]
    flat = labels.ravel()
    sums = np.bincount(flat, weights=d.ravel(), minlength=n + 1)
    counts = np.bincount(flat, minlength=n + 1)
    return _Regions(labels, n, region_ids, sums, counts)


def _nearer_pixels(d: np.ndarray, regions: _Regions, params: RoiParams) -> tuple[np.ndarray, list[int]]:
    """Boolean keep-mask of the near side and the ids of the regions kept: regions within ``near_ratio`` of the
    nearest one, then a disparity cut (midway between kept and dropped, and ``far_cut_ratio`` of the facade),
    then pepper islands and holes removed."""
    means = {i: regions.mean(i) for i in regions.ids}
    nearest = max(means.values())
    kept = [i for i in regions.ids if means[i] >= params.near_ratio * nearest]
    dropped = [i for i in regions.ids if i not in kept]
    is_dropped = np.zeros(regions.n_labels, bool)
    is_dropped[dropped] = True
    in_dropped = is_dropped[regions.labels]  # boundary pixels (label 0) are decided by the cut below
    cut = 0.0
    if dropped:
        # Pixels on the boundary (and tiny regions) go to the side their disparity is closer to; the same cut
        # also trims background that leaked into a kept region through a gap in the boundary.
        cut = 0.5 * (regions.pooled_mean(kept) + regions.pooled_mean(dropped))
    if params.far_cut_ratio > 0:
        # Surfaces that run on continuously from the facade into the distance (a roof seen from above, the
        # ground, a side wall) cross no boundary; their parts far behind the facade are cut by depth alone.
        side = d[::2, ::2][~in_dropped[::2, ::2]]
        near_ref = float(np.percentile(side if side.size else d[~in_dropped], 95))
        cut = max(cut, params.far_cut_ratio * near_ref)
    if params.min_pixel_disparity is not None:
        cut = max(cut, params.min_pixel_disparity)
    keep = (~in_dropped) & (d >= cut)
    if not keep.all():
        min_island = max(4, int(params.min_component_frac * d.size))
        keep = _remove_small(keep, min_island, connectivity=4)
        keep = ~_remove_small(~keep, min_island, connectivity=4)  # fill pepper holes in the ROI
    return keep, kept


def _mask_at_size(keep: np.ndarray, out_w: int, out_h: int) -> np.ndarray:
    """The 0/255 mask at the output size (linear interpolation of the 0/1 mask, then 0.5 threshold: smooth edges)."""
    h, w = keep.shape
    if (out_w, out_h) != (w, h):
        soft = cv2.resize(keep.astype(np.float32), (out_w, out_h), interpolation=cv2.INTER_LINEAR)
        return np.where(soft >= 0.5, 255, 0).astype(np.uint8)
    return np.where(keep, 255, 0).astype(np.uint8)


def extract_roi(
    disparity: np.ndarray,
    out_size: tuple[int, int] | None = None,
    params: RoiParams | None = None,
) -> RoiResult:
    """Segment the near facade from the far background in a disparity image (higher = nearer).

    ``out_size`` is (width, height) of the full-resolution frame; the mask is computed at the disparity's
    resolution and resized (linear interpolation of the 0/1 mask, then 0.5 threshold, for smooth edges).
    """
    params = params or RoiParams()
    d = _disparity_image(disparity)
    h, w = d.shape
    out_w, out_h = out_size if out_size is not None else (w, h)

    edges, thr = boundary_map(d, params)
    regions = _regions_between_boundaries(d, edges, params)
    keep, kept = _nearer_pixels(d, regions, params)
    too_far = params.min_roi_disparity is not None and (not keep.any()
                                                        or float(d[keep].mean()) < params.min_roi_disparity)
    if too_far or float(keep.mean()) < params.min_roi_fraction:
        # Judged on what is finally kept, not on the nearest region's mean: a wall joined to the sky through a
        # gap in the boundary (a wall end fading into the ground) makes one region whose mean is the sky's.
        return RoiResult(
            mask=np.zeros((out_h, out_w), np.uint8),
            empty=True,
            no_boundary=False,
            roi_fraction=0.0,
            n_regions=len(regions.ids),
            n_kept=0,
            roi_mean_disparity=float("nan"),
            background_mean_disparity=float(np.mean(d)),
            gradient_threshold=thr,
        )

    mask = _mask_at_size(keep, out_w, out_h)
    roi_px = keep.sum()
    return RoiResult(
        mask=mask,
        empty=bool(roi_px == 0),
        no_boundary=bool(keep.all()),  # nothing cut: the whole frame is facade
        roi_fraction=float(np.count_nonzero(mask)) / mask.size,
        n_regions=len(regions.ids),
        n_kept=len(kept),
        roi_mean_disparity=float(d[keep].mean()) if roi_px else float("nan"),
        background_mean_disparity=float(d[~keep].mean()) if roi_px < keep.size else float("nan"),
        gradient_threshold=thr,
    )


def apply_mask(image: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """The masked frame: background pixels set to black (the mask must match the image's size)."""
    if image.shape[:2] != mask.shape[:2]:
        raise CompanionError(
            f"mask {mask.shape[:2]} does not match image {image.shape[:2]}",
            "extract the ROI with out_size=(image width, image height)",
        )
    return cv2.bitwise_and(image, image, mask=mask)


def pixel_error_ratio(mask: np.ndarray, truth: np.ndarray) -> float:
    """Fraction of pixels whose ROI/background label differs from the ground-truth mask (paper: 0.75 % mean)."""
    if mask.shape != truth.shape:
        truth = cv2.resize(truth, (mask.shape[1], mask.shape[0]), interpolation=cv2.INTER_NEAREST)
    return float(np.count_nonzero((mask > 127) != (truth > 127))) / mask.size

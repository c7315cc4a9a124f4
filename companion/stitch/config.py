"""What the stitcher can be told: one frozen settings record read by every stage (and the CLI's defaults)."""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, replace

from companion.keyframes.features import FeatureConfig
from companion.matching import MatcherSettings

# The stitcher's features: the gate's extraction (FeatureConfig's CLAHE before SIFT, contrast threshold 0.01 and ROI
# erosion: the settings that find matchable features on plain walls, where plain SIFT left 39 of 90 pairs of a plain
# wall unregistered, issue 15) on a larger working copy with more features, for the map's accuracy. 4K keyframes are
# downscaled to 1600 px for features only.
STITCH_FEATURES = replace(FeatureConfig(), long_side_px=1600, max_features=4000)
# The stitcher's matcher: Lowe's 0.75, 4 kd-trees, 32 checks. On 4K keyframes 32 checks find 98.7 % of the
# ratio-test matches that 64 find (and 98.9 % of exact brute force's, against 99.6 % for 64) in 0.65x the search
# time (docs/BENCHMARKS.md).
STITCH_MATCHING = MatcherSettings(ratio=0.75, kind="flann", trees=4, checks=32)


@dataclass(frozen=True)
class StitchConfig:
    features: FeatureConfig = STITCH_FEATURES  # SIFT in each keyframe's ROI
    neighbours: int = 2  # sequence neighbours matched besides telemetry-overlapping keyframes
    matching: MatcherSettings = STITCH_MATCHING  # pairs: ratio test and FLANN search over keyframe j's index
    ransac_px: float | None = None  # default: 0.4 % of the image width, at least 2 px
    min_inliers: int = 15
    max_pair_residual_px: float = 8.0  # a pair still this far off after global alignment is an outlier
    # matches/models landing further apart than this on the wall contradict telemetry: loose, because GNSS next
    # to a wall is off by metres (0.5 m noise on each of two keyframes and a 1.5 m jump: ~3 m between them).
    # None: ``pose_gate(distance)``, which grows with the camera's distance from the wall (attitude noise moves a
    # keyframe's footprint by distance x angle: 2 degrees at 30 m is 1 m per keyframe)
    pose_gate_m: float | None = None
    attitude_sigma_deg: float = 2.0  # how far the telemetry's attitude may be off (one sigma), for that gate
    far_motion_ratio: float = 0.25  # a plane moving less than this fraction of another in a pair is background
    wall_check: bool = True  # cut mask pixels that neighbouring keyframes show are off the wall plane
    use_poses: bool = True
    # the telemetry prior in the global alignment is robust (Cauchy): within about sigma it pulls like a Gaussian,
    # far beyond (a GNSS jump) it hardly pulls at all, so the images outvote it
    sigma_prior_m: float = 0.5  # how far GNSS may put an image centre off on the wall
    sigma_shape_m: float = 0.15  # how far attitude errors may bend an image's corners (relative to centre): 2 deg
    # how far GNSS absolute position may put the whole map off (per axis, one sigma): a non-RTK receiver's bias of
    # a metre or two that lasts minutes, so it does not average out over a scan (RTK: a few centimetres). The map's
    # placement is this uncertain along (up) unless the keyframes show the wall's ends (roof line: wall_anchor.py)
    gnss_sigma_m: float = 1.5
    # measure the wall's distance from the images and put the map on the wall's edges (wall_distance.py,
    # wall_anchor.py); False: scale and place from the telemetry alone, the map before issue 26 (comparisons)
    measure_wall: bool = True
    local: bool = True  # APAP mesh; False draws each keyframe with its global homography only
    cells: tuple[int, int] = (16, 9)  # Cx x Cy
    rho_px: float | None = None  # Eq. 4 scale; default 10 % of the image width
    gamma: float = 0.01  # weight floor: far cells fall back to the global homography
    mm_per_px: float | None = None  # map scale; default the keyframes' median native resolution
    # refuse absurd map sizes (a bad scale or geometry) before allocating anything; a map really wanted larger (a
    # gigapixel facade at a fine --mm-per-px) is asked for with --max-map-px: rendering and writing are tiled, so
    # memory does not grow with the map (docs/SCALE.md)
    max_map_px: float = 4e8
    tile_px: int = 1024
    max_in_memory_px: float = 6e7  # larger maps are written only as tiles (+ a preview)
    feather_px: float = 4.0
    workers: int = 0  # threads for features, pair matching and keyframe decoding; 0: one per CPU core
    gain_compensation: bool = True
    preview_width: int = 3000
    min_uncovered_m2: float = 0.02
    uncovered_cell_m: float = 0.1  # holes are reported on this grid (re-fly planning, not pixel accuracy)

    def pose_gate(self, distance_m: float) -> float:
        """The telemetry gate on pairs (metres on the wall) for cameras ``distance_m`` from it: ``pose_gate_m``
        when set; else 4 m (GNSS's noise and jumps between two keyframes) or, further out, 3 m plus three
        sigmas of two keyframes' attitude error carried to the wall, whichever is larger."""
        if self.pose_gate_m is not None:
            return self.pose_gate_m
        attitude_m = math.sqrt(2.0) * distance_m * math.tan(math.radians(self.attitude_sigma_deg))
        return max(4.0, 3.0 + 3.0 * attitude_m)

    def ransac_threshold_px(self, image_width: int) -> float:
        """The pairwise RANSAC threshold in full-resolution pixels (also the alignment's match sigma)."""
        return self.ransac_px or max(2.0, 0.004 * image_width)


def worker_count(cfg: StitchConfig) -> int:
    """Threads the stitcher's parallel stages use (at least 1)."""
    return max(1, cfg.workers or len(os.sched_getaffinity(0)))

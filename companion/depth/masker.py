"""The depth-mask pipeline stage: TaggedFrame -> MaskedFrame (or dropped and counted when no ROI is left)."""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from companion.depth.roi import RoiParams, RoiResult, extract_roi
from companion.depth.session import DepthSession
from companion.records import MaskedFrame, TaggedFrame


@dataclass
class MaskerStats:
    frames: int = 0
    dropped_empty: int = 0  # whole frame background: no ROI, frame dropped
    no_boundary: int = 0  # whole frame facade
    parallax_frames: int = 0  # frames whose mask parallax confirmed or corrected (the rest: network alone)
    parallax_skipped_sure: int = 0  # frames the network read as wall everywhere at the standoff: no flow spent
    bound_cut: int = 0  # frames whose mask the mission's wall bound cut (pixels where the wall cannot be)
    bound_dropped: int = 0  # ... of those, frames it left nothing of: dropped as background
    depth_ms: list[float] = field(default_factory=list)
    mask_ms: list[float] = field(default_factory=list)


class Masker:
    """Runs the depth model and ROI extraction on each frame.

    ``max_roi_depth_m`` (default 15 m, about 4x the scan standoff) only applies to models trained on metric
    depth (metadata ``metric_depth=true``, as the shipped one): a frame whose nearest region is farther is
    entirely background and is dropped. Scale-free models (e.g. official KITTI weights) never drop a frame
    for distance, only cut the far side of depth boundaries.

    ``parallax`` (a :class:`companion.depth.parallax.SequenceParallax`, off by default): frames arriving in
    capture order with telemetry poses are also compared with an earlier frame; where the motion parallax is
    trusted it overrides the network's near/far answer, and it drops frames whose trusted pixels are all far
    (docs/DEPTH.md), except while the last kept frame's wall, moved by the telemetry's baseline, must still be in
    view (a sliver of wall at the wall's end: ``ParallaxParams.wall_in_view_rule``). Frames without a pose or a
    baseline keep the network's mask.
    """

    def __init__(
        self,
        model_path: str | Path | None = None,
        *,
        session: DepthSession | None = None,
        params: RoiParams | None = None,
        max_roi_depth_m: float | None = 15.0,
        threads: int | None = None,
        parallax=None,
        bound=None,
    ):
        self.parallax = parallax
        self.bound = bound
        self.session = session or DepthSession(model_path, threads=threads)
        params = params or RoiParams()
        info = self.session.info
        if info.metric and max_roi_depth_m is not None and params.min_roi_disparity is None:
            params = replace(params, min_roi_disparity=info.disparity_for_depth(max_roi_depth_m))
        if info.metric and max_roi_depth_m is not None and params.pixel_depth_cut \
                and params.min_pixel_disparity is None:
            params = replace(params, min_pixel_disparity=info.disparity_for_depth(max_roi_depth_m))
        self.params = params
        self.stats = MaskerStats()

    def mask(self, tagged: TaggedFrame) -> tuple[MaskedFrame | None, RoiResult]:
        """Mask one frame; the MaskedFrame is None when the frame has no ROI (counted in ``stats``)."""
        masked, roi, _ = self.mask_measured(tagged)
        return masked, roi

    def mask_measured(self, tagged: TaggedFrame) -> tuple[MaskedFrame | None, RoiResult, np.ndarray]:
        """:meth:`mask` plus the network's disparity (model resolution), for evaluations that look at it; the
        chain does not carry it."""
        t0 = time.perf_counter()
        disp = self.session.disparity(tagged.frame.image)
        masked, roi = self._mask_from_disparity(tagged, disp, (time.perf_counter() - t0) * 1e3)
        return masked, roi, disp

    def mask_disparity(self, tagged: TaggedFrame, disparity: np.ndarray) -> tuple[MaskedFrame | None, RoiResult]:
        """:meth:`mask` of a frame whose disparity this masker's model already gave (``session.disparity``): an
        evaluation runs the network once per frame and several maskers (ROI and parallax rules) on its answer, each
        exactly as the chain masks (no network time is counted)."""
        return self._mask_from_disparity(tagged, disparity, None)

    def _mask_from_disparity(self, tagged: TaggedFrame, disp: np.ndarray,
                             depth_ms: float | None) -> tuple[MaskedFrame | None, RoiResult]:
        image = tagged.frame.image
        t1 = time.perf_counter()
        roi = self.roi_from_disparity(disp, image.shape[:2])
        if self.parallax is not None:
            roi = self._with_parallax(image, tagged, roi, disp)
        if self.bound is not None and not roi.empty and not tagged.pose_stale:
            roi = self._within_bound(roi, self.bound(tagged.pose, image.shape))
        t2 = time.perf_counter()
        st = self.stats
        st.frames += 1
        if depth_ms is not None:
            st.depth_ms.append(depth_ms)
        st.mask_ms.append((t2 - t1) * 1e3)
        st.no_boundary += int(roi.no_boundary)
        if roi.empty:
            st.dropped_empty += 1
            return None, roi
        return MaskedFrame(tagged=tagged, mask=roi.mask), roi

    def remember(self, tagged: TaggedFrame) -> None:
        """Show the masker a frame it will not mask (the chain tracks it only): with parallax on, it becomes a
        possible reference for the next masked frame. Costs a resize; nothing without parallax."""
        if self.parallax is not None and not tagged.pose_stale:
            self.parallax.remember(tagged.frame.image, tagged.pose)

    def _with_parallax(self, image, tagged: TaggedFrame, roi: RoiResult, disparity: np.ndarray) -> RoiResult:
        from companion.depth.parallax import fuse_with_network, keep_wall_in_view, network_is_sure, wall_depth_of

        pose = None if tagged.pose_stale else tagged.pose
        info = self.session.info
        network_wall_m = (float(info.depth_from_disparity(np.float32(roi.roi_mean_disparity)))
                          if info.metric and np.isfinite(roi.roi_mean_disparity) else float("nan"))
        fallback_m = self.parallax.standoff_m or network_wall_m
        if network_is_sure(roi, info, self.parallax.standoff_m, self.parallax.params):
            self.stats.parallax_skipped_sure += 1
            self.parallax.remember(image, pose)  # still a reference for the next frame in doubt
            self.parallax.note_kept(roi.mask, pose, fallback_m)
            return roi
        in_view = self.parallax.wall_in_view(pose, image.shape)
        par = self.parallax.update(image, pose)
        network = roi.mask if not roi.empty else np.zeros(image.shape[:2], np.uint8)
        if par is None:
            roi = self._unjudged(roi, disparity, image.shape[:2])
            network = roi.mask if not roi.empty else np.zeros(image.shape[:2], np.uint8)
            mask, dropped = network, roi.empty
        else:
            self.stats.parallax_frames += 1
            depth = info.depth_from_disparity(np.squeeze(disparity))  # its ordering is all the split needs
            mask, dropped = fuse_with_network(network, par, depth, image)
        carried = keep_wall_in_view(mask, dropped, in_view, par, self.parallax.params)
        wall_m = wall_depth_of(par, fallback_m) if carried[0] is mask else self.parallax.kept_wall_depth_m()
        mask, dropped = carried
        share = float(np.count_nonzero(mask)) / mask.size
        if not dropped and share > 0.0:
            self.parallax.note_kept(mask, pose, wall_m)
        if par is None and mask is network:
            return roi
        return replace(roi, mask=mask, empty=dropped or share == 0.0, no_boundary=share == 1.0, roi_fraction=share)

    def _within_bound(self, roi: RoiResult, bound: np.ndarray | None) -> RoiResult:
        """The ROI cut to the wall bound (counted in ``stats`` when that cut anything)."""
        from companion.depth.wall_bound import apply_bound

        if bound is None:
            return roi
        mask = apply_bound(roi.mask, bound)
        kept = int(np.count_nonzero(mask))
        if kept == int(np.count_nonzero(roi.mask)):
            return roi
        self.stats.bound_cut += 1
        self.stats.bound_dropped += int(kept == 0)
        share = kept / mask.size
        return replace(roi, mask=mask, empty=kept == 0, no_boundary=False, roi_fraction=share)

    def _unjudged(self, roi: RoiResult, disparity, frame_shape: tuple[int, int]) -> RoiResult:
        """The network's ROI for a frame parallax cannot judge (``ParallaxParams.unjudged_far_cut_ratio``)."""
        params = unjudged_params(self.params, self.parallax.params)
        if params is self.params:
            return roi
        return extract_roi(disparity, out_size=(frame_shape[1], frame_shape[0]), params=params)

    def roi_from_disparity(self, disparity, frame_shape: tuple[int, int]) -> RoiResult:
        """The ROI of a disparity this masker's model produced, at the frame's (height, width); not counted.

        Lets an evaluation run the model once per frame and compare several ROI rules on the same disparity.
        """
        return extract_roi(disparity, out_size=(frame_shape[1], frame_shape[0]), params=self.params)

    def __call__(self, tagged: TaggedFrame) -> MaskedFrame | None:
        return self.mask(tagged)[0]


def unjudged_params(roi: RoiParams, parallax) -> RoiParams:
    """The ROI rules for a frame parallax cannot judge: ``roi`` with the far cut of ``parallax``
    (``ParallaxParams.unjudged_far_cut_ratio``; ``roi`` itself when that is None or the same)."""
    ratio = parallax.unjudged_far_cut_ratio
    if ratio is None or ratio == roi.far_cut_ratio:
        return roi
    return replace(roi, far_cut_ratio=ratio)

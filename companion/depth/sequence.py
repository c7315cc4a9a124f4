"""Parallax for a pass of photos without telemetry: ``companion mask IMAGES --sequence``.

``companion/depth/parallax.py`` turns the flow between two frames into depth with the baseline that telemetry
gives. Anyone's photos come without it, but one pass along a wall (photos in capture order, taken at a steady
speed and interval) has two things that stand in for it:

* the direction the image moves is the same for every pair (the pass direction), and
* the baseline between neighbouring photos is about the same for every pair, so ``s = f x baseline`` (pixels x
  metres at work resolution) is one number for the pass. Each pair where the network sees a near surface
  measures it as the network's metric depth of that surface times its flow; the median over the pass is robust
  to pairs where the network is wrong, and a photo of only far background is then judged by the pass's scale,
  not by the network that misread it.

Each photo is compared with its predecessor (the first with its successor); the result goes through
``fuse_with_network``: trusted near pixels kept, trusted far pixels cut, a photo whose trusted pixels are all far
dropped (all-zero mask), untrusted (plain) pixels keep the network's answer. The photos are read twice (the pass's
scale must be known before the first photo is decided) and the network runs once per photo.

Limits: one straight pass at a steady speed (a turn or a stop breaks the constant-baseline assumption), a model
trained on metric depth (the shipped ones), and a scene that is static between neighbouring photos.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import cv2
import numpy as np

from companion.depth.parallax import (
    DenseFlow,
    ParallaxParams,
    dense_flow,
    depth_from_flow,
    dominant_motion_grey,
    fill_untrusted,
    fuse_with_network,
    merged_flow,
    motion_prior,
)
from companion.errors import CompanionError

MIN_MOTION_PX = 0.5  # median flow (work pixels) below which a pair shows no usable motion (hover, repeated photo)
MIN_SCALE_PIXELS = 200  # network-near, trusted pixels a pair needs to measure the pass's scale


@dataclass(frozen=True)
class PassMotion:
    """What the pass's neighbouring photos say together."""

    direction: np.ndarray  # unit (x, y): how the image content moves from one photo to the next (work pixels)
    scale_px_m: float  # focal length (work pixels) x baseline between neighbouring photos (metres)
    pairs: int  # pairs that measured the scale
    # the wall's dominant motion between neighbours (work pixels, the median of the pairs aligned by
    # :func:`dominant_prior`), None when no pair needed aligning: a pair whose own dominant motion is the
    # background's (the wall entering or leaving the view) is measured around it too (:func:`pass_flow`)
    wall_shift: tuple[int, int] | None = None
    # the wall's depth in the pass's units (scale / the wall's motion on pairs the network reads as mostly near),
    # for the wall-plane check of a photo whose own flow shows too little wall to measure it (a sliver at the
    # frame's edge); None when no pair measured it or ``ParallaxParams.sequence_wall_depth`` is off
    wall_depth: float | None = None
    wall_motion_px: float | None = None  # that dominant motion (work pixels)
    # per photo index: whether its pair with the previous readable photo moves along the pass (the median trusted
    # flow within ``ParallaxParams.sequence_break_deg`` of the pass's direction); False at a strip's first photo,
    # whose predecessor is the last of the strip before (another height, the camera flown back)
    continuous: dict[int, bool] | None = None


@dataclass(frozen=True)
class NetworkMask:
    """The network's answer for one photo, kept compact between the two readings of the pass."""

    png: bytes  # the mask (uint8 0/255, photo size), PNG-encoded
    empty: bool  # the network found no near surface

    def mask(self) -> np.ndarray:
        return cv2.imdecode(np.frombuffer(self.png, np.uint8), cv2.IMREAD_UNCHANGED)


@dataclass(frozen=True)
class SequenceMask:
    """One photo's mask after parallax: what to write, and whether parallax judged it."""

    mask: np.ndarray  # uint8 0/255, photo size
    no_near_surface: bool
    parallax: bool  # False: the network alone decided (no usable motion or no pass scale)


@dataclass(frozen=True)
class ScaleSample:
    """One pair's measure of the pass's scale: ``depth x flow`` over what the network calls near, and how far the
    pair's content moved (its median trusted flow, work pixels)."""

    scale_px_m: float
    motion_px: float


def _pair_measure(flow: DenseFlow, network_near: np.ndarray, network_depth_m: np.ndarray,
                  params: ParallaxParams) -> tuple[np.ndarray | None, ScaleSample | None]:
    """A pair's median flow vector (None without enough trusted, moving pixels) and its scale sample
    ``depth x flow`` over the pixels the network calls near (None with too few of them)."""
    if flow.trusted.mean() < params.min_confident_share:
        return None, None
    vectors = flow.flow[flow.trusted]
    median = np.median(vectors, axis=0)
    motion = float(np.hypot(*median))
    if motion < MIN_MOTION_PX:
        return None, None
    direction = median / motion
    near = flow.trusted & network_near
    along = flow.flow[near] @ direction
    moving = along > MIN_MOTION_PX
    if int(moving.sum()) < MIN_SCALE_PIXELS:
        return direction, None
    return direction, ScaleSample(float(np.median(network_depth_m[near][moving] * along[moving])), motion)


def pass_scale(samples: Sequence[ScaleSample], min_motion_share: float | None) -> float:
    """The pass's scale: the median of the samples, or (``min_motion_share``) of those whose pair moved at least that
    share of the pass's wall motion (the 90th percentile of the pairs' motion): background-only pairs past the
    wall's end move little and, where the network reads the far background as near, measure far too small a scale."""
    if min_motion_share is not None:
        floor = min_motion_share * float(np.percentile([s.motion_px for s in samples], 90))
        samples = [s for s in samples if s.motion_px >= floor] or list(samples)
    return float(np.median([s.scale_px_m for s in samples]))


def pass_motion(directions: Sequence[np.ndarray | None], scales: Sequence[ScaleSample | None],
                shifts: Sequence[tuple[int, int]] = (), wall_motions: Sequence[float] = (),
                scale_min_motion: float | None = None) -> PassMotion | None:
    """The pass's direction (median of the pairs') and scale (:func:`pass_scale` of the pairs that measured one);
    None when no pair measured a scale (the network alone decides every photo). ``shifts``: the priors of the
    aligned pairs; ``wall_motions``: the dominant motion (work pixels) of pairs the network reads as mostly near."""
    measured = [s for s in scales if s is not None]
    moving = [d for d in directions if d is not None]
    if not measured or not moving:
        return None
    d = np.median(np.array(moving), axis=0)
    norm = float(np.hypot(*d))
    if norm < 1e-6:
        return None
    wall_shift = tuple(int(round(v)) for v in np.median(np.array(shifts), axis=0)) if shifts else None
    scale = pass_scale(measured, scale_min_motion)
    wall_motion = float(np.median(wall_motions)) if wall_motions else None
    wall_depth = scale / wall_motion if wall_motion else None
    return PassMotion(d / norm, scale, len(measured), wall_shift, wall_depth, wall_motion)


def pass_flow(ref: np.ndarray, cur: np.ndarray, params: ParallaxParams, wall_shift: tuple[int, int] | None):
    """The flow of one pair for deciding a photo (:func:`merged_flow`): around its own dominant motion, and where the
    pass's wall motion differs from that (the wall entering or leaving the view, the background dominating the
    pair) also around the wall's. With ``sequence_zero_prior`` also around no motion (a far background moves a few
    pixels while the wall dominates the pair: measured around the wall's motion it is lost)."""
    own = dominant_prior(ref, cur, params)
    zero = (0, 0) if params.sequence_zero_prior and wall_shift is not None else None
    return merged_flow(lambda prior: dense_flow(ref, cur, params, prior), (own or (0, 0), wall_shift, zero), params)


def dominant_motion(ref: np.ndarray, cur: np.ndarray, params: ParallaxParams) -> tuple[float, float, float]:
    """The two photos' dominant image motion (work pixels, ``cur(x) ~ ref(x + d)``) by phase correlation of the
    working copies, and the correlation peak (near 1: one motion fills the frame)."""
    size = _work_size(cur, params)
    grey = [cv2.resize(cv2.cvtColor(im, cv2.COLOR_BGR2GRAY) if im.ndim == 3 else im, size,
                       interpolation=cv2.INTER_AREA).astype(np.float32) for im in (ref, cur)]
    return dominant_motion_grey(grey[0], grey[1])


def dominant_prior(ref: np.ndarray, cur: np.ndarray, params: ParallaxParams,
                   motion: tuple[float, float, float] | None = None) -> tuple[int, int] | None:
    """:func:`dominant_motion` (or the one given) when it is large enough that DIS should measure around it
    (:func:`motion_prior`); None otherwise."""
    if params.sequence_align_share is None:
        return None
    return motion_prior(motion or dominant_motion(ref, cur, params), params)


def _work_size(image: np.ndarray, params: ParallaxParams) -> tuple[int, int]:
    h, w = image.shape[:2]
    return params.work_width, max(8, round(h * params.work_width / w))


class SequenceMasker:
    """Masks the photos of one pass in capture order with the network and parallax (see the module notes).

    ``masker`` is a :class:`companion.depth.masker.Masker` whose model was trained on metric depth.
    """

    def __init__(self, masker, params: ParallaxParams | None = None):
        info = masker.session.info
        if not info.metric:
            raise CompanionError(
                f"--sequence needs a depth model trained on metric depth; {info.path.name} is scale-free",
                "use a shipped model (--model sim or real-nc), or mask without --sequence",
            )
        self.masker = masker
        self.params = params or ParallaxParams()

    def _network(self, image: np.ndarray) -> tuple[NetworkMask, np.ndarray, np.ndarray]:
        """The network's mask, and at work resolution its near pixels and metric depth."""
        disparity = self.masker.session.disparity(image)
        roi = self.masker.roi_from_disparity(disparity, image.shape[:2])
        mask = roi.mask if not roi.empty else np.zeros(image.shape[:2], np.uint8)
        ok, png = cv2.imencode(".png", mask)
        if not ok:  # pragma: no cover - PNG encoding of a uint8 image does not fail
            raise CompanionError("could not encode a mask", "report this as a bug")
        size = _work_size(image, self.params)
        near = cv2.resize(mask, size, interpolation=cv2.INTER_AREA) >= 128
        depth = cv2.resize(self.masker.session.info.depth_from_disparity(np.squeeze(disparity)).astype(np.float32),
                           size, interpolation=cv2.INTER_LINEAR)
        return NetworkMask(png.tobytes(), bool(roi.empty)), near, depth

    def measure(self, images: Iterator[tuple[int, np.ndarray | None]]) -> tuple[dict[int, NetworkMask],
                                                                                  PassMotion | None]:
        """First reading: the network's mask of every readable photo and the pass's motion."""
        networks: dict[int, NetworkMask] = {}
        directions: list[np.ndarray | None] = []
        scales: list[ScaleSample | None] = []
        shifts: list[tuple[int, int]] = []
        wall_motions: list[float] = []
        previous: np.ndarray | None = None
        pair_directions: dict[int, np.ndarray | None] = {}
        for i, image in images:
            if image is None:
                continue
            networks[i], near, depth = self._network(image)
            if previous is not None and previous.shape == image.shape:
                dominant = dominant_motion(previous, image, self.params)
                prior = dominant_prior(previous, image, self.params, dominant)
                shifts += [prior] if prior is not None else []
                if self.params.sequence_wall_depth and dominant[2] >= self.params.sequence_align_min_response \
                        and near.mean() >= 0.5:
                    wall_motions.append(float(np.hypot(dominant[0], dominant[1])))
                direction, scale = _pair_measure(dense_flow(previous, image, self.params, prior), near, depth,
                                                 self.params)
                directions.append(direction)
                pair_directions[i] = direction
                scales.append(scale)
            previous = image
        motion = pass_motion(directions, scales, shifts, wall_motions, self.params.sequence_scale_min_motion)
        if motion is not None and self.params.sequence_break_deg is not None:
            limit = np.cos(np.radians(self.params.sequence_break_deg))
            motion = replace(motion, continuous={
                i: d is not None and float(np.dot(d, motion.direction)) >= limit for i, d in pair_directions.items()})
        if motion is not None and motion.wall_shift is not None and \
                np.hypot(*motion.wall_shift) > self.params.sequence_max_share * self.params.work_width:
            return networks, None  # stills too far apart for the flow: the network alone decides
        return networks, motion

    def _parallax(self, image: np.ndarray, neighbour: np.ndarray, forward: bool, motion: PassMotion):
        """The photo's parallax against ``neighbour`` (the previous photo, or the next one when ``forward`` is
        False) at the pass's scale."""
        wall_shift = motion.wall_shift if forward or motion.wall_shift is None else \
            (-motion.wall_shift[0], -motion.wall_shift[1])
        flow = pass_flow(neighbour, image, self.params, wall_shift)
        sign = 1.0 if forward else -1.0
        fx = float(image.shape[1])  # any focal length: the scale was measured in the same units, so it cancels
        baseline_m = motion.scale_px_m / (fx * flow.work_width / flow.frame_width)
        translation = np.array([*(sign * baseline_m * motion.direction), 0.0])
        par = depth_from_flow(flow, translation, fx, self.params)
        if par.all_background and motion.wall_depth is not None and \
                motion.wall_motion_px < (self.params.sequence_align_share or 0.0) * self.params.work_width:
            par = depth_from_flow(flow, translation, fx, self.params, motion.wall_depth)
        return par

    def decide(self, image: np.ndarray, neighbour: np.ndarray | None, forward: bool, network: NetworkMask,
               motion: PassMotion | None, other: np.ndarray | None = None) -> SequenceMask:
        """One photo's mask: the network's, corrected by its parallax against ``neighbour`` (the previous photo,
        or the next one when ``forward`` is False) at the pass's scale. ``other``: the neighbour on the other side
        (``ParallaxParams.sequence_both_sides``): its parallax decides the pixels the first flow could not trust
        (the strip that entered the view since the previous photo has nothing to compare with there)."""
        net_mask = network.mask()
        if motion is None or neighbour is None or neighbour.shape != image.shape:
            return SequenceMask(net_mask, network.empty, False)
        par = self._parallax(image, neighbour, forward, motion)
        if self.params.sequence_both_sides and other is not None and other.shape == image.shape:
            par = fill_untrusted(par, self._parallax(image, other, not forward, motion))
        mask, dropped = fuse_with_network(net_mask, par, image=image)
        return SequenceMask(mask, dropped or not mask.any(), True)


def mask_sequence(paths: Sequence[Path], masker, read: Callable[[Path], np.ndarray | None],
                  params: ParallaxParams | None = None) -> Iterator[tuple[int, SequenceMask | None]]:
    """(index into ``paths``, its mask) in order; None for a photo ``read`` could not read."""
    seq = SequenceMasker(masker, params)
    networks, motion = seq.measure((i, read(p)) for i, p in enumerate(paths))
    readable = [i for i in range(len(paths)) if i in networks]
    continuous = (motion.continuous if motion is not None else None) or {}
    previous: np.ndarray | None = None
    for i in range(len(paths)):
        if i not in networks:
            yield i, None
            continue
        image = read(paths[i])
        if image is None:  # changed on disk between the two readings
            raise CompanionError(f"{paths[i]} could not be read the second time",
                                 "leave the photos unchanged while they are being masked, then rerun")
        later = [j for j in readable if j > i]
        # a strip's first photo (its pair with the previous photo does not move along the pass, and its pair with the
        # next one does) is compared with the next one, as the pass's first photo is
        broken = i in continuous and not continuous[i] and bool(later) and continuous.get(later[0], False)
        if previous is not None and not broken:
            neighbour, forward = previous, True
        else:  # the first photo: compared with the next one, whose content moves the other way
            neighbour, forward = (read(paths[later[0]]) if later else None), False
        other = None
        if seq.params.sequence_both_sides and forward and later and continuous.get(later[0], True):
            other = read(paths[later[0]])
        yield i, seq.decide(image, neighbour, forward, networks[i], motion, other)
        previous = image

"""Streaming keyframe gate (paper Sec. 2.2, made online): frames go in one by one, keyframes come out when decided.

After keyframe Ip every new frame Iq gets R(Ip, Iq). While R >= Rth, Iq is the candidate (the newest such frame,
unless it is blurred and the held candidate is not). When R falls below Rth the candidate becomes the next
keyframe and the current frame is compared again against it. So the keyframe is the last frame still >= Rth
(paper: R(I1, I4) = 82.9 % kept, R(I1, I5) = 77.2 % rejected -> I4).

Memory is bounded: between calls the gate holds the last keyframe and one candidate at full resolution, plus
their working-resolution features (one SIFT extraction per incoming frame, one match, two after a promotion).

With telemetry (a ``WallMotionPredictor`` and frames carrying poses) the gate measures the wall, not whatever
RANSAC agrees on: the wall's motion predicted from the two poses picks the RANSAC hypothesis that decides R (a
static far background cannot), a pair the poses put below Rth - ``telemetry_margin`` is never accepted whatever
the image says, and where the image holds too little wall to measure (a thin strip at the wall's end) the
predicted overlap decides and the keyframe's record says so (``overlap_source``). Frames without poses are
decided by the image alone, as in the paper.

``measure`` gives R against the current keyframe without deciding anything, so a scheduler that holds frames back
(``companion.onboard.tracked``) can find the last frame still >= Rth among them and push only that one and the
next; the features and the estimate it computed are reused by the push.

A segment ends at the end of the stream (``flush``) or where the scan is left (``end_segment``, the chain's scan
scope): the held candidate is the wall's last view and becomes the last keyframe, unless it has nothing of the wall
to give (issue 15, the plain-wall pass: at the end of the stream the camera had left the wall, the ROI held 1.5 %
of the frame, 81 % of it background 120 m away, and the stitcher could not place it by images). A last candidate
whose ROI is below ``min_last_roi`` of the frame, or whose ROI outside the previous keyframe's view (the pair's
measured motion, or the poses' where the image could not measure it) is below ``min_last_new_roi`` of the frame,
is dropped and said (``LAST_DROPPED``). A segment ending on frames the gate could not measure after its last
keyframe is a possible gap (``GAP``), unless each of them loses no wall: its ROI is below ``min_last_roi`` (the
camera leaving the wall), or, with the poses and the mission's wall (``wall_unseen``, set by the chain from its
scan scope), the last keyframe shows all the wall it shows (the exit climb past the roof line, the plain roof under
the camera kept as ROI and too poor in features to measure); both are said (``BARE_END``). After ``end_segment``
the next frame opens a new segment: it is judged against nothing before the gap, so it is neither a low-overlap
pair nor a lost track (``SEGMENT``).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field, replace
from enum import StrEnum

import cv2
import numpy as np

from companion.errors import CompanionError
from companion.keyframes.features import FeatureConfig, FeatureExtractor, FeatureSet
from companion.keyframes.motion import WallMotion, WallMotionPredictor
from companion.keyframes.overlap import OverlapConfig, OverlapEstimate, OverlapEstimator
from companion.keyframes.sharpness import SharpnessReference, laplacian_variance
from companion.records import GateDecision, GateReason, Keyframe, MaskedFrame, OverlapSource, Pose


@dataclass(frozen=True)
class GateConfig:
    """``rth`` and ``warn_margin`` are fractions (0.80 = 80 %), the unit of the mission's ``overlap``."""

    rth: float = 0.80
    warn_margin: float = 0.10  # R dropping from >= Rth to below Rth - margin in one frame -> overlap warning
    blur_ratio: float = 0.6  # sharpness below this share of the running reference = blurred
    telemetry_margin: float = 0.03  # poses saying overlap < rth - this veto the pair, whatever the image says
    min_last_roi: float = 0.03  # a segment's last candidate with less ROI (share of the frame) is not kept
    min_last_new_roi: float = 0.001  # ... nor one adding less ROI (share of the frame) outside the previous keyframe
    features: FeatureConfig = field(default_factory=FeatureConfig)
    overlap: OverlapConfig = field(default_factory=OverlapConfig)

    def __post_init__(self) -> None:
        if not 0.0 < self.rth < 1.0:
            hint = f"pass a fraction: {self.rth / 100:.2f}" if 1.0 < self.rth <= 100.0 else "use e.g. 0.80"
            raise CompanionError(f"overlap threshold rth={self.rth} is not a fraction in (0, 1)", hint)
        if not 0.0 <= self.warn_margin < self.rth:
            raise CompanionError(f"warn_margin={self.warn_margin} must be in [0, rth)", "use e.g. 0.10")
        if not 0.0 < self.blur_ratio <= 1.0:
            raise CompanionError(f"blur_ratio={self.blur_ratio} must be in (0, 1]", "use e.g. 0.6")
        if not 0.0 <= self.telemetry_margin < self.rth:
            raise CompanionError(f"telemetry_margin={self.telemetry_margin} must be in [0, rth)", "use e.g. 0.03")
        if not (0.0 <= self.min_last_roi < 1.0 and 0.0 <= self.min_last_new_roi < 1.0):
            raise CompanionError(f"min_last_roi={self.min_last_roi} / min_last_new_roi={self.min_last_new_roi} are not "
                                 "shares of the frame", "use fractions in [0, 1), e.g. 0.03 and 0.001 (0 keeps any)")

    @classmethod
    def for_mission(cls, mission, **overrides) -> GateConfig:
        """Rth from the mission's ``overlap`` (fraction), 0.80 when the mission has none."""
        rth = getattr(mission, "overlap", None)
        return cls(rth=float(rth) if rth is not None else 0.80, **overrides)


_MAX_LOOKED = 8  # frames whose features ``measure`` keeps for a following push


class GateEventKind(StrEnum):
    KEYFRAME = "keyframe"
    OVERLAP_WARNING = "overlap_warning"  # overlap falling too fast: slow down
    LOW_OVERLAP = "low_overlap"  # a keyframe had to be taken below Rth (no frame in between was >= Rth)
    GAP = "gap"  # tracking lost: a new segment starts, the map may have a hole here
    UNUSABLE_FRAME = "unusable_frame"  # no texture in the ROI, or blurred and unmatched: frame skipped
    LAST_DROPPED = "last_dropped"  # a segment's last candidate had no wall to add: not kept
    BARE_END = "bare_end"  # a segment ended on unusable frames with next to no ROI: no wall lost, no gap
    SEGMENT = "segment"  # the scan resumed after a stretch off it: a new segment, not judged against the old one


class StepRole(StrEnum):
    """What one push made of its frame (``GateStep.role``)."""

    KEYFRAME = "keyframe"
    CANDIDATE = "candidate"  # at or above Rth: held, may become the next keyframe
    REJECTED = "rejected"  # neither kept nor held (a sharper neighbour is the candidate)
    UNUSABLE = "unusable"  # the gate could not measure it
    FLUSH = "flush"  # no frame: the segment or stream ended (``end_segment``)


@dataclass(frozen=True)
class GateEvent:
    kind: GateEventKind
    frame_index: int
    message: str
    R: float | None = None  # percent


@dataclass(frozen=True)
class Comparison:
    """One R(Ip, Iq) the gate computed (kept per step for evaluation against simulator truth)."""

    ref_index: int
    frame_index: int
    estimate: OverlapEstimate


@dataclass
class GateStep:
    """What one push did."""

    frame_index: int
    role: StepRole
    sharpness: float
    blurred: bool
    comparisons: list[Comparison] = field(default_factory=list)
    keyframe_indices: list[int] = field(default_factory=list)  # indices only: the step must not pin frames
    events: list[GateEvent] = field(default_factory=list)

    @property
    def overlap_warning(self) -> bool:
        return any(e.kind == GateEventKind.OVERLAP_WARNING for e in self.events)


@dataclass
class _Held:
    masked: MaskedFrame
    features: FeatureSet
    sharpness: float
    blurred: bool
    estimate: OverlapEstimate | None = None  # vs the keyframe it was compared with

    @property
    def index(self) -> int:
        return self.masked.index


class KeyframeGate:
    """Online keyframe selection. ``push(frame) -> keyframes decided now``; ``flush()`` at end of stream.

    ``predictor``: the wall's motion from telemetry poses (see module docstring); None decides on images alone.
    ``on_matches``: called once per pair the gate matched with fresh poses on both frames, as
    ``on_matches(reference, frame, points, (width, height))`` (``points``: every distinctive match, N x 4, full
    resolution px): the chain measures the standoff from them (``companion.onboard.standoff_watch``).
    """

    def __init__(self, config: GateConfig | None = None, predictor: WallMotionPredictor | None = None):
        self.config = config or GateConfig()
        self.predictor = predictor
        self.on_matches: Callable[[MaskedFrame, MaskedFrame, np.ndarray, tuple[int, int]], None] | None = None
        # (frame's pose, keyframe's pose) -> share of the frame showing wall the keyframe does not show (None: cannot
        # tell); the chain sets it from its scan scope (``ScanScope.wall_unseen``). Asked of unusable frames only.
        self.wall_unseen: Callable[[Pose, Pose], float | None] | None = None
        self.telemetry_vetoes = 0  # comparisons where the poses overruled an image R >= Rth
        self.telemetry_fallbacks = 0  # comparisons decided by the poses because the image could not measure the wall
        self.last_dropped = 0  # segments' last candidates not kept: no wall to add (see the module docstring)
        self._segment_ended = False  # end_segment() closed a segment with keyframes: the next keyframe opens one
        self._extractor = FeatureExtractor(self.config.features)
        self._estimator = OverlapEstimator(self.config.overlap)
        self._sharp_ref = SharpnessReference(self.config.blur_ratio)
        self._key: _Held | None = None
        self._cand: _Held | None = None
        self._prev_R: float = 100.0  # R of the previous frame vs the current keyframe
        self._segment = 0
        self._unusable_since_key = 0
        self._unusable_bare_since_key = 0  # ... of them with next to no ROI (< min_last_roi): no wall to lose
        self._unusable_seen_since_key = 0  # ... of them whose wall the keyframe shows (by the poses): none to lose
        self._events: list[GateEvent] = []
        self._out: list[Keyframe] = []  # keyframes decided during the current push/flush
        self.last_step: GateStep | None = None
        self.frames_in = 0
        self.keyframes_out = 0
        self.measured = 0  # frames whose features were extracted (each costs the SIFT extraction)
        # Frames ``measure`` looked at (features) and what it measured, reused by a push of the same frame;
        # bounded: a scheduler looks at a few frames around a decision, then pushes one or two of them.
        self._looked: dict[int, _Held] = {}
        self._looked_est: dict[tuple[int, int], OverlapEstimate] = {}

    # -- public -------------------------------------------------------------------------------------------
    @property
    def rth_percent(self) -> float:
        return 100.0 * self.config.rth

    def held_frames(self) -> int:
        """Full-resolution frames held between calls (at most 2: the keyframe and one candidate)."""
        return int(self._key is not None) + int(self._cand is not None)

    def pop_events(self) -> list[GateEvent]:
        """Events since the last call (warnings, gaps, skipped frames, keyframes), oldest first."""
        events, self._events = self._events, []
        return events

    @property
    def keyframe_index(self) -> int | None:
        """Frame index of the current keyframe (the reference new frames are compared with)."""
        return None if self._key is None else self._key.index

    @property
    def candidate_index(self) -> int | None:
        return None if self._cand is None else self._cand.index

    def held_indices(self) -> list[int]:
        """Frames the gate holds that may still become a keyframe: its candidate (the keyframe is decided). The
        same question the chain asks its other holds (``companion.onboard.pending.Hold``)."""
        return [] if self._cand is None else [self._cand.index]

    def measure(self, masked: MaskedFrame) -> OverlapEstimate | None:
        """R(current keyframe, this frame) without deciding anything (None before the first keyframe or when the
        ROI has too few features). A scheduler uses it to find the last frame still >= Rth among frames it held
        back; the features and the estimate are kept for a ``push`` of the same frame, which then costs nothing
        more."""
        item = self._held(masked)
        self._looked[item.index] = item
        while len(self._looked) > _MAX_LOOKED:
            self._looked.pop(next(iter(self._looked)))
        if self._key is None or len(item.features) < self.config.overlap.min_matches:
            return None
        pair = (self._key.index, item.index)
        if pair not in self._looked_est:
            self._looked_est[pair] = self._estimate(self._key, item, count=False)
        return self._looked_est[pair]

    def push(self, masked: MaskedFrame) -> list[Keyframe]:
        item = self._held(masked)
        self._sharp_ref.update(item.sharpness)
        frame = masked.frame
        step = GateStep(frame.index, StepRole.REJECTED, item.sharpness, item.blurred)
        self.last_step = step
        self.frames_in += 1
        self._out = []
        try:
            self._decide(item, step)
        finally:
            self._events.extend(step.events)
            self._looked = {i: h for i, h in self._looked.items() if i > frame.index}
            self._looked_est = {p: e for p, e in self._looked_est.items() if p[1] in self._looked}
        out, self._out = self._out, []
        return out

    def _held(self, masked: MaskedFrame) -> _Held:
        if not isinstance(masked, MaskedFrame):
            raise CompanionError(
                f"the gate takes MaskedFrame records, got {type(masked).__name__}",
                "wrap frames as MaskedFrame(TaggedFrame(Frame(...), pose), mask) (mask all 255 when unmasked)",
            )
        looked = self._looked.get(masked.index)
        if looked is not None and looked.masked is masked:
            return looked
        feats = self._extractor.extract(masked.image, masked.mask)
        self.measured += 1
        sharp = laplacian_variance(feats.work_gray, feats.work_mask)
        return _Held(masked, feats, sharp, self._sharp_ref.is_blurred(sharp))

    def flush(self) -> list[Keyframe]:
        """End of stream: the held candidate becomes the last keyframe (unless it has no wall to add)."""
        return self.end_segment(end_of_stream=True)

    def end_segment(self, end_of_stream: bool = False) -> list[Keyframe]:
        """The scan was left (or the stream ended): the held candidate, the segment's last view, becomes its last
        keyframe unless it has no wall to add; the next frame pushed opens a new segment."""
        step = GateStep(-1, StepRole.FLUSH, 0.0, False)
        self.last_step = step
        self._out = []
        where = "stream" if end_of_stream else "segment"
        if self._cand is not None:
            why = self._no_wall_to_add(self._key, self._cand)
            if why is None:
                self._promote(step, reason=GateReason.END_OF_STREAM if end_of_stream else GateReason.END_OF_SEGMENT)
            else:
                cand, self._cand = self._cand, None
                self.last_dropped += 1
                step.events.append(GateEvent(GateEventKind.LAST_DROPPED, cand.index,
                                             f"last candidate {cand.index} of the {where} not kept: {why}"))
        no_loss = self._unusable_bare_since_key + self._unusable_seen_since_key
        with_wall = self._unusable_since_key - no_loss
        if with_wall:
            step.events.append(
                GateEvent(
                    GateEventKind.GAP,
                    -1,
                    f"{where} ended with {with_wall} unusable frame(s) showing wall after the last keyframe",
                )
            )
        elif self._unusable_since_key:
            step.events.append(
                GateEvent(
                    GateEventKind.BARE_END,
                    -1,
                    f"{where} ended with {self._unusable_since_key} unusable frame(s) after the last keyframe, "
                    f"{self._unusable_bare_since_key} with an ROI under {100 * self.config.min_last_roi:g} % of the "
                    f"frame (leaving the wall), {self._unusable_seen_since_key} showing only wall keyframe "
                    f"{self._key.index if self._key is not None else '-'} shows (by the poses): no gap",
                )
            )
        self._segment_ended = self._segment_ended or self._key is not None
        self._key = None
        self._prev_R = 100.0
        self._unusable_since_key = self._unusable_bare_since_key = self._unusable_seen_since_key = 0
        self._looked, self._looked_est = {}, {}
        self._events.extend(step.events)
        out, self._out = self._out, []
        return out

    def _no_wall_to_add(self, key: _Held | None, cand: _Held) -> str | None:
        """Why the segment's last candidate is not worth a keyframe (None: keep it): its ROI holds next to no
        wall, or it shows next to no ROI outside the previous keyframe's view."""
        cfg = self.config
        mask = cand.masked.mask
        small = _small_mask(mask)
        roi = small > 127
        share = float(roi.mean()) if roi.size else 0.0
        if share < cfg.min_last_roi:
            return (f"its ROI is {100.0 * share:.1f} % of the frame (next to no wall; at least "
                    f"{100 * cfg.min_last_roi:g} %)")
        if key is None:
            return None
        H = self._key_to_frame(key, cand)
        if H is None:
            return None
        h, w = mask.shape[:2]
        rows, cols = np.nonzero(roi)
        sy, sx = h / small.shape[0], w / small.shape[1]
        pts = np.stack([(cols + 0.5) * sx, (rows + 0.5) * sy], axis=1).reshape(-1, 1, 2)
        try:
            to_key = np.linalg.inv(H)
        except np.linalg.LinAlgError:
            return None
        # the candidate's ROI pixels in the previous keyframe's frame (points behind its camera: not in its view)
        z = pts.reshape(-1, 2) @ to_key[2, :2] + to_key[2, 2]
        x, y = cv2.perspectiveTransform(pts, to_key).reshape(-1, 2).T if len(pts) else (z, z)
        kw, kh = key.features.full_size
        inside = (z > 0) & (x >= 0) & (x < kw) & (y >= 0) & (y < kh)
        new = float(np.count_nonzero(~inside)) / roi.size
        if new < cfg.min_last_new_roi:
            return (f"it adds {100.0 * new:.2f} % of the frame of ROI to keyframe {key.index}'s view (at least "
                    f"{100 * cfg.min_last_new_roi:g} %): nothing of the wall")
        return None

    def _key_to_frame(self, key: _Held, cand: _Held) -> np.ndarray | None:
        """Homography from the keyframe's pixels to the candidate's: the image's where it measured the wall,
        else the poses' prediction, else the measured shift (None: nothing known)."""
        est = cand.estimate
        if est is not None and est.source == OverlapSource.IMAGE and est.H is not None:
            return np.asarray(est.H, dtype=np.float64)
        prior = self._predict(key, cand)
        if prior is not None:
            return np.asarray(prior.H, dtype=np.float64)
        if est is not None and est.dx is not None and est.dy is not None:
            return np.array([[1.0, 0.0, est.dx], [0.0, 1.0, est.dy], [0.0, 0.0, 1.0]])
        return None

    def run(self, frames: Iterable[MaskedFrame]) -> Iterator[Keyframe]:
        """Convenience: push every frame, then flush."""
        for f in frames:
            yield from self.push(f)
        yield from self.flush()

    # -- decisions ----------------------------------------------------------------------------------------
    def _decide(self, item: _Held, step: GateStep) -> None:
        rth = self.rth_percent
        if self._key is None:
            step.role = StepRole.KEYFRAME
            if not self._segment_ended:
                self._emit(item, step, overlap=None, gap=False, reason=GateReason.FIRST)
                return
            self._segment += 1
            step.events.append(GateEvent(GateEventKind.SEGMENT, item.index,
                                         f"scan resumed at frame {item.index}: new segment {self._segment}, not "
                                         "judged against the keyframes before the frames off the scan"))
            self._emit(item, step, overlap=None, gap=True, reason=GateReason.NEW_SEGMENT)
            return
        if len(item.features) < self.config.overlap.min_matches:
            self._unusable(item, step, f"only {len(item.features)} features in the ROI")
            return
        est = self._compare(self._key, item, step)
        if est.known and est.percent >= rth:
            self._offer_candidate(item, est, step)
            return
        if est.known:
            self._warn_if_falling(item, est, step)
            if self._cand is not None:
                self._promote(step, reason=GateReason.OVERLAP)
                self._after_promotion(item, step)
            else:
                self._low_overlap_keyframe(item, est, step)
            return
        # Unknown R: tracking lost against the keyframe.
        if item.blurred:
            self._unusable(item, step, f"blurred and unmatched ({est.status})")
            return
        if self._cand is not None:
            self._promote(step, reason=GateReason.TRACKING_LOST)
            self._after_promotion(item, step)
        else:
            self._gap_keyframe(item, est, step)

    def _after_promotion(self, item: _Held, step: GateStep) -> None:
        est = self._compare(self._key, item, step)
        if est.known and est.percent >= self.rth_percent:
            self._offer_candidate(item, est, step)
        elif est.known:
            self._warn_if_falling(item, est, step)
            self._low_overlap_keyframe(item, est, step)
        else:
            self._gap_keyframe(item, est, step)

    def _offer_candidate(self, item: _Held, est: OverlapEstimate, step: GateStep) -> None:
        item.estimate = est
        self._prev_R = est.R
        cand = self._cand
        if cand is not None and item.blurred and not cand.blurred:
            step.role = StepRole.REJECTED  # keep the sharper neighbour, which is still >= Rth
            return
        self._cand = item
        step.role = StepRole.CANDIDATE

    def _warn_if_falling(self, item: _Held, est: OverlapEstimate, step: GateStep) -> None:
        rth = self.rth_percent
        if step.overlap_warning:  # one warning per frame (the re-comparison after a promotion may repeat it)
            return
        if self._prev_R >= rth and est.percent < rth - 100.0 * self.config.warn_margin:
            step.events.append(
                GateEvent(
                    GateEventKind.OVERLAP_WARNING,
                    item.index,
                    f"overlap falling too fast: slow down (R {self._prev_R:.1f} % -> {est.R:.1f} % in one frame, "
                    f"threshold {rth:.0f} %)",
                    est.R,
                )
            )

    def _low_overlap_keyframe(self, item: _Held, est: OverlapEstimate, step: GateStep) -> None:
        step.events.append(
            GateEvent(
                GateEventKind.LOW_OVERLAP,
                item.index,
                f"frame {item.index} kept at R {est.R:.1f} % < {self.rth_percent:.0f} %"
                f"{'' if est.source == OverlapSource.IMAGE else ' (from telemetry)'}: no frame in between",
                est.R,
            )
        )
        item.estimate = est
        step.role = StepRole.KEYFRAME
        self._emit(item, step, overlap=est, gap=False, reason=GateReason.LOW_OVERLAP)

    def _gap_keyframe(self, item: _Held, est: OverlapEstimate, step: GateStep) -> None:
        step.events.append(
            GateEvent(
                GateEventKind.GAP,
                item.index,
                f"tracking lost at frame {item.index} ({est.status}): new segment, possible gap in the map",
            )
        )
        self._segment += 1
        item.estimate = est
        step.role = StepRole.KEYFRAME
        self._emit(item, step, overlap=None, gap=True, reason=GateReason.TRACKING_LOST)

    def _unusable(self, item: _Held, step: GateStep, why: str) -> None:
        """A frame the gate cannot measure. One whose ROI is next to nothing (the camera leaving the wall at a
        segment's end: too few features in a sliver) loses no wall, so a segment ending on it is no gap. Nor does
        one whose wall the keyframe shows, by the two poses' footprints on the mission's wall (``wall_unseen``):
        the judged 1280 px demo's exit climb past the roof line, its last frame of the scan showing a few
        centimetres of wall (all in the keyframe's view) under the roof, which the depth mask keeps as ROI (>= 3 %
        of the frame) and which holds too few features to measure. A frame showing wall no keyframe shows, or
        one without a fresh pose, still ends the segment with a gap."""
        self._unusable_since_key += 1
        roi = _small_mask(item.masked.mask) > 127
        if roi.size == 0 or float(roi.mean()) < self.config.min_last_roi:
            self._unusable_bare_since_key += 1
        elif self._wall_seen_by_key(item):
            self._unusable_seen_since_key += 1
        step.role = StepRole.UNUSABLE
        step.events.append(GateEvent(GateEventKind.UNUSABLE_FRAME, item.index, f"frame {item.index} skipped: {why}"))

    def _wall_seen_by_key(self, item: _Held) -> bool:
        """True when the poses say the keyframe shows all the wall this frame shows (less than
        ``min_last_new_roi`` of the frame unseen); False when they cannot tell."""
        key = self._key
        if self.wall_unseen is None or key is None:
            return False
        a, b = key.masked, item.masked
        if a.pose is None or b.pose is None or a.pose_stale or b.pose_stale:
            return False
        unseen = self.wall_unseen(b.pose, a.pose)
        return unseen is not None and unseen < self.config.min_last_new_roi

    def _promote(self, step: GateStep, reason: GateReason) -> None:
        cand, self._cand = self._cand, None
        self._emit(cand, step, overlap=cand.estimate, gap=False, reason=reason)

    def _predict(self, key: _Held, item: _Held) -> WallMotion | None:
        if self.predictor is None:
            return None
        a, b = key.masked, item.masked
        if a.pose_stale or b.pose_stale:
            return None
        w, h = item.features.full_size
        return self.predictor.predict(a.pose, b.pose, w, h)

    def _compare(self, key: _Held, item: _Held, step: GateStep) -> OverlapEstimate:
        est = self._looked_est.get((key.index, item.index))
        if est is not None:  # measured already; counted now that it decides
            self.telemetry_vetoes += int(est.source == OverlapSource.TELEMETRY_VETO)
            self.telemetry_fallbacks += int(est.source == OverlapSource.TELEMETRY)
        else:
            est = self._estimate(key, item, count=True)
        step.comparisons.append(Comparison(key.index, item.index, est))
        return est

    def _estimate(self, key: _Held, item: _Held, count: bool) -> OverlapEstimate:
        prior = self._predict(key, item)
        est = self._estimator.estimate(key.features, item.features, prior=prior)
        if est.matched_points is not None:  # handed on, not kept: estimates are held for later pushes and reports
            if self.on_matches is not None and prior is not None:
                self.on_matches(key.masked, item.masked, est.matched_points, item.features.full_size)
            est = replace(est, matched_points=None)
        if prior is not None:
            est = self._with_telemetry(est, prior)
            if count:
                self.telemetry_vetoes += int(est.source == OverlapSource.TELEMETRY_VETO)
                self.telemetry_fallbacks += int(est.source == OverlapSource.TELEMETRY)
        return est

    def _with_telemetry(self, est: OverlapEstimate, prior: WallMotion) -> OverlapEstimate:
        """The image decides where it measured the wall; the poses veto a pair they put below Rth - margin and
        decide alone where the image found no wall motion."""
        predicted = prior.overlap_percent
        floor = self.rth_percent - 100.0 * self.config.telemetry_margin
        if est.known:
            if est.percent >= self.rth_percent and predicted < floor:
                return replace(est, R=predicted, source=OverlapSource.TELEMETRY_VETO, R_image=est.R,
                               R_telemetry=predicted)
            return replace(est, R_telemetry=predicted)
        return replace(est, R=predicted, source=OverlapSource.TELEMETRY, R_telemetry=predicted)

    def _emit(self, item: _Held, step: GateStep, overlap: OverlapEstimate | None, gap: bool,
              reason: GateReason) -> None:
        est = overlap
        kf = Keyframe.of(
            item.masked,
            GateDecision(
                overlap_to_previous=None if est is None else est.R,
                inliers=0 if est is None else est.inliers,
                gap_before=gap,
                reason=reason,
                segment=self._segment,
                previous_index=None if self._key is None else self._key.index,
                frames_since_previous=0 if self._key is None else item.index - self._key.index,
                matches=0 if est is None else est.matches,
                dx_px=None if est is None else est.dx,
                dy_px=None if est is None else est.dy,
                R_displacement=None if est is None else est.R_displacement,
                R_polygon=None if est is None else est.R_polygon,
                sharpness=item.sharpness,
                low_overlap=est is not None and est.known and est.percent < self.rth_percent,
                overlap_source=None if est is None else est.source,
                R_image=None if est is None else (est.R_image if est.source != OverlapSource.IMAGE else est.R),
                R_telemetry=None if est is None else est.R_telemetry,
                prediction_miss_px=None if est is None else est.prediction_miss_px,
                background_matches_rejected=0 if est is None else est.rejected_matches,
            ),
        )
        self._key = item
        self._prev_R = 100.0
        self._unusable_since_key = self._unusable_bare_since_key = self._unusable_seen_since_key = 0
        self.keyframes_out += 1
        self._out.append(kf)
        step.keyframe_indices.append(item.index)
        step.events.append(
            GateEvent(GateEventKind.KEYFRAME, item.index, f"keyframe {item.index} ({reason})", kf.overlap_to_previous)
        )


def _small_mask(mask: np.ndarray, long_side_px: int = 320) -> np.ndarray:
    """A small copy of a 0/255 mask (shares and positions to a few tenths of a percent, at a few microseconds)."""
    h, w = mask.shape[:2]
    s = min(1.0, long_side_px / max(h, w))
    if s >= 1.0:
        return mask
    return cv2.resize(mask, (max(1, round(w * s)), max(1, round(h * s))), interpolation=cv2.INTER_AREA)

"""One frame through the whole chain: tag -> mask -> gate -> spool.

Kept synchronous and free of threads so the live runner (``runner.py``) and the offline ``companion cull`` use
exactly the same logic. What waits for a decision is ``PendingFrames``' (``pending.py``); what is counted and said
is ``ChainRecorder``'s (``chain_stats.py``): the chain decides, and tells them what happened.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import replace

import numpy as np

from companion.capture.tagging import FrameTagger
from companion.depth.masker import Masker
from companion.depth.parallax_first import first_look
from companion.errors import CompanionError
from companion.keyframes.gate import KeyframeGate
from companion.keyframes.gate_scope import ScanPhase, ScanScope, ScopeStep
from companion.onboard.chain_stats import (
    CORRUPT_NAMED,
    CaptureCounters,
    ChainRecorder,
    ChainStats,
    FrameDone,
    FrameFate,
    FrameStart,
    one_line,
)
from companion.onboard.crosscheck import OverlapCrossCheck
from companion.onboard.pending import PendingFrames
from companion.onboard.standoff_watch import StandoffWatch
from companion.onboard.tracked import MeasureSchedule, TrackedSelection
from companion.onboard.working import WorkingCopy
from companion.records import EncodedFrame, Frame, Keyframe, MaskedFrame, StandoffEstimate, TaggedFrame
from companion.spool import KeyframeSpool, SpoolEntry, SpoolFullError

# the statistics' names, where the chain's users have always found them
__all__ = ["CORRUPT_NAMED", "CaptureCounters", "ChainStats", "CullChain", "FOLLOW_STANDOFF_M", "one_line"]

log = logging.getLogger(__name__)


# the gate's wall-motion prediction follows the measured standoff once it is this far off (the flight's tolerance)
FOLLOW_STANDOFF_M = 0.3


class CullChain:
    """Frames before the first telemetry sample are not culled (``require_telemetry``): they cannot be placed on
    the map. After that, a frame whose pose is stale (telemetry gap) is kept and flagged, not dropped.

    ``scope`` (a ``ScanScope``): frames taken too far from the wall to belong to the scan are counted, not judged;
    the scan is the frames showing the wall from near the standoff, and leaving it ends the gate's segment
    (``companion.keyframes.gate_scope.ScanPhase``).

    ``track`` (a ``MeasureSchedule``, default its defaults): every frame is tracked cheaply and only the frames
    around each keyframe decision are masked and measured (``companion.onboard.tracked``).

    ``working``: each frame is resized once to this working copy, on which tagging, tracking, the depth mask and the
    gate all run, so the chain's cost per frame does not grow with the camera's resolution; keyframes are spooled
    with their full-resolution pixels (``companion.onboard.working``).

    ``standoff_watch`` (a ``StandoffWatch``): the camera-to-wall distance is measured from the pairs the gate
    matches; each spooled keyframe carries the estimate of its time, the stats its summary, and ``standoff`` is the
    current estimate for whoever supervises the flight (None: nothing measured in the last few seconds).
    """

    def __init__(
        self,
        tagger: FrameTagger,
        masker: Masker | None,
        gate: KeyframeGate,
        spool: KeyframeSpool,
        *,
        on_keyframe: Callable[[Keyframe, SpoolEntry], None] | None = None,
        on_warning: Callable[[str], None] | None = None,
        require_telemetry: bool = True,
        crosscheck: OverlapCrossCheck | None = None,
        track: MeasureSchedule | None = None,
        working: WorkingCopy | None = None,
        scope: ScanScope | None = None,
        standoff_watch: StandoffWatch | None = None,
    ):
        self.tagger = tagger
        self.working = working or WorkingCopy()
        self.masker = masker
        self.gate = gate
        self.spool = spool
        self.on_keyframe = on_keyframe
        self.record = ChainRecorder(on_warning or (lambda msg: log.warning(msg)), log)
        self.spool_disabled = False
        self.require_telemetry = require_telemetry
        self.crosscheck = crosscheck
        self.scope = scope
        self.standoff_watch = standoff_watch
        if standoff_watch is not None:
            gate.on_matches = standoff_watch.observe
            self.record.standoff(standoff_watch.summary())
        if crosscheck is not None and gate.predictor is None:
            gate.predictor = crosscheck.predictor  # the cross-check decides in the gate, it does not only flag
        self._last_key_pose = None
        self._seen_pose = False
        observe = masker.remember if masker is not None and masker.parallax is not None else None
        self.selection = TrackedSelection(gate, self._mask, gate.predictor, track or MeasureSchedule(), observe=observe)
        self.pending = PendingFrames((self.selection, gate), masker)

    @property
    def stats(self) -> ChainStats:
        return self.record.stats

    @property
    def scope(self) -> ScanScope | None:
        return self._scope

    @scope.setter
    def scope(self, scope: ScanScope | None) -> None:
        self._scope = scope
        self.phase = None if scope is None else ScanPhase(scope)
        # the gate tells a frame it cannot measure that shows only wall the keyframe shows (no gap) by the scope's wall
        self.gate.wall_unseen = None if scope is None else scope.wall_unseen

    @property
    def standoff(self) -> StandoffEstimate | None:
        """The camera-to-wall distance measured from the images, as of the last frame of the scan (None: none in
        the last few seconds, or not measured). The hook for a flight supervisor that corrects the distance."""
        return None if self.standoff_watch is None else self.standoff_watch.current

    @property
    def full_resolution_held(self) -> int:
        """Full-resolution frames kept because they may still become keyframes (the chain decides on copies)."""
        return self.pending.full_resolution_held

    def warn(self, message: str) -> None:
        self.record.warn(message)

    # -- one frame -------------------------------------------------------------------------------------------------
    def process(self, frame: Frame | EncodedFrame) -> list[SpoolEntry]:
        """One camera frame, decoded or still encoded as the camera sent it (decoded here at the working size).

        Tagging and the scan scope read the capture time only, so a frame that is not judged (before the first
        telemetry sample, off the scan) is never decoded: at 1280 px that is 5 ms of CPU each (issue 17)."""
        started = FrameStart.now()
        tagged = self.tagger.tag(frame)
        if self._before_telemetry(tagged):
            self.pending.release_decided(None)
            fate, out = FrameFate.BEFORE_TELEMETRY, []
        else:
            where = None if self.phase is None else self.phase.step(tagged.pose, tagged.pose_stale)
            if where is not None and not where.judged:
                fate, out = FrameFate.OFF_SCAN, self._off_scan(tagged, where)
            else:
                fate, out = self._judge(frame, tagged, where)
        self.record.frame(FrameDone(fate, tagged.pose_stale, started))
        return out

    def _before_telemetry(self, tagged: TaggedFrame) -> bool:
        """No pose yet, and none ever seen: the frame cannot be placed on the map, so it is not culled. Notes the
        first pose, after which a frame without one is judged (flagged stale, not dropped)."""
        if tagged.pose is None and not self._seen_pose and self.require_telemetry:
            return True
        self._seen_pose = self._seen_pose or tagged.pose is not None
        return False

    def _off_scan(self, tagged: TaggedFrame, where: ScopeStep) -> list[SpoolEntry]:
        """Take-off, transit, landing: not a frame of the scan, so the gate never judges it; the first one after
        the scan ends the segment."""
        out = self._end_segment() if where == ScopeStep.LEAVES else []
        self.pending.release_decided(tagged.index + 1)  # this one is never a keyframe
        return out

    def _judge(self, frame: Frame | EncodedFrame, tagged: TaggedFrame,
               where: ScopeStep | None) -> tuple[FrameFate, list[SpoolEntry]]:
        """A frame of the scan: skipped undecoded far above Rth, or decoded to its working copy and offered."""
        if where == ScopeStep.OPENS:
            self.record.scan_opened()
        self._watch_standoff(tagged.frame.capture_time_s)
        if self.selection.skips(tagged):
            self.pending.skip(frame, tagged)  # decoded only if it turns out to be the wall's last view
            self.record.tracking(self.selection.counts)
            return FrameFate.SKIPPED_FAR, []
        self.pending.forget_skipped()
        work = self.working.of(frame)
        if work is None:  # an encoded frame that is not an image: counted with the camera's corrupt frames
            return FrameFate.UNDECODABLE, []
        out = self._offer(frame, replace(tagged, frame=work))
        self.record.telemetry_vetoes(self.gate.telemetry_vetoes)  # read here only, as the report always has
        self.pending.release_decided(tagged.index)
        return FrameFate.OFFERED, out

    def _offer(self, frame: Frame | EncodedFrame, tagged: TaggedFrame) -> list[SpoolEntry]:
        """A frame decoded to its working copy (``tagged.frame``) offered to the tracked selection; the keyframes
        decided spooled as far as their order allows (``PendingFrames.spool_order``)."""
        self.pending.keep(frame, tagged.frame)
        keyframes = self.selection.offer(tagged)
        self.record.tracking(self.selection.counts)
        self.record.gate_events(self.gate.pop_events())
        return self._spool_in_order(keyframes, later=tagged)

    def _watch_standoff(self, time_s: float) -> None:
        """A frame of the scan: the standoff estimate at its time, and the warnings it calls for."""
        watch = self.standoff_watch
        if watch is None:
            return
        for message in watch.step(time_s):
            self.record.warn(message)
        self.record.standoff(watch.summary())
        self._follow_standoff(watch.current)

    def _follow_standoff(self, estimate: StandoffEstimate | None) -> None:
        """The wall's predicted image motion (gate, tracker, cross-check) at the MEASURED standoff once it is off
        the one predicted from by more than ``FOLLOW_STANDOFF_M`` (and three of its sigmas): flown 1.5 m nearer
        than planned, the wall moves 1.6x what the plan predicts, the gate finds no wall where the prediction
        looks and falls back to the telemetry's overlap at the wrong distance. Within the tolerance nothing
        changes (a flight on plan keeps exactly its keyframes)."""
        check = self.crosscheck
        if estimate is None or check is None or check.standoff_m is None:
            return
        if abs(estimate.distance_m - check.standoff_m) <= max(FOLLOW_STANDOFF_M, 3.0 * estimate.sigma_m):
            return
        log.info("predicting the wall's motion at the measured standoff %.2f m (was %.2f m)", estimate.distance_m,
                 check.standoff_m)
        shared = self.gate.predictor is check.predictor
        self.crosscheck = check = replace(check, standoff_m=round(estimate.distance_m, 3))
        if shared:
            self.gate.predictor = check.predictor
        if self.selection.predictor is not None:
            self.selection.predictor = check.predictor

    def _mask(self, tagged: TaggedFrame) -> MaskedFrame | None:
        """The depth mask stage (None: the frame holds no facade, counted)."""
        if self.masker is None:  # no depth model requested: the whole frame is ROI
            masked = MaskedFrame(tagged, np.full(tagged.image.shape[:2], 255, np.uint8))
            self.record.masked(masked, None)
            return masked
        look = first_look(self.masker, tagged)
        masked = look.masked
        if look.alone:
            self.pending.mark_alone(tagged.index)
        elif look.earlier is not None:
            self.pending.mark_one_sided(tagged.index, look.earlier)
        self.record.masked(masked, self.masker.stats)
        return masked

    # -- segment and stream ends -----------------------------------------------------------------------------
    def finish(self) -> list[SpoolEntry]:
        """End of stream: the gate's last candidate becomes a keyframe and the spool is marked CLOSED."""
        out = self._decide_held(self.gate.flush)
        self.pending.release_decided(None)
        self.record.gate_events(self.gate.pop_events())
        if self.standoff_watch is not None:
            self.record.standoff(self.standoff_watch.summary())
        if not self.spool_disabled:
            try:
                self.spool.close()
            except OSError as exc:
                self.record.warn(f"cannot mark the spool closed: {exc}")
        return out

    def _end_segment(self) -> list[SpoolEntry]:
        """The scan was left: the held frames are decided and the gate's segment ends with its last view (the same
        as the end of a stream); the next frame of the scan opens a new segment."""
        out = self._decide_held(self.gate.end_segment)
        self.record.gate_events(self.gate.pop_events())
        return out

    def _decide_held(self, end_gate: Callable[[], list[Keyframe]]) -> list[SpoolEntry]:
        """No later frame will come (the segment or the stream ends): the frame skipped last is offered, as the
        wall's last view, then every hold decides in turn (the tracked selection, the gate with ``end_gate``, the
        later-reference hold) and what they decide is spooled."""
        out = self._offer_skipped_last()
        out += self._spool_in_order(self.selection.finish(), later=None)
        out += self._spool_in_order(end_gate(), later=None)
        return out

    def _offer_skipped_last(self) -> list[SpoolEntry]:
        """The segment or the stream ends on a frame skipped far above Rth: it is the wall's last view, so it is
        decoded and offered now, as if it had not been skipped."""
        skipped = self.pending.take_skipped()
        if skipped is None:
            return []
        work = self.working.of(skipped.frame)
        if work is None:
            self.record.undecodable()
            return []
        return self._offer(skipped.frame, replace(skipped.tagged, frame=work))

    # -- spooling ----------------------------------------------------------------------------------------------
    def _spool_in_order(self, keyframes: list[Keyframe], later: TaggedFrame | None) -> list[SpoolEntry]:
        """Decided keyframes to the spool once no earlier one waits (``later``: the frame just offered, which may
        settle a held one; None: nothing comes after, every held one goes now)."""
        order = self.pending.spool_order(keyframes, later)
        self.record.judged_later(order.judged_later)
        return self._spool(list(order.keyframes))

    def _spool(self, keyframes: list[Keyframe]) -> list[SpoolEntry]:
        out = []
        for kf in keyframes:
            kf = self._as_spooled(kf)
            entry = self._append(kf)
            if entry is None:
                continue
            out.append(entry)
            if self.on_keyframe:
                self.on_keyframe(kf, entry)
        return out

    def _as_spooled(self, kf: Keyframe) -> Keyframe:
        """The keyframe as spooled: full resolution, cross-checked against the poses, the standoff of its time."""
        kf = self._cross_check(self.pending.restore(kf))
        if self.standoff_watch is not None:
            kf = replace(kf, standoff=self.standoff_watch.current)
        return kf

    def _cross_check(self, kf: Keyframe) -> Keyframe:
        """A new record flagged ``telemetry_overlap_suspect`` where the poses contradict the image's overlap."""
        pose = kf.pose
        predicted = None
        if self.crosscheck is not None and not kf.gap_before:
            predicted = self.crosscheck.suspect(
                kf.overlap_to_previous, self._last_key_pose, pose, self.gate.rth_percent
            )
            if predicted is not None:
                kf = replace(kf, telemetry_overlap_suspect=round(predicted, 2))
        self._last_key_pose = pose
        self.record.cross_checked(kf, predicted)
        return kf

    def _append(self, kf: Keyframe) -> SpoolEntry | None:
        """The keyframe written (None: not written now: the spool is full or refused it, or it holds it already)."""
        if self.spool_disabled:
            return None
        try:
            entry = self.spool.append(kf)
        except SpoolFullError as exc:
            self.spool_disabled = True
            self.record.spool_error(exc)
            return None
        except CompanionError as exc:
            self.record.spool_error(exc)
            return None
        self.record.spooled(entry is not None)
        return entry

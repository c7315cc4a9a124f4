"""One frame through the whole chain: tag -> mask -> gate -> spool, with counts and user-facing warnings.

Kept synchronous and free of threads so the live runner (``runner.py``) and the offline ``companion cull`` use
exactly the same logic.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from companion.capture.tagging import FrameTagger
from companion.depth.masker import Masker
from companion.depth.parallax_first import LaterReference, Resolved, masked_without_reference
from companion.errors import CompanionError
from companion.keyframes.gate import GateEventKind, KeyframeGate
from companion.keyframes.gate_scope import ScanPhase, ScanScope, ScopeStep
from companion.onboard.crosscheck import OverlapCrossCheck
from companion.onboard.standoff_watch import StandoffWatch
from companion.onboard.tracked import MeasureSchedule, TrackedSelection
from companion.onboard.working import FullResolution, WorkingCopy
from companion.records import EncodedFrame, Frame, Keyframe, MaskedFrame, OverlapSource, StandoffEstimate, TaggedFrame
from companion.spool import KeyframeSpool, SpoolEntry, SpoolFullError

log = logging.getLogger(__name__)


CORRUPT_NAMED = 100  # corrupt files named in the cull report (the count says how many there were)


@dataclass
class CaptureCounters:
    """Counted by the capture thread alone (``LiveRunner``, or the offline cull's single thread): the chain's worker
    never writes them, so no counter is incremented from two threads."""

    skipped_backlog: int = 0  # dropped before processing because the CPU could not keep up
    corrupt: int = 0
    corrupt_files: list[str] = field(default_factory=list)  # "NAME: why" for the corrupt files a source named


@dataclass
class ChainStats:
    """Written only by the thread that runs :meth:`CullChain.process`; the capture thread's counters are in
    ``capture`` and merged when read (``frames_in`` = processed + dropped from the backlog)."""

    frames_processed: int = 0
    capture: CaptureCounters = field(default_factory=CaptureCounters)
    stale_pose: int = 0
    before_telemetry: int = 0  # frames from before the first telemetry sample: not placeable, not culled
    off_scan: int = 0  # frames not of the scan (take-off, transit, landing: keyframes/gate_scope.py): not judged
    scan_segments: int = 0  # times the scan opened (1 on a planned flight; more: it was left and resumed)
    last_candidates_dropped: int = 0  # segments' last candidates not kept as keyframes: no wall to add
    dropped_no_roi: int = 0
    parallax_frames: int = 0  # masked frames whose mask motion parallax confirmed or corrected (docs/DEPTH.md)
    parallax_skipped_sure: int = 0  # masked frames the network read as wall everywhere: no flow spent on them
    # keyframes the network alone had masked (no reference before them: a scan's first) masked again against a
    # later frame before they were spooled (companion.depth.parallax_first), and of those, found all background
    # by that parallax (not spooled)
    keyframes_judged_later: int = 0
    keyframes_later_background: int = 0
    frames_tracked: int = 0  # followed by the wall tracker only (cheap); 0 without a tracker
    skipped_far: int = 0  # judged frames the telemetry and tracker put far above Rth: not decoded (tracked.py)
    frames_measured: int = 0  # depth mask + SIFT measurement (every processed frame without a tracker)
    keyframes: int = 0
    already_spooled: int = 0  # resumed run: keyframes found in the spool already
    overlap_warnings: int = 0
    low_overlap_keyframes: int = 0
    gaps: int = 0
    telemetry_disagrees: int = 0  # keyframes whose image overlap the poses contradict (flagged in the spool)
    telemetry_vetoes: int = 0  # frames the poses put below Rth - 3 points although the image said >= Rth
    telemetry_overlap_keyframes: int = 0  # keyframes whose overlap the poses gave (too little wall to measure)
    spool_errors: int = 0
    # the standoff measured from the images (companion.onboard.standoff_watch.StandoffWatch.summary); None: not
    # measured (no mission, so no wall to measure against)
    standoff: dict | None = None
    undecodable: int = 0  # frames that reached the chain still encoded and did not decode (part of ``corrupt``)
    busy_s: float = 0.0
    backlog_max_s: float = 0.0  # the furthest the chain worked behind the newest camera frame (capture time)
    cpu_s: float = 0.0  # CPU time of the thread running the chain (the depth model's own threads not included)
    first_frame_wall_s: float | None = None
    last_frame_wall_s: float | None = None
    warnings: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)  # decisions worth saying that need no action (dropped ends)

    @property
    def skipped_backlog(self) -> int:
        return self.capture.skipped_backlog

    @property
    def corrupt(self) -> int:
        return self.capture.corrupt + self.undecodable

    @property
    def frames_in(self) -> int:
        """Frames received: processed by the chain plus dropped from the backlog before it."""
        return self.frames_processed + self.capture.skipped_backlog

    def as_dict(self) -> dict:
        d = {"frames_in": self.frames_in, "skipped_backlog": self.skipped_backlog, "corrupt": self.corrupt,
             "corrupt_files": self.capture.corrupt_files[:CORRUPT_NAMED]}
        d.update({k: v for k, v in self.__dict__.items()
                  if k not in ("warnings", "notes", "capture", "undecodable")})
        span = (self.last_frame_wall_s or 0) - (self.first_frame_wall_s or 0)
        d["processed_fps"] = round(self.frames_processed / span, 3) if span > 0 else None
        d["warnings"] = self.warnings[-20:]
        d["notes"] = self.notes[-20:]
        return d


# the gate's wall-motion prediction follows the measured standoff once it is this far off (the flight's tolerance)
FOLLOW_STANDOFF_M = 0.3


def one_line(text: str) -> str:
    """A warning as one log line (an error's "problem / fix:" lines joined), so logs stay one record per line."""
    return "; ".join(part.strip() for part in str(text).splitlines() if part.strip())


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
        self._full = FullResolution()
        self.masker = masker
        self.gate = gate
        self.spool = spool
        self.on_keyframe = on_keyframe
        self.on_warning = on_warning or (lambda msg: log.warning(msg))
        self.stats = ChainStats()
        self.spool_disabled = False
        self.require_telemetry = require_telemetry
        self.crosscheck = crosscheck
        self.scope = scope
        self.standoff_watch = standoff_watch
        if standoff_watch is not None:
            gate.on_matches = standoff_watch.observe
            self.stats.standoff = standoff_watch.summary()
        if crosscheck is not None and gate.predictor is None:
            gate.predictor = crosscheck.predictor  # the cross-check decides in the gate, it does not only flag
        self._last_key_pose = None
        self._seen_pose = False
        self._skipped_last: tuple[Frame | EncodedFrame, TaggedFrame] | None = None
        observe = masker.remember if masker is not None and masker.parallax is not None else None
        # a keyframe the network alone masked waits here for a later frame's parallax before it is spooled
        self._later = None if observe is None else LaterReference(masker)
        self._alone: set[int] = set()  # frames masked by the network alone for want of a reference
        self.selection = TrackedSelection(gate, self._mask, gate.predictor, track or MeasureSchedule(), observe=observe)

    @property
    def scope(self) -> ScanScope | None:
        return self._scope

    @scope.setter
    def scope(self, scope: ScanScope | None) -> None:
        self._scope = scope
        self.phase = None if scope is None else ScanPhase(scope)

    @property
    def standoff(self) -> StandoffEstimate | None:
        """The camera-to-wall distance measured from the images, as of the last frame of the scan (None: none in
        the last few seconds, or not measured). The hook for a flight supervisor that corrects the distance."""
        return None if self.standoff_watch is None else self.standoff_watch.current

    @property
    def full_resolution_held(self) -> int:
        """Full-resolution frames kept because they may still become keyframes (the chain decides on copies)."""
        return len(self._full)

    def warn(self, message: str) -> None:
        message = one_line(message)
        self.stats.warnings.append(message)
        self.on_warning(message)

    def process(self, frame: Frame | EncodedFrame) -> list[SpoolEntry]:
        """One camera frame, decoded or still encoded as the camera sent it (decoded here at the working size)."""
        now, cpu0 = time.monotonic(), time.thread_time()
        st = self.stats
        # Tagging and the scan scope read the capture time only, so a frame that is not judged (before the first
        # telemetry sample, off the scan) is never decoded: at 1280 px that is 5 ms of CPU each (issue 17).
        tagged = self.tagger.tag(frame)
        if tagged.pose is None and not self._seen_pose and self.require_telemetry:
            self._count_processed(now)
            st.before_telemetry += 1
            self._full.release_below(None)
            return []
        self._seen_pose = self._seen_pose or tagged.pose is not None
        where = None if self.phase is None else self.phase.step(tagged.pose, tagged.pose_stale)
        if where is not None and not where.judged:
            self._count_processed(now)
            st.stale_pose += int(tagged.pose_stale)
            st.off_scan += 1  # take-off, transit, landing: not a frame of the scan, so the gate never judges it
            out = self._end_segment() if where == ScopeStep.LEAVES else []
            self._full.release_below(self._oldest_undecided(tagged.index + 1))  # this one is never a keyframe
            st.busy_s += time.monotonic() - now
            st.cpu_s += time.thread_time() - cpu0
            return out
        st.scan_segments += int(where == ScopeStep.OPENS)
        self._watch_standoff(tagged.frame.capture_time_s)
        if self.selection.skips(tagged):  # far above Rth: counted, not decoded
            self._count_processed(now)
            st.skipped_far = self.selection.counts.skipped_far
            self._skipped_last = (frame, tagged)  # decoded only if it turns out to be the wall's last view
            st.busy_s += time.monotonic() - now
            st.cpu_s += time.thread_time() - cpu0
            return []
        self._skipped_last = None
        work = self.working.of(frame)
        if work is None:  # an encoded frame that is not an image: counted with the camera's corrupt frames
            st.undecodable += 1
            st.cpu_s += time.thread_time() - cpu0
            return []
        self._count_processed(now)
        st.stale_pose += int(tagged.pose_stale)
        self._full.keep(frame, work)
        tagged = replace(tagged, frame=work)
        keyframes = self.selection.offer(tagged)
        st.frames_tracked = self.selection.counts.tracked
        st.telemetry_vetoes = self.gate.telemetry_vetoes
        self._events()
        out = self._spool(self._in_spool_order(keyframes, tagged))
        oldest = self._oldest_undecided(tagged.index)
        self._full.release_below(oldest)
        self._alone = {i for i in self._alone if i >= oldest}
        st.busy_s += time.monotonic() - now
        st.cpu_s += time.thread_time() - cpu0
        return out

    def _watch_standoff(self, time_s: float) -> None:
        """A frame of the scan: the standoff estimate at its time, and the warnings it calls for."""
        watch = self.standoff_watch
        if watch is None:
            return
        for message in watch.step(time_s):
            self.warn(message)
        self.stats.standoff = watch.summary()
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

    def _count_processed(self, now: float) -> None:
        st = self.stats
        st.first_frame_wall_s = st.first_frame_wall_s or now
        st.last_frame_wall_s = now
        st.frames_processed += 1

    def finish(self) -> list[SpoolEntry]:
        """End of stream: the gate's last candidate becomes a keyframe and the spool is marked CLOSED."""
        out = self._offer_skipped_last()
        out += self._spool(self._in_spool_order(self.selection.finish(), None))
        out += self._spool(self._in_spool_order(self.gate.flush(), None))
        self._full.release_below(None)
        self._events()
        if self.standoff_watch is not None:
            self.stats.standoff = self.standoff_watch.summary()
        if not self.spool_disabled:
            try:
                self.spool.close()
            except OSError as exc:
                self.warn(f"cannot mark the spool closed: {exc}")
        return out

    def _end_segment(self) -> list[SpoolEntry]:
        """The scan was left: the held frames are decided and the gate's segment ends with its last view (the same
        as the end of a stream); the next frame of the scan opens a new segment."""
        out = self._offer_skipped_last()
        out += self._spool(self._in_spool_order(self.selection.finish(), None))
        out += self._spool(self._in_spool_order(self.gate.end_segment(), None))
        self._events()
        return out

    def _offer_skipped_last(self) -> list[SpoolEntry]:
        """The segment or the stream ends on a frame skipped far above Rth: it is the wall's last view, so it is
        decoded and offered now, as if it had not been skipped."""
        pending, self._skipped_last = self._skipped_last, None
        if pending is None:
            return []
        frame, tagged = pending
        work = self.working.of(frame)
        if work is None:
            self.stats.undecodable += 1
            return []
        self._full.keep(frame, work)
        tagged = replace(tagged, frame=work)
        keyframes = self.selection.offer(tagged)
        self.stats.frames_tracked = self.selection.counts.tracked
        self._events()
        return self._spool(self._in_spool_order(keyframes, tagged))

    def _oldest_undecided(self, newest: int) -> int:
        """The oldest frame that may still become a keyframe: held for a decision, or the gate's candidate."""
        held = self.selection.held_indices()
        held += [] if self._later is None else self._later.held_indices()
        candidate = self.gate.candidate_index
        return min([newest, *held, *([] if candidate is None else [candidate])])

    def _mask(self, tagged: TaggedFrame) -> MaskedFrame | None:
        """The depth mask stage (None: the frame holds no facade, counted)."""
        self.stats.frames_measured += 1
        if self.masker is None:  # no depth model requested: the whole frame is ROI
            return MaskedFrame(tagged, np.full(tagged.image.shape[:2], 255, np.uint8))
        masked, alone = masked_without_reference(self.masker, tagged)
        if alone:
            self._alone.add(tagged.index)
        self.stats.dropped_no_roi += int(masked is None)
        self.stats.parallax_frames = self.masker.stats.parallax_frames
        self.stats.parallax_skipped_sure = self.masker.stats.parallax_skipped_sure
        return masked

    def _in_spool_order(self, keyframes: list[Keyframe], later: TaggedFrame | None) -> list[Keyframe]:
        """The keyframes to spool now, in capture order (issue 15: the first keyframe of a scan judged by the
        parallax of the frames after it).

        A keyframe the network alone masked (no frame far enough back: the scan's first, the first after the scan
        was left) is held until a later frame lies far enough along the baseline, then masked again against it with
        the parallax rules every other frame gets (``companion.depth.parallax_first``) and spooled. ``later``: this
        frame, which may resolve a held keyframe; None when no later frame will come (end of stream or of the scan
        segment), so a held keyframe is spooled now with the network's mask. A newer keyframe never overtakes a held
        one: it is released first (network mask), so the spool stays in capture order."""
        if self._later is None:
            return keyframes
        resolved = [] if later is None else self._later.offer(later)
        if keyframes or later is None:
            resolved += self._later.release()
        ready = [kf for kf in map(self._settled, resolved) if kf is not None]
        for n, kf in enumerate(keyframes):
            if later is not None and n == len(keyframes) - 1 and kf.index in self._alone:
                tagged = TaggedFrame(kf.frame, kf.pose, kf.pose_stale)
                self._later.hold(tagged, MaskedFrame(tagged, kf.mask), kf)
                ready += [k for k in map(self._settled, self._later.offer(later)) if k is not None]
            else:
                ready.append(kf)
        return ready

    def _settled(self, resolved: Resolved) -> Keyframe | None:
        """A held keyframe with the mask a later frame's parallax gave it (None: all background by that parallax,
        not spooled), or as it was when no later frame could judge it."""
        kf = resolved.item
        judgement = resolved.judgement
        if judgement is None:
            return kf
        self.stats.keyframes_judged_later += 1
        if judgement.masked is None:
            self.stats.keyframes_later_background += 1
            self.stats.notes.append(f"keyframe {kf.index} not spooled: the parallax against frame "
                                    f"{judgement.later_index} shows only background (the network alone kept it)")
            log.info(self.stats.notes[-1])
            return None
        return replace(kf, mask=judgement.masked.mask)

    def _cross_check(self, kf: Keyframe) -> Keyframe:
        """The keyframe as spooled: a new record flagged ``telemetry_overlap_suspect`` where the poses contradict
        the image's overlap."""
        pose = kf.pose
        if kf.decision.overlap_source in (OverlapSource.TELEMETRY, OverlapSource.TELEMETRY_VETO):
            self.stats.telemetry_overlap_keyframes += 1
        if self.crosscheck is not None and not kf.gap_before:
            predicted = self.crosscheck.suspect(
                kf.overlap_to_previous, self._last_key_pose, pose, self.gate.rth_percent
            )
            if predicted is not None:
                kf = replace(kf, telemetry_overlap_suspect=round(predicted, 2))
                self.stats.telemetry_disagrees += 1
                self.warn(
                    f"keyframe {kf.index}: the images say {kf.overlap_to_previous:.1f} % overlap "
                    f"but the telemetry says {predicted:.1f} %: possible gap (background in the mask?)"
                )
        self._last_key_pose = pose
        return kf

    def _events(self) -> None:
        for ev in self.gate.pop_events():
            if ev.kind == GateEventKind.OVERLAP_WARNING:
                self.stats.overlap_warnings += 1
                self.warn(f"overlap falling too fast at frame {ev.frame_index} ({ev.message}): slow down")
            elif ev.kind == GateEventKind.LOW_OVERLAP:
                self.stats.low_overlap_keyframes += 1
                self.warn(f"keyframe below the overlap target at frame {ev.frame_index}: {ev.message}")
            elif ev.kind == GateEventKind.GAP:
                self.stats.gaps += 1
                self.warn(f"possible gap in coverage at frame {ev.frame_index}: {ev.message}")
            elif ev.kind == GateEventKind.SEGMENT:
                self.warn(f"the scan was left and resumed at frame {ev.frame_index}: {ev.message}")
            elif ev.kind == GateEventKind.LAST_DROPPED:
                self.stats.last_candidates_dropped += 1
                self.stats.notes.append(one_line(ev.message))
                log.info(ev.message)
            elif ev.kind == GateEventKind.BARE_END:
                self.stats.notes.append(one_line(ev.message))
                log.info(ev.message)

    def _spool(self, keyframes: list[Keyframe]) -> list[SpoolEntry]:
        out = []
        for kf in keyframes:
            kf = self._cross_check(self._full.restore(kf))
            if self.standoff_watch is not None:
                kf = replace(kf, standoff=self.standoff_watch.current)
            if self.spool_disabled:
                continue
            try:
                entry = self.spool.append(kf)
            except SpoolFullError as exc:
                self.stats.spool_errors += 1
                self.spool_disabled = True
                self.warn(str(exc))  # flight supervision carries on; the error is reported, not raised
                continue
            except CompanionError as exc:
                self.stats.spool_errors += 1
                self.warn(str(exc))
                continue
            if entry is None:
                self.stats.already_spooled += 1
                continue
            self.stats.keyframes += 1
            out.append(entry)
            if self.on_keyframe:
                self.on_keyframe(kf, entry)
        return out

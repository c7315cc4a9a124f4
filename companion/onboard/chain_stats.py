"""What the onboard chain counts and says, kept apart from what it decides.

Why: ``CullChain`` decides which frames become keyframes; the cull report, the live summary and the user's warnings
are what it did, told afterwards. When the counters lived in the decision code every step read as half decision, half
bookkeeping, and a counter could not be checked without running the decision it sat in. So the chain calls a
``ChainRecorder`` once per step with what happened (a frame's fate, the masker's figures, the gate's events, a
later frame's verdict, a spool outcome) and the recorder alone writes ``ChainStats``, the warnings and the notes.
The recorder decides nothing: swapping it for one that records nothing leaves the keyframes as they are.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from enum import StrEnum

from companion.depth.masker import MaskerStats
from companion.keyframes.gate import GateEvent, GateEventKind
from companion.onboard.pending import LaterVerdict
from companion.onboard.tracked import TrackedCounts
from companion.records import Keyframe, MaskedFrame, OverlapSource

CORRUPT_NAMED = 100  # corrupt files named in the cull report (the count says how many there were)


def one_line(text: str) -> str:
    """A warning as one log line (an error's "problem / fix:" lines joined), so logs stay one record per line."""
    return "; ".join(part.strip() for part in str(text).splitlines() if part.strip())


@dataclass
class CaptureCounters:
    """Counted by the capture thread alone (``LiveRunner``, or the offline cull's single thread): the chain's worker
    never writes them, so no counter is incremented from two threads."""

    skipped_backlog: int = 0  # dropped before processing because the CPU could not keep up
    corrupt: int = 0
    corrupt_files: list[str] = field(default_factory=list)  # "NAME: why" for the corrupt files a source named


@dataclass
class ChainStats:
    """Written only by the thread that runs :meth:`CullChain.process` (through its ``ChainRecorder``); the capture
    thread's counters are in ``capture`` and merged when read (``frames_in`` = processed + dropped from the
    backlog)."""

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
    # masked frames the mission's wall bound cut (beyond a 4 m standoff: companion.depth.pose_bound), and of those,
    # frames it left nothing of (dropped as background)
    bound_cut: int = 0
    bound_dropped: int = 0
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


class FrameFate(StrEnum):
    """What ``CullChain.process`` made of one camera frame: which counters it joins and whose time it spent."""

    BEFORE_TELEMETRY = "before_telemetry"  # no pose yet: not placeable, not culled, never decoded
    OFF_SCAN = "off_scan"  # take-off, transit, landing: not judged, never decoded
    SKIPPED_FAR = "skipped_far"  # far above Rth: counted, not decoded (``TrackedSelection.skips``)
    UNDECODABLE = "undecodable"  # still encoded and not an image: one of the corrupt frames, not a processed one
    OFFERED = "offered"  # decoded to its working copy and offered to the tracked selection


# fates that count as processed frames / whose pose staleness is counted / whose wall time is the chain's busy time
# / whose CPU time is counted: the cull report's figures as they have always been defined
_PROCESSED = frozenset(FrameFate) - {FrameFate.UNDECODABLE}
_STALE_COUNTED = frozenset({FrameFate.OFF_SCAN, FrameFate.OFFERED})
_BUSY = frozenset(FrameFate) - {FrameFate.BEFORE_TELEMETRY, FrameFate.UNDECODABLE}
_CPU = frozenset(FrameFate) - {FrameFate.BEFORE_TELEMETRY}


@dataclass(frozen=True)
class FrameStart:
    """When the chain took a frame: the wall clock (``time.monotonic``) and the thread's CPU clock."""

    wall_s: float
    cpu_s: float

    @classmethod
    def now(cls) -> FrameStart:
        return cls(time.monotonic(), time.thread_time())


@dataclass(frozen=True)
class FrameDone:
    """One camera frame through ``CullChain.process``: its fate, whether its pose was stale, when it started."""

    fate: FrameFate
    pose_stale: bool
    started: FrameStart


class ChainRecorder:
    """Writes ``stats``, the warnings and the notes from what the chain reports, one call per step of a frame.

    ``on_warning``: each warning as one line, as it is given (the user's log, a flight supervisor's console);
    ``log``: where notes (decisions that need no action) are logged, the chain's logger.
    """

    def __init__(self, on_warning: Callable[[str], None], log: logging.Logger):
        self.stats = ChainStats()
        self.on_warning = on_warning
        self.log = log

    def warn(self, message: str) -> None:
        message = one_line(message)
        self.stats.warnings.append(message)
        self.on_warning(message)

    def note(self, message: str) -> None:
        self.stats.notes.append(one_line(message))
        self.log.info(message)

    def frame(self, done: FrameDone) -> None:
        """A frame left ``CullChain.process``: the frame counters and the chain's busy and CPU time."""
        st, fate = self.stats, done.fate
        if fate in _PROCESSED:
            st.first_frame_wall_s = st.first_frame_wall_s or done.started.wall_s
            st.last_frame_wall_s = done.started.wall_s
            st.frames_processed += 1
        st.stale_pose += int(fate in _STALE_COUNTED and done.pose_stale)
        st.before_telemetry += int(fate == FrameFate.BEFORE_TELEMETRY)
        st.off_scan += int(fate == FrameFate.OFF_SCAN)
        st.undecodable += int(fate == FrameFate.UNDECODABLE)
        if fate in _BUSY:
            st.busy_s += time.monotonic() - done.started.wall_s
        if fate in _CPU:
            st.cpu_s += time.thread_time() - done.started.cpu_s

    def undecodable(self) -> None:
        """A frame held undecoded (skipped far above Rth) turned out to be needed and did not decode."""
        self.stats.undecodable += 1

    def scan_opened(self) -> None:
        self.stats.scan_segments += 1

    def tracking(self, counts: TrackedCounts) -> None:
        """The tracked selection's figures, after it skipped or was offered a frame."""
        self.stats.frames_tracked = counts.tracked
        self.stats.skipped_far = counts.skipped_far

    def telemetry_vetoes(self, vetoes: int) -> None:
        """The gate's count of pairs the poses overruled, after a frame of the scan was offered."""
        self.stats.telemetry_vetoes = vetoes

    def masked(self, masked: MaskedFrame | None, masker: MaskerStats | None) -> None:
        """A frame measured: masked by the depth model (``masker``: its figures so far), or whole (None)."""
        st = self.stats
        st.frames_measured += 1
        st.dropped_no_roi += int(masked is None)
        if masker is not None:
            st.parallax_frames = masker.parallax_frames
            st.parallax_skipped_sure = masker.parallax_skipped_sure
            st.bound_cut = masker.bound_cut
            st.bound_dropped = masker.bound_dropped

    def judged_later(self, verdicts: Iterable[LaterVerdict]) -> None:
        """Held keyframes masked again against a later frame (``PendingFrames.spool_order``); a background one is
        not spooled, and said."""
        for verdict in verdicts:
            self.stats.keyframes_judged_later += 1
            if verdict.background:
                self.stats.keyframes_later_background += 1
                self.note(f"keyframe {verdict.index} not spooled: the parallax against frame {verdict.later_index} "
                          "shows only background (the network alone kept it)")

    def gate_events(self, events: Iterable[GateEvent]) -> None:
        """The gate's events since the last call: warnings for the pilot, notes for decisions needing no action."""
        st = self.stats
        for ev in events:
            if ev.kind == GateEventKind.OVERLAP_WARNING:
                st.overlap_warnings += 1
                self.warn(f"overlap falling too fast at frame {ev.frame_index} ({ev.message}): slow down")
            elif ev.kind == GateEventKind.LOW_OVERLAP:
                st.low_overlap_keyframes += 1
                self.warn(f"keyframe below the overlap target at frame {ev.frame_index}: {ev.message}")
            elif ev.kind == GateEventKind.GAP:
                st.gaps += 1
                self.warn(f"possible gap in coverage at frame {ev.frame_index}: {ev.message}")
            elif ev.kind == GateEventKind.SEGMENT:
                self.warn(f"the scan was left and resumed at frame {ev.frame_index}: {ev.message}")
            elif ev.kind == GateEventKind.LAST_DROPPED:
                st.last_candidates_dropped += 1
                self.note(ev.message)
            elif ev.kind == GateEventKind.BARE_END:
                self.note(ev.message)

    def standoff(self, summary: dict) -> None:
        self.stats.standoff = summary

    def cross_checked(self, kf: Keyframe, predicted: float | None) -> None:
        """A keyframe about to be spooled: whose overlap the poses gave, and whether they contradict the image's
        (``predicted``: the poses' overlap where they do)."""
        if kf.decision.overlap_source in (OverlapSource.TELEMETRY, OverlapSource.TELEMETRY_VETO):
            self.stats.telemetry_overlap_keyframes += 1
        if predicted is not None:
            self.stats.telemetry_disagrees += 1
            self.warn(f"keyframe {kf.index}: the images say {kf.overlap_to_previous:.1f} % overlap "
                      f"but the telemetry says {predicted:.1f} %: possible gap (background in the mask?)")

    def spool_error(self, exc: Exception) -> None:
        """The spool refused a keyframe: reported, never raised (flight supervision carries on)."""
        self.stats.spool_errors += 1
        self.warn(str(exc))

    def spooled(self, new: bool) -> None:
        """A keyframe appended (``new``), or found in the spool already (a resumed run)."""
        if new:
            self.stats.keyframes += 1
        else:
            self.stats.already_spooled += 1

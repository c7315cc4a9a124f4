"""A recorded source (video file, image folder) used as the live camera of a flight, paced on the autopilot clock.

A recording's frames all exist before the flight starts. Read as fast as the disk allows they reach the tagger
before the first telemetry sample, cannot be placed, and the flight ends with no keyframe. Paced, each frame is
released only once the flight's telemetry has reached its capture time, as a camera on the drone would deliver
it: the tagger can interpolate its pose, and the chain sees the frames at the rate they were taken.

The frames' capture times (``times.csv``, the video's own timestamps, or index / fps) are read as seconds on the
autopilot clock (time since boot, as MAVLink time_boot_ms), plus ``offset_s``, the same convention as
``companion cull --time-offset``. Times that can never be reached are refused with an error naming the spans.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Iterator

from companion.capture.sources import FrameSource, ImageFolderSource
from companion.capture.telemetry import TelemetryBuffer
from companion.errors import CompanionError
from companion.records import Frame

log = logging.getLogger(__name__)

MAX_BOOT_TIME_S = 2**32 / 1000.0  # time_boot_ms is a uint32: about 49.7 days after boot
RECORDED_TIME_FIX = (
    "a recorded capture is paced on the autopilot clock: give its frames' times in seconds since the autopilot "
    "booted, inside the flight (an image folder's times.csv: 'name,seconds' per image, or a video whose time 0 is "
    "the autopilot's boot); cull a recording of another flight afterwards with `companion cull` and that "
    "flight's telemetry log instead"
)


def check_recorded_times(source: FrameSource, offset_s: float = 0.0) -> None:
    """Refuse, before the flight, a recording whose times cannot be on the autopilot clock at all."""
    span = source.time_span()
    if span is None:
        return
    first, last = span[0] + offset_s, span[1] + offset_s
    if last < 0.0:
        raise CompanionError(f"recorded capture {source.name}: its frame times (t = {first:.2f} .. {last:.2f} s) are "
                             "all before the autopilot booted (negative)", RECORDED_TIME_FIX)
    if first > MAX_BOOT_TIME_S:
        raise CompanionError(f"recorded capture {source.name}: its frame times start at t = {first:.0f} s, beyond any "
                             f"autopilot boot time ({MAX_BOOT_TIME_S:.0f} s, 49.7 days): wall-clock (Unix) times?",
                             RECORDED_TIME_FIX)


class AutopilotPacedSource(FrameSource):
    """Releases each frame of ``recording`` once ``telemetry`` has a sample at or after its time.

    ``finish()`` says the flight is over and its telemetry is all in: the frames it reached are released, later
    ones are counted and reported (``stats.notes``), and the iteration ends. ``close()`` ends it at once.
    """

    def __init__(self, recording: FrameSource, telemetry: TelemetryBuffer, *, offset_s: float = 0.0,
                 poll_s: float = 0.02):
        super().__init__()
        self.recording = recording
        self.telemetry = telemetry
        self.offset_s = offset_s
        self.poll_s = poll_s
        self.name = recording.name
        self.unreached = 0
        self._finished = threading.Event()
        self._closed = threading.Event()
        self._lock = threading.Lock()
        self._iterating = False
        self._checked_start = False

    def finish(self) -> None:
        self._finished.set()

    def close(self) -> None:
        self._closed.set()
        with self._lock:
            if not self._iterating:
                self.recording.close()  # else the iterating thread closes it when it leaves

    def _check_start(self, first_telemetry_s: float) -> None:
        """At the first telemetry sample: a recording that ends before it can never be placed."""
        self._checked_start = True
        span = self.recording.time_span()
        if span is not None and span[1] + self.offset_s < first_telemetry_s:
            raise CompanionError(
                f"recorded capture {self.name}: all its frames (t = {span[0] + self.offset_s:.2f} .. "
                f"{span[1] + self.offset_s:.2f} s) are older than the flight's first telemetry sample "
                f"(t = {first_telemetry_s:.2f} s on the autopilot clock): none can be placed",
                RECORDED_TIME_FIX,
            )

    def _wait_for(self, t: float) -> bool:
        """True once the telemetry reaches ``t``; False when the flight ended (or we were closed) first."""
        while not self._closed.is_set():
            first = self.telemetry.first_time_s
            if first is not None and not self._checked_start:
                self._check_start(first)
            newest = self.telemetry.newest_time_s
            if newest is not None and newest >= t:
                return True
            if self._finished.is_set():
                return False
            self._closed.wait(self.poll_s)
        return False

    def __iter__(self) -> Iterator[Frame]:
        with self._lock:
            if self._closed.is_set():
                return
            self._iterating = True
        last_t: float | None = None
        frames = iter(self.recording)
        try:
            for frame in frames:
                t = frame.capture_time_s + self.offset_s
                if not self._wait_for(t):
                    self._report_unreached(t)
                    return
                last_t = t
                self.stats.delivered += 1
                yield Frame(index=frame.index, capture_time_s=t, image=frame.image)
            self.stats.ended = (f"recording {self.name} ended after {self.stats.delivered} frames"
                                + (f" at t = {last_t:.2f} s on the autopilot clock" if last_t is not None else ""))
            if not self._finished.is_set():
                self.stats.notes.append(f"{self.stats.ended}, before the flight did: no more keyframes; flight "
                                        "supervision continues")
        finally:
            self.stats.corrupt = self.recording.stats.corrupt
            with self._lock:
                self._iterating = False
                self.recording.close()

    def _report_unreached(self, t: float) -> None:
        if self._closed.is_set():
            self.stats.ended = f"recording {self.name} closed after {self.stats.delivered} frames"
            return
        span = self.recording.time_span()
        last = t if span is None else max(t, span[1] + self.offset_s)
        left = _frames_from(self.recording, t - self.offset_s)
        self.unreached = left or 1
        newest = self.telemetry.newest_time_s
        reached = "no telemetry" if newest is None else f"its last telemetry sample is at t = {newest:.2f} s"
        self.stats.ended = f"the flight ended ({reached}) before recording {self.name} did"
        self.stats.notes.append(f"{left or 'the'} frames of recording {self.name} from t = {t:.2f} to {last:.2f} s "
                                f"(autopilot clock) come after the flight's telemetry ({reached}): not culled")


def _frames_from(recording: FrameSource, t_s: float) -> int | None:
    """How many frames of a recording are at or after ``t_s`` (its own clock), without decoding them."""
    if isinstance(recording, ImageFolderSource):
        return sum(1 for i, p in enumerate(recording.files) if recording.time_of(i, p) >= t_s)
    span = recording.time_span()
    fps = getattr(recording, "fps", 0.0)
    if span is None or not fps:
        return None
    return max(1, round((span[1] - t_s) * fps) + 1)

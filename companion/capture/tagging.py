"""Tagging stage: Frame -> TaggedFrame with the pose at its capture time (or flagged stale)."""

from __future__ import annotations

import logging

from companion.capture.telemetry import ClockMap, TelemetryBuffer
from companion.records import EncodedFrame, Frame, TaggedFrame

log = logging.getLogger(__name__)


class FrameTagger:
    """Also keeps the span of frame times it saw on the autopilot clock, so a run that placed no frame can say how
    the frames' times and the telemetry's missed each other.

    ``wait_for_telemetry_s`` (live telemetry only): how long a frame newer than the newest sample waits for the
    sample after its capture time, so its pose is interpolated, not the last one held (``TelemetryBuffer.wait_for``).
    Once a wait runs out, no frame waits again until a new sample arrives: a silent link costs one wait, not one per
    frame. 0: never wait (a recorded flight: the buffer already holds all the telemetry there is)."""

    def __init__(self, buffer: TelemetryBuffer, clock: ClockMap, *, wait_for_telemetry_s: float = 0.0):
        self.buffer = buffer
        self.clock = clock
        self.wait_for_telemetry_s = wait_for_telemetry_s
        self._waited_in_vain_at: float | None = None  # the newest sample when a wait last ran out
        self.stale_count = 0
        self.earliest_frame_s: float | None = None  # autopilot clock
        self.latest_frame_s: float | None = None

    def tag(self, frame: Frame | EncodedFrame) -> TaggedFrame:
        """Reads the frame's index and capture time only (an encoded frame is tagged before it is decoded)."""
        t = self.clock.to_autopilot(frame.capture_time_s)
        if t is None:
            self.stale_count += 1
            return TaggedFrame(frame, None, pose_stale=True)
        self.earliest_frame_s = t if self.earliest_frame_s is None else min(self.earliest_frame_s, t)
        self.latest_frame_s = t if self.latest_frame_s is None else max(self.latest_frame_s, t)
        self._wait_for_telemetry(t)
        result = self.buffer.pose_at(t)
        if result.stale:
            self.stale_count += 1
            if self.stale_count in (1, 10, 100) or self.stale_count % 1000 == 0:
                log.warning(
                    "frame %d: pose not used (%s); %d stale so far", frame.index, result.reason, self.stale_count
                )
        return TaggedFrame(frame, result.pose, pose_stale=result.stale)

    def _wait_for_telemetry(self, t: float) -> None:
        newest = self.buffer.newest_time_s
        if self.wait_for_telemetry_s <= 0 or newest is None or newest >= t or newest == self._waited_in_vain_at:
            return
        if not self.buffer.wait_for(t, self.wait_for_telemetry_s):
            self._waited_in_vain_at = self.buffer.newest_time_s

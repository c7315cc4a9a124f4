"""Runs the chain concurrently with capture: a capture thread feeds a bounded buffer, a worker thread drains it.

When the worker cannot keep up, frames wait; past the buffer's bounds (``Backlog``) a waiting frame is dropped
(counted as skipped): waiting frames have not reached the gate yet, so a frame the gate already chose as keyframe
can never be dropped. Which one: the OLDEST (the freshest are kept), or, with ``drop="thin"`` (the chain's
backlog: it works in bursts while it measures), the one whose neighbours are closest
in capture time, so what waits stays evenly spread over the time the worker was busy: a burst costs frames here
and there, never a stretch of the wall.

Why the tracker chain's buffer is deep (a minute of camera time, ``TRACKED_BACKLOG``): its CPU comes in bursts
(two measurements per keyframe, about half a second of CPU) and, on a machine whose other work takes a core, it
needs somewhat more than it gets for the length of a scan. With a one-second buffer it then thinned the frames to
six per second, and the gaps that left around decisions made keyframes below the overlap target. Waiting frames
are the camera's JPEGs (a 1280 px frame is about 0.1-0.2 MB), so a minute of them is affordable; the chain then
works behind the camera for a while, loses no frame, and catches up when the scan ends (the live scan waits for
it before writing its report).
Only a backlog that keeps growing past the minute is thinned.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from dataclasses import dataclass

from companion.capture.sources import FrameSource
from companion.onboard.chain import CullChain
from companion.onboard.chain_stats import one_line
from companion.records import EncodedFrame, Frame

log = logging.getLogger(__name__)
_END = object()


@dataclass(frozen=True)
class Backlog:
    """How much may wait between the camera and the chain: at most ``frames`` frames, ``megabytes`` of image data
    and ``seconds`` of capture time from the oldest waiting frame to the newest; past any of them a frame is dropped
    (``drop``: "oldest" or "thin")."""

    frames: int
    drop: str = "oldest"
    megabytes: float | None = None
    seconds: float | None = None

    def __post_init__(self) -> None:
        positive = all(v is None or v > 0 for v in (self.megabytes, self.seconds))
        if self.frames < 1 or self.drop not in ("oldest", "thin") or not positive:
            raise ValueError(f"bad frame backlog {self}: frames >= 1, drop 'oldest' or 'thin', megabytes and "
                             "seconds > 0 or None")


# The tracker chain's backlog: a minute of a 30 fps camera, within 512 MB (decoded frames from a video device are
# bigger than JPEGs: then the megabytes bound it) and the telemetry the chain keeps (``live.run_live_scan`` sizes
# its telemetry buffer for this backlog).
TRACKED_BACKLOG = Backlog(frames=1800, drop="thin", megabytes=512.0, seconds=60.0)


def _nbytes(frame: Frame | EncodedFrame) -> int:
    return len(frame.data) if isinstance(frame, EncodedFrame) else int(frame.image.nbytes)


class FrameBuffer:
    """Bounded, blocking buffer of frames between capture and the chain; ``put`` returns the frames it dropped.
    ``get`` also says how far behind the newest frame put the returned one is (seconds of capture time)."""

    def __init__(self, limits: Backlog):
        self.limits = limits
        self._items: deque = deque()
        self._bytes = 0
        self._newest_time_s: float | None = None
        self._ready = threading.Condition()

    def __len__(self) -> int:
        return len(self._items)

    def put(self, frame: Frame | EncodedFrame) -> list[Frame | EncodedFrame]:
        with self._ready:
            self._items.append(frame)
            self._bytes += _nbytes(frame)
            self._newest_time_s = frame.capture_time_s
            dropped = []
            while len(self._items) > 1 and self._over_count():
                dropped.append(self._drop())
            if not dropped and self._over_span():
                dropped.append(self._drop())
            self._ready.notify()
            return dropped

    def put_end(self) -> None:
        """The end-of-stream marker: always fits, after every frame."""
        with self._ready:
            self._items.append(_END)
            self._ready.notify()

    def get(self) -> tuple[object, float]:
        """(next frame or the end marker, its lag behind the newest frame put, in seconds)."""
        with self._ready:
            while not self._items:
                self._ready.wait()
            item = self._items.popleft()
            if item is _END:
                return item, 0.0
            self._bytes -= _nbytes(item)
            newest = item.capture_time_s if self._newest_time_s is None else self._newest_time_s
            return item, max(0.0, newest - item.capture_time_s)

    def waiting(self) -> tuple[int, float]:
        """(frames waiting, seconds of capture time they span)."""
        with self._ready:
            frames = [f for f in self._items if f is not _END]
            span = frames[-1].capture_time_s - frames[0].capture_time_s if len(frames) > 1 else 0.0
            return len(frames), span

    def _over_count(self) -> bool:
        lim = self.limits
        return len(self._items) > lim.frames or (lim.megabytes is not None and self._bytes > lim.megabytes * 1e6)

    def _over_span(self) -> bool:
        """The waiting frames span more capture time than ``seconds``. One frame is dropped per arrival while so:
        thinning keeps the oldest and the newest, so it cannot shorten the span itself, but the worker then crosses
        the waiting time in fewer frames and the span shrinks as it catches up."""
        items, seconds = self._items, self.limits.seconds
        if seconds is None or len(items) < 3 or items[0] is _END or items[-1] is _END:
            return False
        return items[-1].capture_time_s - items[0].capture_time_s > seconds

    def _drop(self) -> Frame | EncodedFrame:
        victim = self._victim()
        self._bytes -= _nbytes(victim)
        return victim

    def _victim(self) -> Frame | EncodedFrame:
        items = self._items
        if self.limits.drop == "oldest" or len(items) < 3 or any(i is _END for i in items):
            return items.popleft()
        times = [f.capture_time_s for f in items]
        k = min(range(1, len(items) - 1), key=lambda j: times[j + 1] - times[j - 1])  # the oldest and newest stay
        victim = items[k]
        del items[k]
        return victim


class LiveRunner:
    def __init__(self, source: FrameSource, chain: CullChain, backlog: Backlog = TRACKED_BACKLOG):
        self.source = source
        self.chain = chain
        self.queue = FrameBuffer(backlog)
        self.stop_event = threading.Event()
        self.error: BaseException | None = None
        self._capture = threading.Thread(target=self._capture_loop, name="capture", daemon=True)
        self._worker = threading.Thread(target=self._work_loop, name="cull", daemon=True)

    def start(self) -> LiveRunner:
        self._capture.start()
        self._worker.start()
        return self

    def stop(self) -> None:
        """Stop capturing; the worker drains what is queued, then flushes the gate."""
        self.stop_event.set()

    def join(self, timeout: float | None = None) -> bool:
        self._capture.join(timeout)
        self._worker.join(timeout)
        return not self._worker.is_alive()

    def _put(self, frame: Frame | EncodedFrame) -> None:
        dropped = self.queue.put(frame)
        if dropped:  # counted by this (capture) thread only
            self.chain.stats.capture.skipped_backlog += len(dropped)

    def _capture_loop(self) -> None:
        try:
            for frame in self.source:
                if self.stop_event.is_set():
                    break
                self._put(frame)
            stats = self.source.stats
            for note in stats.notes:
                self.chain.warn(note)
            if stats.ended is not None:
                log.info("%s", stats.ended)  # a recording reached its end: not a camera fault
            elif not self.stop_event.is_set():
                self.chain.warn(
                    f"camera {self.source.name} stopped delivering frames after {stats.delivered} "
                    f"({stats.stalls} stall(s), {stats.corrupt} corrupt): no more keyframes; flight supervision "
                    "continues"
                )
        except BaseException as exc:  # reported by the caller; the worker still flushes
            self.error = exc
            log.error("capture stopped: %s", one_line(exc))
            self.chain.warn(f"camera {self.source.name} failed: {exc}")
        finally:
            self.chain.stats.capture.corrupt = self.source.stats.corrupt
            self.chain.stats.capture.corrupt_files = list(self.source.stats.corrupt_files)
            self.queue.put_end()

    def _work_loop(self) -> None:
        try:
            while True:
                item, lag_s = self.queue.get()
                if item is _END:
                    break
                assert isinstance(item, Frame | EncodedFrame)
                stats = self.chain.stats
                stats.backlog_max_s = max(stats.backlog_max_s, lag_s)
                self.chain.process(item)
            self.chain.finish()
        except BaseException as exc:
            self.error = self.error or exc
            log.exception("onboard chain failed")

    def wait_for_chain(self, limit_s: float, log_every_s: float = 10.0) -> bool:
        """After ``stop``: wait (at most ``limit_s``) while the worker catches up on what waits, saying how much is
        left every ``log_every_s``. True once the worker has finished."""
        deadline = time.monotonic() + limit_s
        while self._worker.is_alive() and time.monotonic() < deadline:
            self._worker.join(min(log_every_s, max(0.0, deadline - time.monotonic())))
            if self._worker.is_alive():
                frames, span = self.queue.waiting()
                log.info("onboard chain catching up: %d frame(s) waiting, %.1f s of camera time", frames, span)
        return not self._worker.is_alive()

    def run_until_done(self, poll_s: float = 0.2) -> None:
        """Blocking helper for offline use."""
        self.start()
        while self._worker.is_alive():
            time.sleep(poll_s)

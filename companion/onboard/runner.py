"""Runs the chain concurrently with capture: a capture thread feeds a bounded buffer, a worker thread drains it.

When the worker cannot keep up, a waiting frame is dropped (counted as skipped): waiting frames have not reached
the gate yet, so a frame the gate already chose as keyframe can never be dropped. Which one: the OLDEST (a chain
that measures every frame keeps the freshest), or, with ``drop="thin"`` (the tracker chain, which works in
bursts while it measures), the one whose neighbours are closest in capture time, so what waits stays evenly spread
over the time the worker was busy: a burst costs frames here and there, never a stretch of the wall.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque

from companion.capture.sources import FrameSource
from companion.onboard.chain import CullChain, one_line
from companion.records import EncodedFrame, Frame

log = logging.getLogger(__name__)
_END = object()


class FrameBuffer:
    """Bounded, blocking buffer of frames between capture and the chain; ``put`` returns the frame it dropped."""

    def __init__(self, size: int, drop: str = "oldest"):
        if size < 1 or drop not in ("oldest", "thin"):
            raise ValueError(f"bad frame buffer: size={size}, drop={drop!r} (size >= 1, drop 'oldest' or 'thin')")
        self.size, self.drop = size, drop
        self._items: deque = deque()
        self._ready = threading.Condition()

    def __len__(self) -> int:
        return len(self._items)

    def put(self, frame: Frame | EncodedFrame) -> Frame | EncodedFrame | None:
        with self._ready:
            self._items.append(frame)
            dropped = self._victim() if len(self._items) > self.size else None
            self._ready.notify()
            return dropped

    def put_end(self) -> None:
        """The end-of-stream marker: always fits, after every frame."""
        with self._ready:
            self._items.append(_END)
            self._ready.notify()

    def get(self):
        with self._ready:
            while not self._items:
                self._ready.wait()
            return self._items.popleft()

    def _victim(self) -> Frame | EncodedFrame:
        items = self._items
        if self.drop == "oldest" or len(items) < 3 or any(i is _END for i in items):
            return items.popleft()
        times = [f.capture_time_s for f in items]
        k = min(range(1, len(items) - 1), key=lambda j: times[j + 1] - times[j - 1])  # the oldest and newest stay
        victim = items[k]
        del items[k]
        return victim


class LiveRunner:
    def __init__(self, source: FrameSource, chain: CullChain, *, queue_size: int = 3, drop: str = "oldest"):
        self.source = source
        self.chain = chain
        self.queue = FrameBuffer(queue_size, drop)
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
        if self.queue.put(frame) is not None:  # counted by this (capture) thread only
            self.chain.stats.capture.skipped_backlog += 1

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
            self.queue.put_end()

    def _work_loop(self) -> None:
        try:
            while True:
                item = self.queue.get()
                if item is _END:
                    break
                assert isinstance(item, Frame | EncodedFrame)
                self.chain.process(item)
            self.chain.finish()
        except BaseException as exc:
            self.error = self.error or exc
            log.exception("onboard chain failed")

    def run_until_done(self, poll_s: float = 0.2) -> None:
        """Blocking helper for offline use."""
        self.start()
        while self._worker.is_alive():
            time.sleep(poll_s)

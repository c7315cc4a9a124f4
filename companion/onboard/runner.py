"""Runs the chain concurrently with capture: a capture thread feeds a bounded queue, a worker thread drains it.

When the worker cannot keep up, the OLDEST waiting frame is dropped (counted as skipped): waiting frames have
not reached the gate yet, so a frame the gate already chose as keyframe can never be dropped, and the freshest
frames, which the gate needs to track the motion, are kept.
"""

from __future__ import annotations

import logging
import queue
import threading
import time

from companion.capture.sources import FrameSource
from companion.onboard.chain import CullChain, one_line
from companion.records import Frame

log = logging.getLogger(__name__)
_END = object()


class LiveRunner:
    def __init__(self, source: FrameSource, chain: CullChain, *, queue_size: int = 3):
        self.source = source
        self.chain = chain
        self.queue: queue.Queue = queue.Queue(maxsize=queue_size)
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

    def _put(self, item: object) -> None:
        while True:
            try:
                self.queue.put_nowait(item)
                return
            except queue.Full:
                try:
                    dropped = self.queue.get_nowait()
                    if dropped is not _END:  # counted by this (capture) thread only
                        self.chain.stats.capture.skipped_backlog += 1
                except queue.Empty:
                    pass

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
            self.queue.put(_END)

    def _work_loop(self) -> None:
        try:
            while True:
                item = self.queue.get()
                if item is _END:
                    break
                assert isinstance(item, Frame)
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

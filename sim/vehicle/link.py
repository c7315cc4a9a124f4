"""UDP datagram link with injected faults: packet loss, added latency and a scheduled outage.

Faults apply to both directions, per datagram, the way a lossy radio would. Link timing is wall-clock time
because the peer's timeouts (heartbeat loss, retransmission) run on the wall clock too.
"""

from __future__ import annotations

import heapq
import itertools
import socket
import time

import numpy as np


class FaultyUdpLink:
    """Sends to ``target`` from a socket bound on ``bind`` and receives the replies the peer sends back."""

    def __init__(self, target: tuple[str, int], rng: np.random.Generator, *, bind: tuple[str, int] = ("127.0.0.1", 0),
                 loss: float = 0.0, latency_s: float = 0.0):
        if not 0.0 <= loss < 1.0:
            raise ValueError("packet loss must be a fraction in [0, 1)")
        self.target = target
        self.rng = rng
        self.loss = loss
        self.latency_s = latency_s
        self.down = False  # True during an outage: everything is dropped
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(bind)
        self.sock.setblocking(False)
        self._delayed: list[tuple[float, int, str, bytes]] = []  # (due, tiebreak, direction, data)
        self._counter = itertools.count()
        self.sent = self.dropped = self.received = 0

    def fileno(self) -> int:
        return self.sock.fileno()

    def _lost(self) -> bool:
        return self.down or (self.loss > 0.0 and self.rng.random() < self.loss)

    def send(self, data: bytes) -> None:
        if self._lost():
            self.dropped += 1
            return
        if self.latency_s > 0.0:
            heapq.heappush(self._delayed, (time.monotonic() + self.latency_s, next(self._counter), "out", data))
        else:
            self._send_now(data)

    def _send_now(self, data: bytes) -> None:
        try:
            self.sock.sendto(data, self.target)
            self.sent += 1
        except OSError:  # nobody listening yet (ICMP port unreachable): same as a lost packet
            self.dropped += 1

    def receive(self) -> list[bytes]:
        """All datagrams that have arrived (and survived the faults) by now."""
        out: list[bytes] = []
        while True:
            try:
                data, _ = self.sock.recvfrom(65535)
            except (BlockingIOError, InterruptedError):
                break
            except OSError:  # e.g. ECONNREFUSED reported for an earlier send
                continue
            if self._lost():
                self.dropped += 1
                continue
            if self.latency_s > 0.0:
                heapq.heappush(self._delayed, (time.monotonic() + self.latency_s, next(self._counter), "in", data))
            else:
                out.append(data)
        now = time.monotonic()
        while self._delayed and self._delayed[0][0] <= now:
            _, _, direction, data = heapq.heappop(self._delayed)
            if direction == "out":
                self._send_now(data)
            else:
                out.append(data)
        self.received += len(out)
        return out

    def next_due(self) -> float | None:
        """Monotonic time of the next delayed datagram, if any."""
        return self._delayed[0][0] if self._delayed else None

    def close(self) -> None:
        self.sock.close()

"""Wall-clock (UTC) time of a keyframe's exposure, for its EXIF capture time and sidecar.

Frames carry the time of the clock that stamped them: the companion's Unix clock (live cameras), a video's own
time line (recordings culled offline) or the autopilot's boot clock (the simulator camera). The telemetry log
puts the companion's Unix time (``t_wall``) beside the autopilot's (``t_boot_s``) on every row; the smallest
``t_wall - t_boot_s`` seen is the boot -> Unix offset (every row is written after its message was stamped, so
delays only add: the same minimum-delay idea as ``ClockMap``), with the two clocks' rate fitted (a simulator may
run faster than real time). A capture time that cannot be placed on the wall
clock, or lands before 2000 (a clock that was never set), gives None: the image then carries no time rather
than a wrong one.
"""

from __future__ import annotations

import logging
import threading
from typing import Protocol

import numpy as np

from companion.capture.telemetry import ClockMap

log = logging.getLogger(__name__)

EARLIEST_PLAUSIBLE_UNIX_S = 946684800.0  # 2000-01-01T00:00:00Z: anything earlier is an unset clock, not a flight


class CaptureClock(Protocol):
    def unix_time(self, capture_time_s: float) -> float | None: ...


class UnixCaptureClock:
    """Capture times are Unix times already (live cameras stamped with the companion's ``time.time()``)."""

    def unix_time(self, capture_time_s: float) -> float | None:
        return plausible(capture_time_s)


class TelemetryWallClock:
    """Capture clock -> autopilot boot clock (``camera_to_autopilot``) -> Unix time (learnt from the telemetry).

    Feed ``observe(t_wall, t_boot_s)`` with telemetry rows; live, a tailer does it as rows arrive. Unix time =
    a + b * boot time: b is the least-squares rate of the Unix clock against the boot clock (1 for a real autopilot
    to within its crystal's ppm; a simulator run faster than real time has another rate), a the smallest
    ``t_wall - b * t_boot_s`` seen (rows are written after their message was stamped: delays only add). With less
    than ``MIN_RATE_SPAN_S`` of boot time seen, b is taken as 1.
    """

    MIN_RATE_SPAN_S = 10.0

    def __init__(self, camera_to_autopilot: ClockMap):
        self.camera_to_autopilot = camera_to_autopilot
        self._boot: list[float] = []
        self._wall: list[float] = []
        self._lock = threading.Lock()
        self._fit: tuple[int, float, float] | None = None  # (rows used, a, b)

    def observe(self, t_wall: float, t_boot_s: float) -> None:
        with self._lock:
            self._boot.append(float(t_boot_s))
            self._wall.append(float(t_wall))

    @classmethod
    def from_log_rows(cls, rows: list[dict], camera_to_autopilot: ClockMap) -> TelemetryWallClock:
        clock = cls(camera_to_autopilot)
        for row in rows:
            if row.get("t_wall") is not None and row.get("t_boot_s") is not None:
                clock.observe(float(row["t_wall"]), float(row["t_boot_s"]))
        return clock

    @property
    def has_wall_time(self) -> bool:
        return bool(self._boot)

    def boot_to_unix(self) -> tuple[float, float] | None:
        """(a, b) with Unix time = a + b * boot time, from the rows seen so far; None before the first row."""
        with self._lock:
            n = len(self._boot)
            if n == 0:
                return None
            if self._fit is not None and self._fit[0] == n:
                return self._fit[1], self._fit[2]
            boot, wall = np.array(self._boot), np.array(self._wall)
        rate = 1.0
        if boot.max() - boot.min() >= self.MIN_RATE_SPAN_S:
            rate = float(np.polyfit(boot - boot[0], wall - wall[0], 1)[0])
        offset = float(np.min(wall - rate * boot))
        with self._lock:
            self._fit = (n, offset, rate)
        return offset, rate

    def unix_time(self, capture_time_s: float) -> float | None:
        t_boot = self.camera_to_autopilot.to_autopilot(capture_time_s)
        fit = self.boot_to_unix()
        if t_boot is None or fit is None:
            return None
        return plausible(fit[0] + fit[1] * t_boot)


def plausible(unix_s: float) -> float | None:
    return unix_s if unix_s >= EARLIEST_PLAUSIBLE_UNIX_S else None

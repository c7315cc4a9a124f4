"""Wall-clock (UTC) time of a keyframe's exposure, for its EXIF capture time and sidecar.

Frames carry the time of the clock that stamped them: the companion's Unix clock (live cameras), a video's own
time line (recordings culled offline) or the autopilot's boot clock (the simulator camera). The telemetry log
puts the companion's Unix time (``t_wall``) beside the autopilot's (``t_boot_s``) on every row; the smallest
``t_wall - t_boot_s`` seen is the boot -> Unix offset (every row is written after its message was stamped, so
delays only add: the same minimum-delay idea as ``ClockMap``). A capture time that cannot be placed on the wall
clock, or lands before 2000 (a clock that was never set), gives None: the image then carries no time rather
than a wrong one.
"""

from __future__ import annotations

import logging
from typing import Protocol

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

    Feed ``observe(t_wall, t_boot_s)`` with telemetry rows; live, a tailer does it as rows arrive.
    """

    def __init__(self, camera_to_autopilot: ClockMap, window: int = 100_000):
        self.camera_to_autopilot = camera_to_autopilot
        self._boot_to_wall = ClockMap(window=window)

    def observe(self, t_wall: float, t_boot_s: float) -> None:
        self._boot_to_wall.observe(t_wall, t_boot_s)

    @classmethod
    def from_log_rows(cls, rows: list[dict], camera_to_autopilot: ClockMap) -> TelemetryWallClock:
        clock = cls(camera_to_autopilot, window=max(len(rows), 1))
        for row in rows:
            if row.get("t_wall") is not None and row.get("t_boot_s") is not None:
                clock.observe(float(row["t_wall"]), float(row["t_boot_s"]))
        return clock

    @property
    def boot_to_unix_offset_s(self) -> float | None:
        return self._boot_to_wall.offset_s

    def unix_time(self, capture_time_s: float) -> float | None:
        t_boot = self.camera_to_autopilot.to_autopilot(capture_time_s)
        offset = self.boot_to_unix_offset_s
        if t_boot is None or offset is None:
            return None
        return plausible(t_boot + offset)


def plausible(unix_s: float) -> float | None:
    return unix_s if unix_s >= EARLIEST_PLAUSIBLE_UNIX_S else None

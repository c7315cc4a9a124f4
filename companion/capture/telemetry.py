"""Telemetry buffer: the vehicle's recent poses, interpolated at a frame's capture time.

Times are seconds on the AUTOPILOT's clock (MAVLink time_boot_ms / 1000). Frames are stamped by the camera's
clock; ``ClockMap`` turns those into autopilot time. Position is interpolated linearly, attitude by quaternion
slerp. A pose is flagged stale (and not used) when the telemetry around the capture time has a gap, or the
capture time lies beyond the newest sample by more than a short extrapolation window, or a sample it would use
carries a held attitude (a telemetry-log row written before the ATTITUDE after it came, ``attitude_held``:
``flight/telemetry_log.py``): its roll and pitch are an older sample's, not the ones at the frame's time.
"""

from __future__ import annotations

import bisect
import threading
from collections import deque
from dataclasses import dataclass, replace

from companion.attitude import euler_to_quat, quat_to_euler, slerp
from companion.records import Pose


@dataclass(frozen=True)
class TagResult:
    pose: Pose | None
    stale: bool
    reason: str = ""


class ClockMap:
    """Maps a camera/companion clock onto the autopilot clock.

    Fed with (local_time, autopilot_time) pairs observed when telemetry arrives; since every message reaches us
    later than it was stamped, the smallest (local - autopilot) difference over a window is the best estimate of
    the offset (the same minimum-delay idea as MAVLink TIMESYNC). A fixed offset can be set instead (e.g. the
    simulator's camera shares the vehicle's clock: offset 0).
    """

    def __init__(self, fixed_offset_s: float | None = None, window: int = 200):
        self._fixed = fixed_offset_s
        self._diffs: deque[float] = deque(maxlen=window)

    def observe(self, local_time_s: float, autopilot_time_s: float) -> None:
        self._diffs.append(local_time_s - autopilot_time_s)

    @property
    def offset_s(self) -> float | None:
        if self._fixed is not None:
            return self._fixed
        return min(self._diffs) if self._diffs else None

    def to_autopilot(self, local_time_s: float) -> float | None:
        off = self.offset_s
        return None if off is None else local_time_s - off


class TelemetryBuffer:
    """Thread-safe ring buffer of poses ordered by autopilot time."""

    def __init__(self, max_samples: int = 4000, max_gap_s: float = 0.5, max_extrapolation_s: float = 0.1):
        self.max_gap_s = max_gap_s
        self.max_extrapolation_s = max_extrapolation_s
        self._times: deque[float] = deque(maxlen=max_samples)
        self._poses: deque[Pose] = deque(maxlen=max_samples)
        self._held: deque[bool] = deque(maxlen=max_samples)  # the sample's attitude is held, not its own
        self._first_time_s: float | None = None  # the first sample ever (the ring forgets it on long flights)
        self._lock = threading.Lock()
        self._arrived = threading.Condition(self._lock)  # notified on every new sample (``wait_for``)

    def __len__(self) -> int:
        return len(self._times)

    def add(self, pose: Pose, attitude_held: bool = False) -> bool:
        """Append a sample; out-of-order or duplicate times are ignored (returns False). ``attitude_held``: its
        attitude is an older one held (``row_attitude_held``); a frame tagged from it is stale."""
        with self._lock:
            if self._times and pose.time_s <= self._times[-1]:
                return False
            self._times.append(pose.time_s)
            self._poses.append(pose)
            self._held.append(bool(attitude_held))
            if self._first_time_s is None:
                self._first_time_s = pose.time_s
            self._arrived.notify_all()
            return True

    def wait_for(self, t: float, timeout_s: float) -> bool:
        """Wait, at most ``timeout_s`` of wall time, until a sample at or after autopilot time ``t`` has arrived.

        Why: a live frame can reach the chain before the telemetry of its capture time does (the recorder writes a
        position row once the ATTITUDE after it has come, and the log is tailed); tagged at once, its pose is the
        last sample held up to ``max_extrapolation_s``, and at a strip's start the vehicle rolls 4 degrees in those
        80 ms (SITL, a loaded machine). Returns whether such a sample is there."""
        with self._arrived:
            return self._arrived.wait_for(lambda: bool(self._times) and self._times[-1] >= t, timeout_s)

    @property
    def first_time_s(self) -> float | None:
        """Autopilot time of the first sample this buffer received."""
        with self._lock:
            return self._first_time_s

    @property
    def newest_time_s(self) -> float | None:
        with self._lock:
            return self._times[-1] if self._times else None

    def pose_at(self, t: float) -> TagResult:
        with self._lock:
            times = list(self._times)
            poses = list(self._poses)
            held = list(self._held)
        if not times:
            return TagResult(None, True, "no telemetry yet")
        if t < times[0] - self.max_extrapolation_s:
            return TagResult(None, True, f"capture time {t:.3f} s is older than the telemetry buffer")
        if t > times[-1] + self.max_extrapolation_s:
            return TagResult(None, True, f"telemetry is {t - times[-1]:.2f} s behind the frame")
        k = bisect.bisect_right(times, t)
        used = [i for i in (k - 1, k) if 0 <= i < len(times)]
        if any(held[i] for i in used):
            return TagResult(None, True, f"the telemetry's attitude at {t:.3f} s is held, not measured "
                                         "(the ATTITUDE stream lagged the position stream)")
        if k == 0:
            return TagResult(_with_time(poses[0], t), False)
        if k == len(times):
            return TagResult(_with_time(poses[-1], t), False)
        t0, t1 = times[k - 1], times[k]
        if t1 - t0 > self.max_gap_s:
            return TagResult(None, True, f"telemetry gap of {t1 - t0:.2f} s around the frame")
        return TagResult(interpolate(poses[k - 1], poses[k], (t - t0) / (t1 - t0), t), False)


def _with_time(p: Pose, t: float) -> Pose:
    return replace(p, time_s=t)


def interpolate(a: Pose, b: Pose, s: float, t: float) -> Pose:
    def lerp(x: float, y: float) -> float:
        return x + s * (y - x)

    q = slerp(euler_to_quat(yaw_deg=a.yaw_deg, pitch_deg=a.pitch_deg, roll_deg=a.roll_deg),
              euler_to_quat(yaw_deg=b.yaw_deg, pitch_deg=b.pitch_deg, roll_deg=b.roll_deg), s)
    roll, pitch, yaw = quat_to_euler(q)
    nearer = b if s >= 0.5 else a
    return Pose(
        time_s=t,
        lat=lerp(a.lat, b.lat),
        lon=lerp(a.lon, b.lon),
        alt_amsl_m=lerp(a.alt_amsl_m, b.alt_amsl_m),
        relative_alt_m=lerp(a.relative_alt_m, b.relative_alt_m),
        roll_deg=roll,
        pitch_deg=pitch,
        yaw_deg=yaw,
        velocity_ned_m_s=tuple(lerp(x, y) for x, y in zip(a.velocity_ned_m_s, b.velocity_ned_m_s, strict=True)),
        gimbal_pitch_deg=_lerp_known(a.gimbal_pitch_deg, b.gimbal_pitch_deg, s),
        mission_item=nearer.mission_item,
        gimbal_yaw_deg=_lerp_known(a.gimbal_yaw_deg, b.gimbal_yaw_deg, s),
        gimbal_source=nearer.gimbal_source,
        range_forward_m=_lerp_known(a.range_forward_m, b.range_forward_m, s),
    )


def _lerp_known(x: float | None, y: float | None, s: float) -> float | None:
    """Linear between two known values; where one is unknown (the gimbal was commanded between the samples, the
    rangefinder lost the wall) the nearer sample's value, unknown included."""
    if x is not None and y is not None:
        return x + s * (y - x)
    return y if s >= 0.5 else x


def pose_from_log_row(row: dict) -> Pose | None:
    """A Pose from one telemetry-log line (``companion fly --telemetry-log``); None if it lacks a fix or a time."""
    return Pose.from_json(row)


def row_attitude_held(row: dict) -> bool:
    """Whether a telemetry-log row's attitude is held from an older ATTITUDE, not its own (a log from before the
    key: never)."""
    return bool(row.get("attitude_held"))


def buffer_from_log(rows: list[dict], max_gap_s: float = 0.5) -> TelemetryBuffer:
    """A buffer holding a whole recorded flight (offline culling)."""
    buf = TelemetryBuffer(max_samples=max(len(rows), 1), max_gap_s=max_gap_s)
    for row in rows:
        pose = pose_from_log_row(row)
        if pose is not None:
            buf.add(pose, attitude_held=row_attitude_held(row))
    return buf

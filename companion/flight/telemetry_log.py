"""Telemetry recorder: keeps the latest value of each telemetry stream and writes one JSON line per position
sample, flushed as written, so a crash or a cut link loses nothing already received.

Each row is a pose in its one JSON form (``companion.records.pose_json``) plus the flight state. The camera
gimbal's angles come from the gimbal's own attitude report (GIMBAL_DEVICE_ATTITUDE_STATUS) when the vehicle sends
one; PX4 and ArduPilot SITL without a configured gimbal send none (notes/real-firmware.md), and mavsdk's gimbal
plugin reports nothing without it either. Then they come from the plan's gimbal command once the vehicle has
passed that item, and before that they are unknown (null). ``gimbal_source`` says which.

A forward rangefinder (DISTANCE_SENSOR with orientation MAV_SENSOR_ROTATION_NONE) gives ``range_forward_m``: the
reading nearest the row's autopilot time, within 0.5 s, and inside the sensor's own min/max (outside it, e.g.
MAVLink's max + 1 "nothing in range", there is no distance). It is what a GNSS bias cannot move: the estimate says
the planned standoff, the rangefinder the true one. Read from the raw MAVLink stream because mavsdk's
``distance_sensor()`` does not say which way the sensor points (a downward one would be taken for the wall).

A row's attitude is the ATTITUDE at the row's autopilot time, interpolated between the ATTITUDE samples around it
(a short history is kept). The two streams come through separate subscriptions, and under load the ATTITUDE stream
lags the position stream (a 2-core companion with busy loops: rows 0.4 s long all carried the roll of one old
ATTITUDE, and a keyframe was tagged 6 degrees off). So a position row waits for the ATTITUDE at or after its time,
bounded: it is written anyway once the position stream has run ``ATTITUDE_WAIT_S`` of autopilot time past it, or it
has waited that long on the wall clock (checked as messages arrive; the log's end writes all). Such a row carries the
newest ATTITUDE before it, held, and says so: ``attitude_held: true`` and ``attitude_age_s`` (the row's time minus the
held sample's, null when unknown). The keys are there only on held rows, so a log from before them reads as it did
(every row interpolated); ``capture/telemetry.py`` takes a held row's pose as stale.
"""

from __future__ import annotations

import asyncio
import bisect
import contextlib
import json
import logging
import math
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import IO

from companion.attitude import quat_to_euler
from companion.files import read_jsonl
from companion.flight.status_texts import clean_text
from companion.mission import items as mi
from companion.records import GimbalSource, pose_json

log = logging.getLogger(__name__)

_GIMBAL_YAW_LOCK = 16  # GIMBAL_DEVICE_FLAGS: yaw held in the earth frame (older senders)
_GIMBAL_YAW_IN_VEHICLE_FRAME = 32
_GIMBAL_YAW_IN_EARTH_FRAME = 64
_GIMBAL_REPORT_FRESH_S = 2.0  # a gimbal report older than this (monotonic seconds) is not the gimbal's angle now
_RANGE_FRESH_S = 0.5  # a rangefinder reading further than this (autopilot seconds) from a row is not its distance
_RANGE_KEEP = 32  # readings kept to find the one nearest a row (a row may wait a while for its ATTITUDE)
_ATT_KEEP = 512  # ATTITUDE samples kept to interpolate a row's attitude (seconds of them, at any stream rate)
_SENSOR_ROTATION_FORWARD = 0  # MAV_SENSOR_ROTATION_NONE: the sensor looks along the vehicle's nose


@dataclass(frozen=True)
class PlannedGimbal:
    """The plan's gimbal command: angles the gimbal holds once the vehicle has passed mission item ``seq``."""

    seq: int
    pitch_deg: float
    yaw_deg: float | None  # relative to the vehicle's heading

    @classmethod
    def from_items(cls, items: Sequence[mi.MissionItem]) -> PlannedGimbal | None:
        """The first gimbal-manager or mount-control item of a mission, or None when it commands no gimbal."""
        for it in items:
            if it.command == mi.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW:
                pitch, yaw = it.param1, it.param2
            elif it.command == mi.MAV_CMD_DO_MOUNT_CONTROL:
                pitch, yaw = it.param1, it.param3
            else:
                continue
            if math.isfinite(pitch):
                return cls(int(it.seq), float(pitch), float(yaw) if math.isfinite(yaw) else None)
        return None


def gimbal_from_status(fields: dict, vehicle_yaw_deg: float | None) -> tuple[float, float | None]:
    """(pitch from the horizon, yaw relative to the vehicle's heading) of a GIMBAL_DEVICE_ATTITUDE_STATUS message.

    Its quaternion's yaw is in the earth frame when the flags say so (YAW_IN_EARTH_FRAME, or YAW_LOCK without
    YAW_IN_VEHICLE_FRAME), else relative to the vehicle; pitch is always from the horizon (the gimbal is
    stabilised). An earth-frame yaw without a vehicle yaw to subtract is unknown (None)."""
    _, pitch, yaw = quat_to_euler(fields["q"])
    flags = int(fields.get("flags") or 0)
    earth = bool(flags & _GIMBAL_YAW_IN_EARTH_FRAME) or (
        bool(flags & _GIMBAL_YAW_LOCK) and not flags & _GIMBAL_YAW_IN_VEHICLE_FRAME
    )
    if earth:
        yaw = None if vehicle_yaw_deg is None else yaw - vehicle_yaw_deg
    return pitch, None if yaw is None else (yaw + 180.0) % 360.0 - 180.0


def _num(x: float) -> float | None:
    return None if x is None or (isinstance(x, float) and not math.isfinite(x)) else x


def _lerp_attitude(a, b, t: float) -> tuple[float, float, float]:
    """Attitude at time t between samples a and b (time, roll, pitch, yaw), linear in time, yaw the short way."""
    if b[0] <= a[0]:
        return b[1], b[2], b[3]
    s = min(1.0, max(0.0, (t - a[0]) / (b[0] - a[0])))
    dyaw = (b[3] - a[3] + 180.0) % 360.0 - 180.0
    return a[1] + s * (b[1] - a[1]), a[2] + s * (b[2] - a[2]), (a[3] + s * dyaw) % 360.0


def _attitude_at(history: Sequence[tuple[float, float, float, float]], t: float):
    """(roll, pitch, yaw, held age) at autopilot time t from ATTITUDE samples in time order.

    Between two samples (or on one): interpolated, age None. After the newest: the newest held, age = t minus its
    time. Before the oldest, or no samples: None."""
    if not history or t < history[0][0]:
        return None
    k = bisect.bisect_left(history, t, key=lambda a: a[0])  # first sample at or after t
    if k == len(history):
        b = history[-1]
        return b[1], b[2], b[3], t - b[0]
    b = history[k]
    a = history[k - 1] if k > 0 else b
    return (*_lerp_attitude(a, b, t), None)


class TelemetryRecorder:
    """Subscribes to position, attitude, velocity, mode, armed, in-air and mission progress.

    ``state`` holds the latest values; ``last_sample_wall`` the monotonic time of the last position sample
    (used to notice a silent link). ``reboot`` is set (and stays) when the autopilot's time since boot goes
    backwards: the vehicle restarted, and nothing it reports about the mission can be trusted after that.
    """

    REBOOT_BACKSTEP_S = 1.0  # time_boot_ms going back by more than this is a new boot, not reordering
    # How long a position row waits for the ATTITUDE after it (autopilot seconds of position stream past the row, or
    # wall seconds since it arrived): above the 1.2 s lag seen in mavsdk's queues on ArduCopter SITL at speed-up 5
    # and the simulator's 2.5 s stream stalls (tests/test_flight_sitl_endings.py)
    ATTITUDE_WAIT_S = 3.0

    def __init__(self, vehicle, path: Path | None = None, *, planned_gimbal: PlannedGimbal | None = None):
        self.vehicle = vehicle
        self.planned_gimbal = planned_gimbal
        self._gimbal_report: tuple[float, float, float | None] | None = None  # (monotonic time, pitch, yaw)
        self.path = Path(path) if path else None
        self._file: IO[str] | None = None
        self.state: dict = {"mission_item": -1, "mission_total": 0, "armed": None, "in_air": None,
                            "flight_mode": None, "landed_state": None, "home_alt_m": None}
        # latched: the vehicle was seen in the air at some point while recording (a short flight can start and end
        # while the companion is still waiting for a slow command acknowledgement on a lossy link)
        self.was_in_air = False
        self.was_armed = False  # latched likewise: armed at some point while recording
        self.home_before_air_m: float | None = None  # the last home altitude received before the vehicle flew
        self.home_before_air_latlon: tuple[float, float] | None = None  # ... and where it was
        self.reboot: str | None = None
        self._boot_time_max: dict[str, float] = {}  # per message stream
        self.status_events: list[tuple[float, str, str]] = []  # (monotonic time, severity name, text)
        self.samples = 0
        self.last_sample_wall: float | None = None
        self._last_position = None
        self.status_texts: list[str] = []
        self._tasks: list[asyncio.Task] = []
        self.progress_event = asyncio.Event()
        # raw ATTITUDE samples (autopilot s, roll, pitch, yaw) in time order, the newest last
        self._atts: list[tuple[float, float, float, float]] = []
        self._att_seen = False  # an ATTITUDE has come (the history is emptied at a reboot)
        self._raw_pos: tuple | None = None  # latest raw GLOBAL_POSITION_INT; once it flows, rows come from it
        # position rows waiting for the ATTITUDE after them: (raw position, monotonic arrival time)
        self._pending: deque[tuple[tuple, float]] = deque()
        self.attitude_held_rows = 0  # rows written with a held (not interpolated) attitude
        # forward DISTANCE_SENSOR readings: (autopilot s, monotonic s, metres or None when outside min/max)
        self._ranges: deque[tuple[float, float, float | None]] = deque(maxlen=_RANGE_KEEP)
        # sees every row's pose JSON before it is written and returns keys to add to it (the standoff loop)
        self.row_hook: Callable[[dict], dict] | None = None

    async def __aenter__(self) -> TelemetryRecorder:
        if self.path is not None:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._file = open(self.path, "a", buffering=1)  # noqa: SIM115 (closed in __aexit__)
        t, m = self.vehicle.telemetry, self.vehicle.mission
        for coro in (self._follow(t.subscribe_position(), self._on_position),
                     self._follow(t.subscribe_attitude_euler(), self._on_attitude),
                     self._follow(t.subscribe_velocity_ned(), self._on_velocity),
                     self._follow(t.subscribe_flight_mode(), lambda v: self.state.update(flight_mode=v.name)),
                     self._follow(t.subscribe_armed(), lambda v: self._on_state("armed", bool(v))),
                     self._follow(t.subscribe_in_air(), lambda v: self._on_state("in_air", bool(v))),
                     self._follow(t.subscribe_landed_state(), lambda v: self.state.update(landed_state=v.name)),
                     self._follow(t.subscribe_status_text(), self._on_status_text),
                     self._follow(t.subscribe_home(), self._on_home),
                     self._follow(m.subscribe_mission_progress(), self._on_progress)):
            self._tasks.append(asyncio.create_task(coro))
        direct = getattr(self.vehicle, "direct", None)
        if direct is not None:
            for name, handler in (("ATTITUDE", self._on_raw_att), ("GLOBAL_POSITION_INT", self._on_raw_pos),
                                  ("GIMBAL_DEVICE_ATTITUDE_STATUS", self._on_gimbal_status),
                                  ("DISTANCE_SENSOR", self._on_distance_sensor)):
                self._tasks.append(asyncio.create_task(self._follow(direct.subscribe_message(name), handler)))
        return self

    async def __aexit__(self, *exc) -> None:
        self._flush_positions(force=True)
        for task in self._tasks:
            task.cancel()
        for task in self._tasks:
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await task
        if self._file is not None:
            self._file.close()
            self._file = None

    @staticmethod
    async def _follow(gen, handler) -> None:
        async for value in gen:
            handler(value)

    def _on_attitude(self, a) -> None:
        self.state.update(roll_deg=_num(a.roll_deg), pitch_deg=_num(a.pitch_deg), yaw_deg=_num(a.yaw_deg),
                          t_boot_s=a.timestamp_us / 1e6 if a.timestamp_us else None)

    def _on_velocity(self, v) -> None:
        self.state.update(vn_m_s=_num(v.north_m_s), ve_m_s=_num(v.east_m_s), vd_m_s=_num(v.down_m_s))

    def _on_home(self, h) -> None:
        """HOME_POSITION: the autopilot may move it in flight (PX4 does for 120 s after take-off; home_watch.py)."""
        alt = _num(h.absolute_altitude_m)
        self.state["home_alt_m"] = alt
        if alt is not None and not self.was_in_air:
            self.home_before_air_m = alt  # home at arming: the ground the vehicle takes off from
            lat, lon = _num(h.latitude_deg), _num(h.longitude_deg)
            self.home_before_air_latlon = (lat, lon) if lat is not None and lon is not None else None

    def _on_progress(self, p) -> None:
        self.state.update(mission_item=p.current, mission_total=p.total)
        self.progress_event.set()

    def _on_status_text(self, s) -> None:
        said = clean_text(s.text)  # PX4 ends its texts with a tab
        text = f"{s.type.name}: {said}"
        self.status_texts.append(text)
        self.status_events.append((time.monotonic(), s.type.name, said))
        log.info("vehicle says %s", text)

    @property
    def boot_time_s(self) -> float | None:
        """The autopilot's latest time since boot on any stream (None before the first one)."""
        return max(self._boot_time_max.values()) if self._boot_time_max else self.state.get("t_boot_s")

    def _on_boot_time(self, t_boot_s: float, stream: str = "") -> None:
        """Notice an autopilot restart: its clock since boot runs backwards within one message stream.

        Each stream (ATTITUDE, GLOBAL_POSITION_INT) is compared only with itself: the two arrive through separate
        subscriptions whose queues are drained by separate tasks, so on a loaded machine one can lag the other by
        more than a second of autopilot time (real ArduCopter SITL at speed-up 5: an ATTITUDE 1.2 s older than the
        GLOBAL_POSITION_INT handled before it). Within one stream the order is the autopilot's."""
        top = self._boot_time_max.get(stream)
        if top is not None and t_boot_s < top - self.REBOOT_BACKSTEP_S and self.reboot is None:
            self.reboot = (f"the autopilot restarted: its time since boot went back from {top:.1f} s to "
                           f"{t_boot_s:.1f} s")
            log.error("%s", self.reboot)
        self._boot_time_max[stream] = t_boot_s if top is None else max(top, t_boot_s)

    def _on_state(self, key: str, value: bool) -> None:
        """Armed / in-air changes also get a row (with the last position), so the log ends in the final state."""
        changed = self.state.get(key) != value
        self.state[key] = value
        if key == "in_air" and value:
            self.was_in_air = True
        if key == "armed" and value:
            self.was_armed = True
        if changed and self._pending:
            pass  # the rows waiting for their ATTITUDE are written with this state (an earlier row now would be
            # out of time order, and the buffer drops those)
        elif changed and self._raw_pos is not None:
            self._write_row(*self._raw_pos)
        elif changed and self._last_position is not None:
            self._write(self._last_position)

    def _on_position(self, p) -> None:
        self.last_sample_wall = time.monotonic()
        self._last_position = p
        if self._raw_pos is None:
            self._write(p)

    def _on_raw_att(self, msg) -> None:
        with contextlib.suppress(ValueError, TypeError, KeyError):
            f = json.loads(msg.fields_json)
            roll, pitch, yaw = (math.degrees(f[k]) for k in ("roll", "pitch", "yaw"))
            t = f["time_boot_ms"] / 1000.0
            self._on_boot_time(t, "ATTITUDE")
            if self._atts and t <= self._atts[-1][0]:
                if t > self._atts[-1][0] - self.REBOOT_BACKSTEP_S:
                    return  # a repeat or a reordered sample: the history stays in time order
                # a new boot: no ATTITUDE will come after the rows of the old one still waiting (the new boot's wait)
                while self._pending and self._pending[0][0][0] > t + self.REBOOT_BACKSTEP_S:
                    self._write_row(*self._pending.popleft()[0])
                self._atts.clear()
            self._atts.append((t, roll, pitch, yaw % 360.0))
            self._att_seen = True
            if len(self._atts) > _ATT_KEEP:
                del self._atts[: len(self._atts) - _ATT_KEEP]
            self._flush_positions()

    def _on_gimbal_status(self, msg) -> None:
        with contextlib.suppress(ValueError, TypeError, KeyError, IndexError):
            pitch, yaw = gimbal_from_status(json.loads(msg.fields_json), self.state.get("yaw_deg"))
            self._gimbal_report = (time.monotonic(), pitch, yaw)

    def _on_distance_sensor(self, msg) -> None:
        """Keep forward readings only (orientation 0); a reading outside the sensor's min/max is no distance."""
        with contextlib.suppress(ValueError, TypeError, KeyError):
            f = json.loads(msg.fields_json)
            if int(f["orientation"]) != _SENSOR_ROTATION_FORWARD:
                return
            cm, lo, hi = int(f["current_distance"]), int(f["min_distance"]), int(f["max_distance"])
            metres = cm / 100.0 if lo <= cm <= hi else None
            self._ranges.append((f["time_boot_ms"] / 1000.0, time.monotonic(), metres))

    def _range_at(self, t_boot: float | None) -> float | None:
        """The forward distance for a row at autopilot time ``t_boot``: the nearest reading within 0.5 s (by
        arrival time when the row has no autopilot time)."""
        if not self._ranges:
            return None
        if t_boot is None:
            _, arrived, metres = self._ranges[-1]
            return metres if time.monotonic() - arrived <= _RANGE_FRESH_S else None
        t, _, metres = min(self._ranges, key=lambda r: abs(r[0] - t_boot))
        return metres if abs(t - t_boot) <= _RANGE_FRESH_S else None

    def _gimbal(self) -> dict:
        """The gimbal's angles for a row now: its own fresh report, else the plan's command once passed."""
        report = self._gimbal_report
        if report is not None and time.monotonic() - report[0] <= _GIMBAL_REPORT_FRESH_S:
            return {"gimbal_pitch_deg": report[1], "gimbal_yaw_deg": report[2],
                    "gimbal_source": GimbalSource.TELEMETRY}
        plan = self.planned_gimbal
        if plan is not None and self.state["mission_item"] > plan.seq:
            return {"gimbal_pitch_deg": plan.pitch_deg, "gimbal_yaw_deg": plan.yaw_deg,
                    "gimbal_source": GimbalSource.PLAN}
        return {}

    def _on_raw_pos(self, msg) -> None:
        """GLOBAL_POSITION_INT carries the autopilot's time_boot_ms: once it flows, rows are stamped with it, so
        frames can be tagged by interpolation at their capture time (mavsdk's Position has no timestamp). A row
        waits (about one attitude period) for the ATTITUDE after it, so its attitude is interpolated, not held."""
        try:
            f = json.loads(msg.fields_json)
            self._raw_pos = (f["time_boot_ms"] / 1000.0, f["lat"] / 1e7, f["lon"] / 1e7, f["alt"] / 1000.0,
                             f["relative_alt"] / 1000.0, (f["vx"] / 100.0, f["vy"] / 100.0, f["vz"] / 100.0))
        except (ValueError, TypeError, KeyError):
            return
        self._on_boot_time(self._raw_pos[0], "GLOBAL_POSITION_INT")
        t = self._raw_pos[0]
        if self._pending and t < self._pending[-1][0][0]:
            self._flush_positions(force=True)  # the position clock went back: keep the log in time order
        if self._atts and t < self._atts[-1][0] - self.ATTITUDE_WAIT_S and self.reboot is not None:
            # a new boot seen first on this stream: the ATTITUDEs far ahead are the old boot's, not this row's
            self._atts = [a for a in self._atts if a[0] <= t + self.ATTITUDE_WAIT_S]
        self._pending.append((self._raw_pos, time.monotonic()))
        self._flush_positions()

    def _flush_positions(self, force: bool = False) -> None:
        """Write the waiting rows whose ATTITUDE after them has come; those that waited ``ATTITUDE_WAIT_S`` (or all,
        ``force``) with the attitude they can have. Rows stay in time order: one waiting holds back those after it."""
        att_t = self._atts[-1][0] if self._atts else None
        newest_t = self._pending[-1][0][0] if self._pending else None
        now = time.monotonic()
        while self._pending:
            pos, arrived = self._pending[0]
            waited = (newest_t - pos[0] >= self.ATTITUDE_WAIT_S or now - arrived >= self.ATTITUDE_WAIT_S)
            # before the first ATTITUDE nothing is waited for: a vehicle that sends none (mavsdk's attitude may come
            # from ATTITUDE_QUATERNION) still gets its rows at once, with that attitude marked held
            if not force and not waited and self._att_seen and (att_t is None or pos[0] > att_t):
                return
            self._pending.popleft()
            self._write_row(*pos)

    def _write_row(self, t_boot, lat, lon, alt, rel, vel) -> None:
        self.samples += 1
        if self._file is None and self.row_hook is None:
            return
        st = self.state
        att = _attitude_at(self._atts, t_boot)
        held: dict = {}
        if att is not None:
            roll, pitch, yaw, age = att
        else:  # no ATTITUDE at or before the row: mavsdk's latest attitude, if any
            roll, pitch, yaw = st.get("roll_deg"), st.get("pitch_deg"), st.get("yaw_deg")
            t_att = st.get("t_boot_s")
            age = None if roll is None else (t_boot - t_att if t_att is not None else math.nan)
        if age is not None:
            held = {"attitude_held": True, "attitude_age_s": round(age, 3) if math.isfinite(age) else None}
            self.attitude_held_rows += 1
        pose = pose_json(time_s=t_boot, lat=lat, lon=lon, alt_amsl_m=alt, relative_alt_m=rel, roll_deg=roll,
                         pitch_deg=pitch, yaw_deg=yaw, velocity_ned_m_s=vel, mission_item=st["mission_item"],
                         range_forward_m=self._range_at(t_boot), **self._gimbal())
        self._emit(pose, held)

    def _row(self, pose: dict, held: dict | None = None) -> dict:
        st = self.state
        extra = self.row_hook(pose) if self.row_hook is not None else {}
        return {"t_wall": round(time.time(), 4), **pose, **(held or {}), "mission_total": st["mission_total"],
                "flight_mode": st["flight_mode"], "armed": st["armed"], "in_air": st["in_air"], **extra}

    def _emit(self, pose: dict, held: dict | None = None) -> None:
        row = self._row(pose, held)
        if self._file is not None:
            self._file.write(json.dumps(row) + "\n")

    def _write(self, p) -> None:
        self.samples += 1
        st = self.state
        if self._file is None and self.row_hook is None:
            return
        pose = pose_json(
            time_s=st.get("t_boot_s"), lat=_num(p.latitude_deg), lon=_num(p.longitude_deg),
            alt_amsl_m=_num(p.absolute_altitude_m), relative_alt_m=_num(p.relative_altitude_m),
            roll_deg=st.get("roll_deg"), pitch_deg=st.get("pitch_deg"), yaw_deg=st.get("yaw_deg"),
            velocity_ned_m_s=(st.get("vn_m_s"), st.get("ve_m_s"), st.get("vd_m_s")), mission_item=st["mission_item"],
            range_forward_m=self._range_at(None), **self._gimbal(),
        )
        self._emit(pose)


def read_telemetry_log(path: Path) -> list[dict]:
    """All samples of a telemetry log (a torn last line from a crash is skipped)."""
    return read_jsonl(path)

"""Telemetry recorder: keeps the latest value of each telemetry stream and writes one JSON line per position
sample, flushed as written, so a crash or a cut link loses nothing already received."""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import math
import time
from collections import deque
from pathlib import Path
from typing import IO

log = logging.getLogger(__name__)


def _num(x: float) -> float | None:
    return None if x is None or (isinstance(x, float) and not math.isfinite(x)) else x


def _attitude_at(a, b, t: float) -> tuple[float, float, float] | None:
    """Attitude at time t from the two latest ATTITUDE samples (time, roll, pitch, yaw), linear in time
    (yaw the short way round); None when the samples are missing or more than 0.5 s away."""
    if b is None or abs(b[0] - t) > 0.5:
        return None
    if a is None or b[0] <= a[0]:
        return b[1], b[2], b[3]
    s = min(1.0, max(0.0, (t - a[0]) / (b[0] - a[0])))
    dyaw = (b[3] - a[3] + 180.0) % 360.0 - 180.0
    return a[1] + s * (b[1] - a[1]), a[2] + s * (b[2] - a[2]), (a[3] + s * dyaw) % 360.0


class TelemetryRecorder:
    """Subscribes to position, attitude, velocity, mode, armed, in-air and mission progress.

    ``state`` holds the latest values; ``last_sample_wall`` the monotonic time of the last position sample
    (used to notice a silent link). ``reboot`` is set (and stays) when the autopilot's time since boot goes
    backwards: the vehicle restarted, and nothing it reports about the mission can be trusted after that.
    """

    REBOOT_BACKSTEP_S = 1.0  # time_boot_ms going back by more than this is a new boot, not reordering

    def __init__(self, vehicle, path: Path | None = None):
        self.vehicle = vehicle
        self.path = Path(path) if path else None
        self._file: IO[str] | None = None
        self.state: dict = {"mission_item": -1, "mission_total": 0, "armed": None, "in_air": None,
                            "flight_mode": None, "landed_state": None}
        # latched: the vehicle was seen in the air at some point while recording (a short flight can start and end
        # while the companion is still waiting for a slow command acknowledgement on a lossy link)
        self.was_in_air = False
        self.was_armed = False  # latched likewise: armed at some point while recording
        self.reboot: str | None = None
        self._boot_time_max: dict[str, float] = {}  # per message stream
        self.status_events: list[tuple[float, str, str]] = []  # (monotonic time, severity name, text)
        self.samples = 0
        self.last_sample_wall: float | None = None
        self._last_position = None
        self.status_texts: list[str] = []
        self._tasks: list[asyncio.Task] = []
        self.progress_event = asyncio.Event()
        self._raw_att: tuple[float, float, float, float] | None = None
        self._prev_att: tuple[float, float, float, float] | None = None
        self._raw_pos: tuple | None = None
        self._pending: deque[tuple] = deque()  # latest raw GLOBAL_POSITION_INT; once it flows, rows come from it

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
                     self._follow(m.subscribe_mission_progress(), self._on_progress)):
            self._tasks.append(asyncio.create_task(coro))
        direct = getattr(self.vehicle, "direct", None)
        if direct is not None:
            for name, handler in (("ATTITUDE", self._on_raw_att), ("GLOBAL_POSITION_INT", self._on_raw_pos)):
                self._tasks.append(asyncio.create_task(self._follow(direct.subscribe_message(name), handler)))
        return self

    async def __aexit__(self, *exc) -> None:
        while self._pending:
            self._write_row(*self._pending.popleft())
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

    def _on_progress(self, p) -> None:
        self.state.update(mission_item=p.current, mission_total=p.total)
        self.progress_event.set()

    def _on_status_text(self, s) -> None:
        text = f"{s.type.name}: {s.text}"
        self.status_texts.append(text)
        self.status_events.append((time.monotonic(), s.type.name, s.text))
        log.info("vehicle says %s", text)

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
        if changed and self._raw_pos is not None:
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
            self._on_boot_time(f["time_boot_ms"] / 1000.0, "ATTITUDE")
            self._prev_att, self._raw_att = self._raw_att, (f["time_boot_ms"] / 1000.0, roll, pitch, yaw % 360.0)
            self._flush_positions()

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
        self._pending.append(self._raw_pos)
        self._flush_positions()

    def _flush_positions(self) -> None:
        att_t = self._raw_att[0] if self._raw_att is not None else None
        while self._pending:
            t = self._pending[0][0]
            # write when the attitude after it has arrived, or when attitude is missing/stale (never hold rows long)
            if att_t is not None and t > att_t and len(self._pending) < 4:
                return
            self._write_row(*self._pending.popleft())

    def _write_row(self, t_boot, lat, lon, alt, rel, vel) -> None:
        self.samples += 1
        if self._file is None:
            return
        st = self.state
        att = _attitude_at(self._prev_att, self._raw_att, t_boot)
        if att is not None:
            roll, pitch, yaw = att
        else:
            roll, pitch, yaw = st.get("roll_deg"), st.get("pitch_deg"), st.get("yaw_deg")
        row = {
            "t_wall": round(time.time(), 4), "t_boot_s": t_boot, "lat": lat, "lon": lon,
            "alt_amsl_m": alt, "rel_alt_m": rel, "roll_deg": roll, "pitch_deg": pitch, "yaw_deg": yaw,
            "vn_m_s": vel[0], "ve_m_s": vel[1], "vd_m_s": vel[2],
            "mission_item": st["mission_item"], "mission_total": st["mission_total"],
            "flight_mode": st["flight_mode"], "armed": st["armed"], "in_air": st["in_air"],
        }
        self._file.write(json.dumps(row) + "\n")

    def _write(self, p) -> None:
        self.samples += 1
        st = self.state
        if self._file is None:
            return
        row = {
            "t_wall": round(time.time(), 4), "t_boot_s": st.get("t_boot_s"),
            "lat": _num(p.latitude_deg), "lon": _num(p.longitude_deg),
            "alt_amsl_m": _num(p.absolute_altitude_m), "rel_alt_m": _num(p.relative_altitude_m),
            "roll_deg": st.get("roll_deg"), "pitch_deg": st.get("pitch_deg"), "yaw_deg": st.get("yaw_deg"),
            "vn_m_s": st.get("vn_m_s"), "ve_m_s": st.get("ve_m_s"), "vd_m_s": st.get("vd_m_s"),
            "mission_item": st["mission_item"], "mission_total": st["mission_total"],
            "flight_mode": st["flight_mode"], "armed": st["armed"], "in_air": st["in_air"],
        }
        self._file.write(json.dumps(row) + "\n")


def read_telemetry_log(path: Path) -> list[dict]:
    """All samples of a telemetry log (a torn last line from a crash is skipped)."""
    rows = []
    with open(path) as f:
        for line in f:
            with contextlib.suppress(json.JSONDecodeError):
                rows.append(json.loads(line))
    return rows

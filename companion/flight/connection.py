"""Connecting to an autopilot through mavsdk and waiting until it is healthy enough to fly.

Kept apart from mission supervision so the onboard pipeline can reuse the same connect/health logic.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import math
from dataclasses import dataclass

import pymap3d
from mavsdk.asyncio import Autopilot, ComponentType, Configuration, Mavsdk
from mavsdk.asyncio.plugins.action import ActionAsync
from mavsdk.asyncio.plugins.mavlink_direct import MavlinkDirectAsync, MavlinkMessage
from mavsdk.asyncio.plugins.mission_raw import MissionRawAsync
from mavsdk.asyncio.plugins.param import ParamAsync
from mavsdk.asyncio.plugins.telemetry import TelemetryAsync

from companion.errors import CompanionError
from companion.flight.mavsdk_log import route_mavsdk_log

log = logging.getLogger(__name__)

MAV_CMD_SET_MESSAGE_INTERVAL = 511
MAV_CMD_DO_SET_MODE = 176
MSG_ID_MISSION_CURRENT = 42
MSG_ID_DISTANCE_SENSOR = 132
DISTANCE_SENSOR_INTERVAL_US = 1e5  # 10 Hz: the telemetry log's range_forward_m (a vehicle without one sends none)
HEALTH_FIELDS = {
    "is_global_position_ok": "global position (GPS fix)",
    "is_local_position_ok": "local position estimate",
    "is_home_position_ok": "home position",
    "is_armable": "pre-arm checks",
}


@dataclass
class Vehicle:
    """A connected autopilot and the mavsdk plugins the flight code uses."""

    mavsdk: Mavsdk
    system: object
    telemetry: TelemetryAsync
    action: ActionAsync
    mission: MissionRawAsync
    direct: MavlinkDirectAsync
    autopilot: str  # 'px4' or 'ardupilot'
    system_id: int
    param: ParamAsync | None = None
    own_system_id: int = 245  # the companion's MAVLink system id (mavsdk's ground-station default)

    async def command_long(self, command: int, *params: float) -> int:
        """Send a COMMAND_LONG through mavlink_direct; returns the MAV_RESULT of its final ACK."""
        fields = {"target_system": self.system_id, "target_component": 1, "command": command, "confirmation": 0}
        padded = list(params) + [0.0] * (7 - len(params))
        fields.update({f"param{i + 1}": float(v) for i, v in enumerate(padded)})
        msg = MavlinkMessage("COMMAND_LONG", 0, 0, self.system_id, 1, json.dumps(fields))
        return _ack_result(await self.direct.send_command(msg))

    async def send_command_int(self, command: int, frame: int, params: tuple[float, float, float, float],
                               lat: float, lon: float, alt_m: float) -> None:
        """Send one COMMAND_INT (a position as lat/lon * 1e7 integers: COMMAND_LONG's float32 params round a
        longitude near 127 degrees to 0.7 m) without waiting for its ACK: the caller confirms by telemetry. (mavsdk
        4.1's send_command aborted the process after an ACK it had already given up on, real PX4 SIH, loaded machine.)
        """
        fields = {"target_system": self.system_id, "target_component": 1, "frame": frame, "command": command,
                  "current": 0, "autocontinue": 0, "x": int(round(lat * 1e7)), "y": int(round(lon * 1e7)),
                  "z": float(alt_m)}
        fields.update({f"param{i + 1}": float(v) for i, v in enumerate(params)})
        await self.direct.send_message(MavlinkMessage("COMMAND_INT", 0, 0, self.system_id, 1, json.dumps(fields)))

    def close(self) -> None:
        self.mavsdk.destroy()


def _ack_result(ack) -> int:
    """MAV_RESULT of a COMMAND_ACK as mavlink_direct returns it (0, ACCEPTED, when it carries none)."""
    try:
        return int(json.loads(ack.fields_json).get("result", 0))
    except (AttributeError, ValueError, TypeError):
        return 0


async def connect(url: str, *, timeout_s: float = 10.0, autopilot: str = "auto") -> Vehicle:
    """Open ``url`` (e.g. ``udp://:14540``, ``tcpout://127.0.0.1:5760``) and wait for an autopilot heartbeat."""
    route_mavsdk_log()  # mavsdk's lines as whole logging records, not spliced into ours
    cfg = Configuration.create_with_component_type(ComponentType.GROUND_STATION)
    mavsdk = Mavsdk(cfg)
    try:
        await mavsdk.add_any_connection(url)
    except Exception as exc:
        mavsdk.destroy()
        raise CompanionError(f"cannot open MAVLink connection {url!r}: {exc}",
                             "use udp://:14540 (PX4 SITL), udpin://0.0.0.0:PORT or tcpout://HOST:PORT") from exc
    system = await mavsdk.first_autopilot(timeout_s=timeout_s)
    if system is None:
        mavsdk.destroy()
        raise CompanionError(
            f"no autopilot heartbeat on {url} within {timeout_s:g} s",
            "start the vehicle or simulator (e.g. `companion sim`), and check the --connect address and port")
    if autopilot == "auto":
        kind = await system.autopilot_type()
        autopilot = "ardupilot" if kind == Autopilot.ARDUPILOT else "px4"
    vehicle = Vehicle(mavsdk, system, TelemetryAsync(system), ActionAsync(system), MissionRawAsync(system),
                      MavlinkDirectAsync(system), autopilot, await system.get_system_id(), ParamAsync(system),
                      own_system_id=int(cfg.system_id))
    log.info("connected to %s autopilot (system %d) on %s as system %d", autopilot, vehicle.system_id, url,
             vehicle.own_system_id)
    return vehicle


async def request_rates(vehicle: Vehicle, rate_hz: float) -> None:
    """Ask for the telemetry the flight needs. ArduPilot streams nothing but HEARTBEAT until asked; PX4 streams
    by default, but asking makes the log density explicit. MISSION_CURRENT and DISTANCE_SENSOR (a forward
    rangefinder, if fitted) have no telemetry setter, so they are requested with MAV_CMD_SET_MESSAGE_INTERVAL."""
    t = vehicle.telemetry
    setters = [(t.set_rate_position, rate_hz), (t.set_rate_attitude_euler, rate_hz),
               (t.set_rate_velocity_ned, rate_hz), (t.set_rate_health, 1.0), (t.set_rate_gps_info, 1.0),
               (t.set_rate_in_air, 2.0), (t.set_rate_battery, 1.0), (t.set_rate_home, 0.5)]
    failed = []
    for setter, hz in setters:
        try:
            await setter(hz)
        except Exception as exc:  # one refused stream is not fatal; health checks catch what matters
            failed.append(f"{setter.__name__}: {exc}")
    with contextlib.suppress(Exception):
        await vehicle.command_long(MAV_CMD_SET_MESSAGE_INTERVAL, MSG_ID_MISSION_CURRENT, 1e6)
    with contextlib.suppress(Exception):  # ArduPilot streams a rangefinder only when asked (or by its SRn_ rates)
        await vehicle.command_long(MAV_CMD_SET_MESSAGE_INTERVAL, MSG_ID_DISTANCE_SENSOR, DISTANCE_SENSOR_INTERVAL_US)
    if failed:
        log.warning("telemetry rate requests refused: %s", "; ".join(failed))


async def wait_initialised(vehicle: Vehicle, timeout_s: float) -> bool:
    """Wait for the first SYS_STATUS: ArduPilot sends it only once the vehicle has finished its start-up
    (``GCS_MAVLINK::send_sys_status``), and before that refuses every mission upload (real ArduCopter SITL, 1 s
    after boot: NO_SPACE, "Only 0 items are supported"). PX4 sends it from the start. False on timeout."""

    async def _first():
        async for _ in vehicle.direct.subscribe_message("SYS_STATUS"):
            return

    try:
        await asyncio.wait_for(_first(), timeout_s)
        return True
    except TimeoutError:
        return False


async def check_home(vehicle: Vehicle, planned, *, max_alt_diff_m: float = 3.0, warn_distance_m: float = 50.0):
    """Compare the vehicle's home with the plan's takeoff point. Scan heights are relative to home, so a home at a
    different altitude shifts the whole scan up or down next to the wall: refuse that; warn about distance."""
    home = await vehicle.telemetry.home()
    if not all(map(math.isfinite, (home.latitude_deg, home.longitude_deg, home.absolute_altitude_m))):
        raise CompanionError("the vehicle reports no home position", "wait for a GPS fix and home, then retry")
    e, n, _ = pymap3d.geodetic2enu(home.latitude_deg, home.longitude_deg, 0.0, planned.lat, planned.lon, 0.0)
    dist = math.hypot(e, n)
    dalt = home.absolute_altitude_m - planned.alt_amsl_m
    if abs(dalt) > max_alt_diff_m:
        raise CompanionError(
            f"the vehicle's home is {dalt:+.1f} m from the planned takeoff altitude ({home.absolute_altitude_m:.1f} "
            f"vs {planned.alt_amsl_m:.1f} m AMSL): every scan height would be off by that much",
            "take off from the planned point, or set takeoff/ground altitude in the mission to the real one")
    if dist > warn_distance_m:
        log.warning("the vehicle's home is %.0f m from the planned takeoff point", dist)
    return dist, dalt


# ArduCopter 4.7 SITL uses GPS in its EKF only 35-40 s after boot (no home, not armable until then); a real
# vehicle after power-on can take longer for a 3D fix. Two minutes covers both with room.
DEFAULT_HEALTH_TIMEOUT_S = 120.0


def missing_health(last: dict) -> list[str]:
    return [HEALTH_FIELDS[k] for k in HEALTH_FIELDS if not last.get(k, False)]


async def wait_healthy(vehicle: Vehicle, timeout_s: float = DEFAULT_HEALTH_TIMEOUT_S, *, report_every_s: float = 5.0,
                       when_only_armable_missing=None) -> None:
    """Wait until GPS, position estimate, home and pre-arm checks are all good. Every ``report_every_s`` it says
    what is still missing (and the vehicle's latest message); on timeout the error names it.

    ``when_only_armable_missing``: a coroutine function called (at most every ``report_every_s``) while
    everything but "armable" is good: the vehicle may sit in a mode it cannot arm in (PX4 Return, Mission without
    a valid mission) and the caller can switch it."""
    last: dict = {}
    said: list[str] = []
    loop = asyncio.get_running_loop()
    t0 = loop.time()

    async def _watch():
        async for health in vehicle.telemetry.subscribe_health():
            last.update({k: bool(getattr(health, k)) for k in HEALTH_FIELDS})
            if all(last.values()):
                return

    async def _texts():
        async for s in vehicle.telemetry.subscribe_status_text():
            said.append(f"{s.type.name}: {s.text}")

    watcher = asyncio.create_task(_watch())
    listener = asyncio.create_task(_texts())
    last_fix = -float("inf")
    try:
        while True:
            elapsed = loop.time() - t0
            remaining = timeout_s - elapsed
            if remaining <= 0:
                break
            done, _ = await asyncio.wait({watcher}, timeout=min(report_every_s, remaining))
            if done:
                watcher.result()
                log.info("vehicle healthy after %.0f s: GPS, position estimate, home and pre-arm checks OK",
                         loop.time() - t0)
                return
            missing = missing_health(last)
            if last and missing == [HEALTH_FIELDS["is_armable"]] and when_only_armable_missing is not None \
                    and loop.time() - last_fix >= report_every_s:
                last_fix = loop.time()
                await when_only_armable_missing()
            what = ", ".join(missing) if last else "no health (SYS_STATUS) telemetry yet"
            log.info("waiting for the vehicle (%.0f of %.0f s): still missing %s%s", loop.time() - t0, timeout_s,
                     what, f" (vehicle says {said[-1]})" if said else "")
    finally:
        for task in (watcher, listener):
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await task
    what = ", ".join(missing_health(last)) if last else "no health (SYS_STATUS) telemetry at all"
    raise CompanionError(
        f"vehicle not ready to fly after {timeout_s:g} s: missing {what}"
        + (f"; the vehicle said: {'; '.join(said[-3:])}" if said else ""),
        "wait for a 3D GPS fix and home position (ArduCopter's EKF takes 35-40 s after boot), check pre-arm "
        "messages on the ground station, or raise --health-timeout")

"""The ArduCopter-flavoured simulator: the behaviours from shared/notes/ardupilot-with-mavsdk4.md, and that
companion.flight handles them (rates requested, seq-0 home, GUIDED before arming, MissionRaw verify)."""

from __future__ import annotations

import dataclasses
import math
import socket
import time

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.errors import CompanionError
from companion.flight import fly_mission_sync
from companion.mission import items as mi
from tests.sitl import SitlVehicle

pytestmark = pytest.mark.sitl
LAT, LON = 375663800, 1269781500


def _mission(takeoff_params=(0.0, 0.0, 0.0, math.nan)):
    return [
        mi.MissionItem(0, 0, mi.MAV_CMD_NAV_WAYPOINT, 1, 1, 0.0, 0.0, 0.0, 0.0, LAT, LON, 30.0),  # home placeholder
        mi.MissionItem(1, 6, mi.MAV_CMD_NAV_TAKEOFF, 0, 1, *takeoff_params, LAT, LON, 8.0),
        mi.MissionItem(2, 6, mi.MAV_CMD_NAV_WAYPOINT, 0, 1, 0.0, 0.5, 0.0, 0.0, LAT + 900, LON, 8.0),
        mi.MissionItem(3, 2, mi.MAV_CMD_NAV_RETURN_TO_LAUNCH, 0, 1, 0.0, 0.0, 0.0, 0.0, 0, 0, 0.0),
    ]


def test_ardupilot_streams_only_heartbeat_until_asked():
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        sock.settimeout(0.2)
        port = sock.getsockname()[1]
        with SitlVehicle(speedup=5, autopilot="ardupilot", mavlink_port=port):
            parser = mavlink.MAVLink(None)
            seen: set[str] = set()
            start_by = time.monotonic() + 20.0  # a loaded machine may take seconds to start the process
            end = None
            while end is None or time.monotonic() < end:
                if end is None and time.monotonic() > start_by:
                    break
                try:
                    data = sock.recv(65535)
                except TimeoutError:
                    continue
                seen.update(m.get_type() for m in parser.parse_buffer(data) or [])
                if seen and end is None:
                    end = time.monotonic() + 1.5  # 1.5 s of wall time (7.5 s simulated) after the first message
    assert seen - {"STATUSTEXT"} == {"HEARTBEAT"}  # texts are events, not streams (real: "ArduPilot Ready")


def test_ardupilot_flavour_flies_with_seq0_home(tmp_path):
    with SitlVehicle(speedup=20, autopilot="ardupilot", log_path=tmp_path / "sim.log") as v:
        result = fly_mission_sync(_mission(), v.url, progress=False, handle_signals=False, flight_timeout_s=60)
    assert result.autopilot == "ardupilot"
    assert result.completed and result.landed and result.disarmed, result
    sim_log = (tmp_path / "sim.log").read_text()
    assert "posctl -> guided" in sim_log  # switched to GUIDED before arming (BRAKE would refuse)


def test_ardupilot_refuses_nan_takeoff_params(tmp_path):
    nan = (math.nan, math.nan, math.nan, math.nan)
    sim = SitlVehicle(speedup=20, autopilot="ardupilot", log_path=tmp_path / "sim.log")
    with sim as v, pytest.raises(CompanionError) as err:
        fly_mission_sync(_mission(nan), v.url, progress=False, handle_signals=False)
    assert "rejected the mission upload (INVALID_ARGUMENT" in err.value.problem
    assert "item 1 (NAV_TAKEOFF) has param1 = nan" in err.value.problem
    assert "plan.mavlink_items('ardupilot')" in err.value.fix


def test_ardupilot_refusal_names_the_real_offending_item(tmp_path):
    """ArduCopter 4.7 refused our first missions at the gimbal item's NaN rates (seq 2), not at NAV_TAKEOFF."""
    nan_rates = mi.MissionItem(2, 2, mi.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW, 0, 1, 0.0, 0.0, math.nan, math.nan, 0, 0,
                               0.0)
    items = _mission()[:2] + [nan_rates] + [dataclasses.replace(it, seq=it.seq + 1) for it in _mission()[2:]]
    sim = SitlVehicle(speedup=20, autopilot="ardupilot", log_path=tmp_path / "sim.log")
    with sim as v, pytest.raises(CompanionError) as err:
        fly_mission_sync(items, v.url, progress=False, handle_signals=False)
    assert "item 2 (DO_GIMBAL_MANAGER_PITCHYAW) has param3 = nan" in err.value.problem
    assert "NAV_TAKEOFF" not in err.value.problem


def _texts(messages) -> list[str]:
    return [m.text.decode() if isinstance(m.text, bytes) else m.text for m in messages if m.get_type() == "STATUSTEXT"]


def test_ardupilot_refuses_uploads_and_sends_no_sys_status_while_starting_up():
    """Real ArduCopter 4.7 SITL, within about a second of boot: a MISSION_COUNT is answered NO_SPACE with "Only 0
    items are supported" (its mission storage is not initialised), and only HEARTBEAT is sent; then "ArduPilot
    Ready", SYS_STATUS once asked for, and the same upload is taken."""
    gcs = mavlink.MAVLink(None, srcSystem=245, srcComponent=190)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        sock.settimeout(0.2)
        with SitlVehicle(speedup=5, autopilot="ardupilot", mavlink_port=sock.getsockname()[1], init_s=8):
            parser = mavlink.MAVLink(None)
            got: list = []  # (monotonic time, message)
            vehicle = None
            asked_at = ready_at = None
            deadline = time.monotonic() + 60.0  # a loaded machine may take seconds to start the process
            while time.monotonic() < deadline:
                try:
                    data, vehicle = sock.recvfrom(65535)
                except TimeoutError:
                    continue
                for m in parser.parse_buffer(data) or []:
                    got.append((time.monotonic(), m))
                if asked_at is None:  # at the first heartbeat: ask for SYS_STATUS and upload, as mavsdk + companion
                    sock.sendto(gcs.command_long_encode(1, 1, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 0,
                                                        mavlink.MAVLINK_MSG_ID_SYS_STATUS, 200000, 0, 0, 0, 0, 0)
                                .pack(gcs), vehicle)
                    sock.sendto(gcs.mission_count_encode(1, 1, 3, 0).pack(gcs), vehicle)
                    asked_at = time.monotonic()
                if ready_at is None and "ArduPilot Ready" in _texts(m for _, m in got):
                    ready_at = time.monotonic()
                    sock.sendto(gcs.mission_count_encode(1, 1, 3, 0).pack(gcs), vehicle)
                if ready_at is not None and time.monotonic() > ready_at + 1.0:
                    break
    assert ready_at is not None, "the vehicle never said it was ready"
    early = [m for t, m in got if t < ready_at]
    late = [m for t, m in got if t >= ready_at]
    acks = [m for m in early if m.get_type() == "MISSION_ACK"]
    assert acks and acks[0].type == mavlink.MAV_MISSION_NO_SPACE
    assert "Only 0 items are supported" in _texts(early)
    assert {m.get_type() for m in early} <= {"HEARTBEAT", "STATUSTEXT", "MISSION_ACK", "COMMAND_ACK"}
    assert "SYS_STATUS" in {m.get_type() for m in late}
    assert any(m.get_type() == "MISSION_REQUEST_INT" and m.seq == 0 for m in late)  # the same upload, now taken


def test_companion_waits_for_the_start_up_before_it_uploads(tmp_path):
    """Against the starting-up vehicle an upload at once is refused, quoting it ("Only 0 items are supported") with
    the fix to wait; ``fly`` waits for the first SYS_STATUS (sent only once initialised), so it flies as on the real
    ArduCopter, where this wait made a fresh SITL fly the demo (docs/FLIGHT.md)."""
    import asyncio

    from companion.flight.connection import connect
    from companion.flight.status_texts import StatusTexts
    from companion.flight.upload import upload_and_verify

    async def upload_at_once(url):
        vehicle = await connect(url, timeout_s=60.0)
        try:
            async with StatusTexts(vehicle.telemetry) as texts:
                await upload_and_verify(vehicle.mission, _mission(), "ardupilot", texts=texts)
        finally:
            vehicle.close()

    early = SitlVehicle(speedup=20, autopilot="ardupilot", init_s=15, log_path=tmp_path / "early.log")
    with early as v, pytest.raises(CompanionError) as err:
        asyncio.run(upload_at_once(v.url))
    assert "(TOO_MANY_MISSION_ITEMS, 4 items); it said: WARNING: Only 0 items are supported" in err.value.problem
    assert "still starting up" in err.value.fix
    with SitlVehicle(speedup=20, autopilot="ardupilot", init_s=5, log_path=tmp_path / "sim.log") as v:
        result = fly_mission_sync(_mission(), v.url, progress=False, handle_signals=False, flight_timeout_s=120,
                                  connect_timeout_s=60)
    assert result.completed and result.landed and result.disarmed, result
    assert "mission upload refused" not in (tmp_path / "sim.log").read_text()

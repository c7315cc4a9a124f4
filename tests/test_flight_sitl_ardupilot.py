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
    assert seen == {"HEARTBEAT"}


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

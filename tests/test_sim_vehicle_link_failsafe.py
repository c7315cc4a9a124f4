"""The simulator's lost-link failsafe counts the heartbeats each real firmware counts (each flavour's
``counts_for_link_failsafe``), in process: ArduCopter only its GCS system id's (MAV_GCS_SYSID, default 255; real
ArduCopter 4.7 flew on when the companion, system 245, was killed), PX4 any MAV_TYPE_GCS heartbeat."""

from __future__ import annotations

import dataclasses
import time

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.mission import items as mi
from sim.vehicle import flavours as fl
from tests.test_sim_vehicle_firmware_rules import _mission, _run_until, _vehicle


def _from(system: int, mav_type: int = mavlink.MAV_TYPE_GCS):
    """A HEARTBEAT as the vehicle decodes it, sent by ``system``."""
    sender = mavlink.MAVLink(None, srcSystem=system, srcComponent=190)
    receiver = mavlink.MAVLink(None)
    return receiver.parse_char(sender.heartbeat_encode(mav_type, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0).pack(sender))


def _flying(autopilot: str, **params):
    v = _vehicle(autopilot=autopilot, gps_ready_after_s=0.0)
    v.params.update(params)
    items = _mission()
    if autopilot == "ardupilot":  # seq 0 is home on ArduCopter
        items = [mi.MissionItem(0, 0, mi.MAV_CMD_NAV_WAYPOINT, 0, 1, 0, 0, 0, 0, 0, 0, 0.0)] + [
            dataclasses.replace(it, seq=it.seq + 1) for it in items]
    v._on_new_mission(items)
    v.set_mode(fl.GUIDED if autopilot == "ardupilot" else fl.HOLD)
    assert v.arm() is None and v.set_mode(fl.MISSION) is None
    _run_until(v, lambda: v.model.state.pos[2] < -3.0)
    return v


def _mode_after(v, heartbeats, wall_s: float) -> str:
    """Step the vehicle for ``wall_s`` wall seconds (its failsafe runs on the wall clock, as the peer's does),
    feeding ``heartbeats`` every 50 ms; the mode it ends in (it stops at the first RTL)."""
    end = time.monotonic() + wall_s
    while time.monotonic() < end and v.mode != fl.RTL:
        for hb in heartbeats:
            v.handle(hb)
        for _ in range(5):
            v.step()
        time.sleep(0.05)
    return v.mode


def test_copter_counts_only_its_gcs_system_ids_heartbeats():
    v = _flying("ardupilot", FS_GCS_ENABLE=1, FS_GCS_TIMEOUT=0.4)
    try:
        v.handle(_from(255))  # the ground station was seen once: the failsafe is armed from now on
        # the companion (245) keeps sending: ArduCopter does not count it, so 255's silence is a lost link
        assert _mode_after(v, [_from(245)], wall_s=1.5) == fl.RTL
    finally:
        v.close()


def test_copter_with_the_companion_as_its_gcs_flies_on_while_it_is_alive_and_returns_when_it_dies():
    v = _flying("ardupilot", FS_GCS_ENABLE=1, FS_GCS_TIMEOUT=0.4, MAV_GCS_SYSID=245)
    try:
        assert _mode_after(v, [_from(245)], wall_s=1.0) == fl.MISSION
        t0 = time.monotonic()
        assert _mode_after(v, [_from(255)], wall_s=1.5) == fl.RTL  # the companion is gone; 255 does not count
        assert time.monotonic() - t0 < 1.0
    finally:
        v.close()


def test_px4_counts_gcs_type_heartbeats_from_any_system(monkeypatch):
    monkeypatch.setattr(fl, "PX4_HEARTBEAT_ALIVE_S", 0.4)  # PX4's 2.5 s, shortened for the test
    v = _flying("px4", NAV_DLL_ACT=2, COM_DL_LOSS_T=0)
    try:
        v.handle(_from(255))
        assert _mode_after(v, [_from(245)], wall_s=1.0) == fl.MISSION  # a GCS heartbeat, whatever its system id
        assert _mode_after(v, [_from(245, mavlink.MAV_TYPE_ONBOARD_CONTROLLER)], wall_s=1.5) == fl.RTL
    finally:
        v.close()


def test_px4_ignores_a_lost_link_in_mission_with_com_dll_except(monkeypatch):
    monkeypatch.setattr(fl, "PX4_HEARTBEAT_ALIVE_S", 0.2)
    v = _flying("px4", NAV_DLL_ACT=2, COM_DL_LOSS_T=0, COM_DLL_EXCEPT=1)
    try:
        v.handle(_from(255))
        assert _mode_after(v, [], wall_s=0.8) == fl.MISSION
    finally:
        v.close()


def test_copter_refuses_to_arm_until_the_companions_first_counted_heartbeat_clears_a_stale_failsafe():
    """The next flight after a killed one: MAV_GCS_SYSID put back to 255 first, so the companion's heartbeats went
    uncounted for a while, then set to 245 again. Real Copter marks the loss while disarmed (no action), refuses to
    arm while it is on ("PreArm: GCS failsafe on", AP_Arming_Copter::gcs_failsafe_check) and clears it at the next
    counted heartbeat. The sim cleared the failsafe on arming and went to RTL at take-off."""
    v = _vehicle(autopilot="ardupilot", gps_ready_after_s=0.0)
    try:
        v.params.update(FS_GCS_ENABLE=1, FS_GCS_TIMEOUT=0.3)
        v.handle(_from(255))  # a GCS seen, then only the uncounted 245 for longer than the timeout
        assert _mode_after(v, [_from(245)], wall_s=0.6) != fl.RTL and v.link_failsafe
        v.params["MAV_GCS_SYSID"] = 245
        v.set_mode(fl.GUIDED)
        assert v.arm() == "PreArm: GCS failsafe on" and not v.armable_now()
        _mode_after(v, [_from(245)], wall_s=0.1)  # the companion's next heartbeat, now counted
        assert not v.link_failsafe
        items = [mi.MissionItem(0, 0, mi.MAV_CMD_NAV_WAYPOINT, 0, 1, 0, 0, 0, 0, 0, 0, 0.0)] + [
            dataclasses.replace(it, seq=it.seq + 1) for it in _mission()]
        v._on_new_mission(items)
        assert v.arm() is None and v.set_mode(fl.MISSION) is None
        _run_until(v, lambda: v.model.state.pos[2] < -3.0)
        assert _mode_after(v, [_from(245)], wall_s=0.3) == fl.MISSION
    finally:
        v.close()


def test_copter_has_no_gcs_id_range_as_real_arducopter_4_7_dev():
    """Real ArduCopter V4.7.0-dev SITL (2598e9d4) has MAV_GCS_SYSID and no MAV_GCS_SYSID_HI: a read of it went
    unanswered and the GCS failsafe compares the sender with MAV_GCS_SYSID alone (GCS_Common.cpp). The simulator
    had the range."""
    v = _vehicle(autopilot="ardupilot", gps_ready_after_s=0.0)
    try:
        assert "MAV_GCS_SYSID" in v.params and "MAV_GCS_SYSID_HI" not in v.params
        rule = v.flavour.counts_for_link_failsafe
        assert rule({"MAV_GCS_SYSID": 245}, _from(245), 1)
        assert not rule({"MAV_GCS_SYSID": 240, "MAV_GCS_SYSID_HI": 250}, _from(245), 1)
    finally:
        v.close()

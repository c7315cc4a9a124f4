"""The simulator's firmware behaviours that decide how a flight starts and ends (sim/vehicle/firmware.py), in
process: each one as seen on real PX4 main (2026-03) / ArduCopter 4.7 SITL (shared/notes/real-firmware.md)."""

from __future__ import annotations

import numpy as np

from companion.mission import items as mi
from sim.vehicle import flavours as fl
from sim.vehicle.autopilot import SimVehicle, VehicleConfig
from sim.vehicle.firmware import lost_link_action

HOME_X, HOME_Y = 375663800, 1269781500


def _mission(north_e7: int = 900) -> list[mi.MissionItem]:
    nan = float("nan")
    return [
        mi.MissionItem(0, 6, mi.MAV_CMD_NAV_TAKEOFF, 1, 1, 0.0, 0.0, 0.0, nan, HOME_X, HOME_Y, 6.0),
        mi.MissionItem(1, 2, mi.MAV_CMD_DO_CHANGE_SPEED, 0, 1, 1.0, 3.0, -1.0, 0.0, 0, 0, 0.0),
        mi.MissionItem(2, 6, mi.MAV_CMD_NAV_WAYPOINT, 0, 1, 0.0, 0.5, 0.0, 0.0, HOME_X + north_e7, HOME_Y, 6.0),
        mi.MissionItem(3, 6, mi.MAV_CMD_NAV_WAYPOINT, 0, 1, 0.0, 0.5, 0.0, 0.0, HOME_X, HOME_Y, 6.0),
        mi.MissionItem(4, 6, mi.MAV_CMD_NAV_LAND, 0, 1, 0.0, 0.0, 0.0, nan, 0, 0, 0.0),
    ]


def _vehicle(**kw) -> SimVehicle:
    """Home kept where it armed (``home_shift_m`` 0): these rules are not about PX4's home correction, whose moves
    would shift every relative altitude (tests/test_sim_vehicle_home.py)."""
    return SimVehicle(VehicleConfig(pose_port=None, target=("127.0.0.1", 9), **{"home_shift_m": 0.0, **kw}))


def _run_until(v: SimVehicle, done, max_s: float = 120.0) -> None:
    for _ in range(int(max_s / 0.02)):
        v.step()
        if done():
            return
    raise AssertionError("condition not reached in simulated time")


def test_px4_keeps_its_current_item_when_the_same_mission_is_uploaded_again():
    v = _vehicle()
    try:
        v._on_new_mission(_mission())
        assert v.arm() is None and v.set_mode(fl.MISSION) is None
        _run_until(v, lambda: v.mission_seq >= 3)
        v.set_mode(fl.HOLD)
        v._on_new_mission(_mission())  # identical: the `current` flag on item 0 does not reset it
        assert v.mission_seq == 3
        v._on_new_mission(_mission(north_e7=1800))  # a different mission starts from its first item
        assert v.mission_seq == 0
    finally:
        v.close()


def test_ardupilot_resets_its_current_item_on_every_upload():
    v = _vehicle(autopilot="ardupilot", gps_ready_after_s=0.0)
    try:
        items = [mi.MissionItem(0, 0, mi.MAV_CMD_NAV_WAYPOINT, 0, 1, 0, 0, 0, 0, HOME_X, HOME_Y, 30.0)] + [
            mi.MissionItem(it.seq + 1, it.frame, it.command, 0, 1, it.param1, it.param2, it.param3,
                           0.0 if it.param4 != it.param4 else it.param4, it.x, it.y, it.z) for it in _mission()]
        v._on_new_mission(items)
        v.mission_seq = 3
        v._on_new_mission(items)
        assert v.mission_seq == 1
    finally:
        v.close()


def test_px4_storage_keeps_mission_and_current_item_across_a_restart(tmp_path):
    store = tmp_path / "px4-dataman.json"
    v = _vehicle(storage=store)
    try:
        v._on_new_mission(_mission())
        v._set_current(2)
    finally:
        v.close()
    again = _vehicle(storage=store)
    try:
        assert len(again.mission) == 5 and again.mission_seq == 2
        again._on_new_mission(_mission())
        assert again.mission_seq == 2  # the re-fly of the same mission would resume at item 2
    finally:
        again.close()


def test_mission_outside_px4_geofence_is_accepted_then_refused_at_takeoff_and_disarms():
    v = _vehicle(geofence_max_dist_m=5.0)
    texts = []
    v.statustext = lambda severity, text: texts.append((severity, text))
    try:
        v._on_new_mission(_mission(north_e7=900))  # ~10 m north: outside a 5 m fence
        assert v.arm() is None
        assert v.set_mode(fl.MISSION) is None  # the start is accepted ...
        _run_until(v, lambda: not v.armed, max_s=30.0)
        assert v.on_ground and not v.took_off  # ... but it never left the ground and disarmed there
        assert 9.9 <= v.t <= 10.5  # after COM_DISARM_PRFLT
        said = [t for _, t in texts]
        # what real PX4 main said (GF_MAX_HOR_DIST 5, docs/FLIGHT.md), tab-terminated as PX4's texts are
        assert said[:2] == ["Geofence violation for waypoint 3\t", "Switching to Mission is currently not available\t"]
    finally:
        v.close()


def test_reboot_restarts_the_clock_on_the_ground_and_keeps_the_px4_mission():
    v = _vehicle()
    try:
        v._on_new_mission(_mission())
        v.arm()
        v.set_mode(fl.MISSION)
        _run_until(v, lambda: v.mission_seq >= 3)
        before = v.t
        v.reboot()
        assert v.t == 0.0 < before and not v.armed and v.on_ground
        assert v.mission_seq == 3 and len(v.mission) == 5
        assert v._global_position().time_boot_ms < 100  # time_boot_ms starts again
        assert np.linalg.norm(v.model.state.pos) == 0.0
    finally:
        v.close()


def test_ardupilot_refuses_to_arm_with_a_prearm_text_until_its_ekf_uses_gps():
    v = _vehicle(autopilot="ardupilot")
    try:
        v.set_mode(fl.GUIDED)
        assert v.arm() == "PreArm: Need Position Estimate"
        assert not v._sys_status().onboard_control_sensors_health & (1 << 28)  # pre-arm check bit clear
        _run_until(v, lambda: v.position_ready, max_s=60.0)
        assert 35.0 <= v.t <= 40.0  # what the real 4.7 SITL took
        assert v.arm() is None
    finally:
        v.close()


def test_px4_does_not_arm_in_return_mode_nor_in_mission_mode_without_a_mission():
    v = _vehicle()
    try:
        v.set_mode(fl.RTL)
        assert v.arm() is not None and not v.armable_now()
        v.mode = fl.MISSION
        assert v.arm() is not None and not v.armable_now()
        v.set_mode(fl.HOLD)
        assert v.armable_now() and v.arm() is None
    finally:
        v.close()


def test_failsafe_parameters_have_the_firmware_defaults():
    px4, copter = _vehicle(), _vehicle(autopilot="ardupilot")
    try:
        assert px4.params["NAV_DLL_ACT"] == 0 and px4.params["RTL_RETURN_ALT"] == 30.0
        assert copter.params["FS_GCS_ENABLE"] == 0 and copter.params["RTL_ALT"] == 1500
        assert isinstance(px4.params["NAV_DLL_ACT"], int) and isinstance(copter.params["RTL_ALT"], int)
        assert lost_link_action("px4", px4.params) is None  # disabled: keeps flying the mission
        assert lost_link_action("ardupilot", copter.params) is None
        assert lost_link_action("px4", {"NAV_DLL_ACT": 2}) == "rtl"
        assert lost_link_action("ardupilot", {"FS_GCS_ENABLE": 1}) == "rtl"
        assert lost_link_action("ardupilot", {"FS_GCS_ENABLE": 2}) is None  # continue in AUTO
    finally:
        px4.close()
        copter.close()


def test_px4_accepts_a_waypoint_within_nav_mc_alt_rad_of_its_altitude():
    """PX4 accepts a multicopter waypoint within its acceptance radius horizontally and NAV_MC_ALT_RAD (0.8 m)
    vertically (MissionBlock::is_mission_item_reached): real PX4 SIH turned 0.6-1.0 m above the bottom of the demo's
    last strip and climbed back up it (three logs, docs/FLIGHT.md). The simulator took the 0.3 m acceptance radius
    in 3D and went down to 0.1 m above it."""
    nan = float("nan")
    items = [mi.MissionItem(0, 6, mi.MAV_CMD_NAV_TAKEOFF, 1, 1, 0.0, 0.0, 0.0, nan, HOME_X, HOME_Y, 12.0),
             mi.MissionItem(1, 2, mi.MAV_CMD_DO_CHANGE_SPEED, 0, 1, 1.0, 0.716, -1.0, 0.0, 0, 0, 0.0),
             mi.MissionItem(2, 6, mi.MAV_CMD_NAV_WAYPOINT, 0, 1, 0.5, 0.3, 0.0, 0.0, HOME_X, HOME_Y, 2.0),
             mi.MissionItem(3, 6, mi.MAV_CMD_NAV_WAYPOINT, 0, 1, 0.5, 0.3, 0.0, 0.0, HOME_X, HOME_Y, 12.0),
             mi.MissionItem(4, 6, mi.MAV_CMD_NAV_LAND, 0, 1, 0.0, 0.0, 0.0, nan, 0, 0, 0.0)]
    def lowest_turn(params) -> float:
        v = _vehicle(params={"MPC_Z_V_AUTO_UP": 0.716, "MPC_Z_V_AUTO_DN": 0.716, **params})
        try:
            v._on_new_mission(v.flavour.transform_upload(items, v.home_item))
            assert v.arm() is None and v.set_mode(fl.MISSION) is None
            lowest = np.inf
            while v.mission_seq < 4 and v.t < 200.0:
                v.step()
                if v.mission_seq in (2, 3):
                    lowest = min(lowest, -float(v.model.state.pos[2]))
            assert v.mission_seq == 4
            return lowest
        finally:
            v.close()

    assert 2.0 + 0.3 < lowest_turn({}) < 2.0 + 0.8  # turned back above the strip's end, inside NAV_MC_ALT_RAD
    assert 2.0 < lowest_turn({"NAV_MC_ALT_RAD": 0.3}) < 2.0 + 0.3  # the companion's setting for a flight

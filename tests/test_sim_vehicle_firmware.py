"""The simulator follows the real firmware, not the planner: what ArduCopter 4.7 and PX4 main accept and hand back
(the recorded real uploads/downloads in ../shared/data/real-firmware/), Copter's heading rules and both firmwares'
climb/descent speeds. In process, no MAVLink peer."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.geo import GeoPoint
from companion.mission import firmware as fw
from companion.mission import items as mi
from companion.mission import load_mission, plan_scan
from companion.mission.autopilot import flight_parameters
from sim.evaluate_scan import scan_leg_reports, worst
from sim.vehicle import flavours as fl
from sim.vehicle.autopilot import SimVehicle, VehicleConfig
from sim.vehicle.mission_server import MissionServer
from tests.sitl import small_demo_plan
from tests.test_flight_verify_real import FIRMWARE, MISSIONS, REAL, recorded

ROOT = fw.__file__.rsplit("/companion/", 1)[0]


class _Gcs:
    """A ground station talking to one flavour's mission server, as the recording did (pymavlink, MAVLink 2)."""

    def __init__(self, flavour, home_item):
        self.vehicle = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
        self.gcs = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
        self.out = []
        self.server = MissionServer(self.vehicle, self.out.append, flavour.validate, lambda items: None,
                                    transform_upload=lambda items: flavour.transform_upload(items, home_item),
                                    transform_download=lambda items: flavour.transform_download(items, home_item))

    def send(self, msg):
        for m in self.vehicle.parse_buffer(msg.pack(self.gcs)) or []:
            self.server.handle(m)
        out, self.out[:] = list(self.out), []
        # what went over the wire, decoded by the GCS (float32 fields included)
        return [self.gcs.parse_char(m.pack(self.vehicle)) for m in out]

    def upload(self, items) -> tuple[list[int], object]:
        requested = []
        replies = self.send(self.gcs.mission_count_encode(1, 1, len(items), 0))
        while replies[0].get_type() != "MISSION_ACK":
            seq = replies[0].seq
            requested.append(seq)
            it = items[seq]
            replies = self.send(self.gcs.mission_item_int_encode(
                1, 1, it.seq, it.frame, it.command, it.current, it.autocontinue, it.param1, it.param2, it.param3,
                it.param4, it.x, it.y, it.z, 0))
        return requested, replies[0]

    def download(self) -> list:
        (count,) = self.send(self.gcs.mission_request_list_encode(1, 1, 0))
        return [self.send(self.gcs.mission_request_int_encode(1, 1, seq, 0))[0] for seq in range(count.count)]


def _home_item(autopilot, mission):
    """The vehicle's home as the real download reported it (ArduCopter hands home back at seq 0)."""
    if autopilot != "ardupilot":
        return mi.MissionItem(0, 0, 16, 0, 1, 0.0, 0.0, 0.0, 0.0, 0, 0, 0.0)
    return recorded(autopilot, mission, "downloaded")[0]


@pytest.mark.parametrize("mission", MISSIONS)
@pytest.mark.parametrize("autopilot", sorted(FIRMWARE))
def test_download_returns_what_the_real_firmware_returned(autopilot, mission):
    gcs = _Gcs(fl.FLAVOURS[autopilot](), _home_item(autopilot, mission))
    _, ack = gcs.upload(recorded(autopilot, mission, "uploaded"))
    assert ack.type == mavlink.MAV_MISSION_ACCEPTED
    got = gcs.download()
    real = json.loads((REAL / FIRMWARE[autopilot] / f"{mission}.downloaded.json").read_text())
    assert len(got) == len(real)
    for msg, want in zip(got, real, strict=True):
        for key in ("seq", "frame", "command", "current", "autocontinue", "x", "y", "mission_type"):
            assert getattr(msg, key) == want[key], (want["seq"], key)
        for key in ("param1", "param2", "param3", "param4", "z"):
            value = getattr(msg, key)
            if want[key] is None:
                assert math.isnan(value), (want["seq"], key)
            else:
                assert value == want[key], (want["seq"], key, value, want[key])  # float32 exact


@pytest.mark.parametrize("mission", MISSIONS)
def test_copter_refuses_the_planned_nan_where_the_real_one_did(mission):
    """upload-as-planned.txt: requests for seq 0..2, then MAV_MISSION_INVALID_PARAM3 (the gimbal item's rates)."""
    planned_path = REAL / FIRMWARE["ardupilot"] / f"{mission}.planned.json"
    if not planned_path.exists():
        pytest.skip("recorded real-firmware data not found")
    from tests.test_flight_verify_real import load_items
    gcs = _Gcs(fl.ArduCopter(), _home_item("ardupilot", mission))
    requested, ack = gcs.upload(load_items(planned_path))
    assert requested == [0, 1, 2] and ack.type == mavlink.MAV_MISSION_INVALID_PARAM3
    # PX4 accepts the same NaN params
    requested, ack = _Gcs(fl.Px4(), _home_item("px4", mission)).upload(recorded("px4", mission, "uploaded"))
    assert ack.type == mavlink.MAV_MISSION_ACCEPTED


def test_copter_nan_rule_per_command():
    copter = fl.ArduCopter()
    nan = math.nan
    wp = mi.MissionItem(3, 6, mi.MAV_CMD_NAV_WAYPOINT, 0, 1, 0.0, 0.0, 0.0, nan, 375663800, 1269781500, 5.0)
    assert copter.validate(wp, 3) is None  # yaw NaN is allowed on a waypoint
    assert copter.validate(dataclasses.replace(wp, param2=nan), 3) == mavlink.MAV_MISSION_INVALID_PARAM2
    assert copter.validate(dataclasses.replace(wp, param4=math.inf), 3) == mavlink.MAV_MISSION_INVALID_PARAM4
    speed = mi.MissionItem(4, 2, mi.MAV_CMD_DO_CHANGE_SPEED, 0, 1, 1.0, 2.0, -1.0, nan, 0, 0, 0.0)
    assert copter.validate(speed, 4) == mavlink.MAV_MISSION_INVALID_PARAM4
    land = mi.MissionItem(5, 6, mi.MAV_CMD_NAV_LAND, 0, 1, 0.0, 0.0, 0.0, nan, 0, 0, 0.0)
    assert copter.validate(land, 5) is None
    assert fl.Px4().validate(speed, 4) is None


# --- flying -----------------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def small_plan():
    """The demo mission shrunk to an 8 m x 6 m wall: 4 vertical strips."""
    return small_demo_plan()


def fly_in_process(plan, autopilot: str, items, params=None, home: GeoPoint | None = None, limit_s: float = 900.0):
    """Fly ``items`` (stored as the flavour stores them) from the ground to disarm; returns the true poses. Home stays
    where it armed (``home_shift_m`` 0): the small plan starts its scan at once, with no hold for PX4's home."""
    v = SimVehicle(VehicleConfig(home=home or plan.home, autopilot=autopilot, pose_port=None,
                                 target=("127.0.0.1", 9), params=params or {}, home_shift_m=0.0))
    try:
        v._on_new_mission(v.flavour.transform_upload(list(items), v.home_item))
        if autopilot == "ardupilot":
            v.set_mode(fl.GUIDED)
        while v.arm() is not None and v.t < 120.0:  # ArduCopter's EKF uses GPS only ~35-40 s after boot
            v.step()
        assert v.armed
        assert v.set_mode(fl.MISSION) is None
        poses = []
        while v.t < limit_s:
            v.step()
            poses.append(v.true_pose())
            if not v.armed and v.took_off:
                break
        assert v.mission_finished and not v.armed, "the flight did not finish"
        return poses
    finally:
        v.close()


def _without(items, drop):
    kept = [it for k, it in enumerate(items) if not drop(k, it)]
    return [dataclasses.replace(it, seq=k) for k, it in enumerate(kept)]


def test_copter_as_first_flown_faces_along_the_wall_and_climbs_at_wpnav_speeds():
    """The recorded real upload (waypoint yaw in param4, DO_CHANGE_SPEED type 1 only): real Copter flew it 90 degrees
    off the wall, 2.3-2.5 m/s up and 1.5 m/s down; so must the simulator."""
    plan = plan_scan(load_mission(f"{ROOT}/missions/demo-facade.yaml")).for_autopilot("ardupilot")
    items = recorded("ardupilot", "demo-facade", "uploaded")
    home = recorded("ardupilot", "demo-facade", "downloaded")[0]
    reports = scan_leg_reports(plan, fly_in_process(plan, "ardupilot", items,
                                                    home=GeoPoint(home.x / 1e7, home.y / 1e7, plan.home.alt_amsl_m)))
    assert len(reports) == plan.estimates.strips == 13 and all(r.samples > 20 for r in reports)
    assert all(abs(r.max_yaw_error_deg - 90.0) < 3.0 for r in reports[1:])  # along the wall, not at it
    for r in reports:
        i, j = plan.scan_legs[r.leg]
        climbing = plan.waypoints[j].rel_alt_m > plan.waypoints[i].rel_alt_m
        want = 2.5 if climbing else 1.5  # WPNAV_SPEED_UP / WPNAV_SPEED_DN, not the planned 0.716 m/s
        assert abs(r.median_speed_m_s - want) / want < 0.15, r


def test_copter_flies_the_planned_items_facing_the_wall_at_the_scan_speed(small_plan):
    """Default WP_YAW_BEHAVIOR (2): the CONDITION_YAW before each waypoint holds the heading (verify_yaw re-asserts
    FIXED); DO_CHANGE_SPEED types 2/3 set the climb and descent speed."""
    reports = scan_leg_reports(small_plan, fly_in_process(small_plan, "ardupilot",
                                                          small_plan.mavlink_items("ardupilot")))
    speed_error, yaw_error = worst(reports)
    assert len(reports) == small_plan.estimates.strips and yaw_error < 3.0 and speed_error < 0.15, reports


def test_copter_keeps_a_condition_yaw_across_waypoints_only_with_wp_yaw_behavior_0(small_plan):
    items = small_plan.mavlink_items("ardupilot")
    first_yaw = next(k for k, it in enumerate(items) if it.command == mi.MAV_CMD_CONDITION_YAW)
    one_yaw = _without(items, lambda k, it: it.command == mi.MAV_CMD_CONDITION_YAW and k != first_yaw)
    held = scan_leg_reports(small_plan, fly_in_process(small_plan, "ardupilot", one_yaw, {"WP_YAW_BEHAVIOR": 0}))
    assert worst(held)[1] < 3.0  # FIXED persists with WP_YAW_BEHAVIOR = 0 (ModeAuto::wp_start)
    reset = scan_leg_reports(small_plan, fly_in_process(small_plan, "ardupilot", one_yaw))
    assert worst(reset)[1] > 80.0  # reset to "face next waypoint" at each waypoint: the hops turn it along the wall


def test_px4_climbs_at_its_auto_speeds_unless_the_parameters_are_set(small_plan):
    items = small_plan.mavlink_items("px4")
    default = scan_leg_reports(small_plan, fly_in_process(small_plan, "px4", items))
    v = small_plan.estimates.scan_speed_m_s
    assert all(r.median_speed_m_s > 1.3 for r in default)  # MPC_Z_V_AUTO_UP 3 / _DN 1.5, not DO_CHANGE_SPEED
    params = flight_parameters(small_plan, "px4")
    tuned = scan_leg_reports(small_plan, fly_in_process(small_plan, "px4", items, params))
    speed_error, yaw_error = worst(tuned)
    assert speed_error < 0.15 and yaw_error < 3.0, tuned
    assert np.median([r.median_speed_m_s for r in tuned]) == pytest.approx(v, rel=0.05)


def test_px4_strips_end_where_planned_only_with_nav_mc_alt_rad_set_for_the_flight(small_plan):
    """PX4 accepts a waypoint within NAV_MC_ALT_RAD (0.8 m) vertically: real PX4 SIH turned its strips up to 1 m
    before their ends. The speed parameters alone leave that (the simulator turns about 0.25 m early on these legs);
    the plan's NAV_MC_ALT_RAD (its 0.3 m acceptance radius) brings every strip's end to within 0.15 m."""
    items = small_plan.mavlink_items("px4")
    params = flight_parameters(small_plan, "px4")
    assert params["NAV_MC_ALT_RAD"] == 0.3
    speeds_only = {k: v for k, v in params.items() if k != "NAV_MC_ALT_RAD"}
    before = scan_leg_reports(small_plan, fly_in_process(small_plan, "px4", items, speeds_only))
    after = scan_leg_reports(small_plan, fly_in_process(small_plan, "px4", items, params))
    assert max(r.end_short_m for r in before) > 0.2, before
    assert all(r.end_short_m < 0.15 for r in after), after
    assert worst(after)[0] < 0.15

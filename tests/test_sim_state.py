"""SIM_STATE -> pose channel (issue 26): ArduPilot SITL's truth message read with its quirks (lat/lon floats that
hold degE7, int32 extensions, yaw in radians wrapped to +-pi), and the simulator's ArduPilot flavour sending it
from the TRUE state as ArduPilot does, so a camera fed through the bridge sees a GNSS bias."""

from __future__ import annotations

import math

import pymap3d
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.geo import FacadeFrame, GeoPoint
from sim.camera.live import camera_pose
from sim.pose_bridge import BridgeConfig, PoseBridge
from sim.sim_state import Gimbal, Home, gimbal_from_mount_status, pose_from_sim_state, sim_state_lat_lon, yaw_0_360
from sim.vehicle.autopilot import SimVehicle, VehicleConfig

HOME = (37.56638, 126.97815, 30.0)


def _fields(**over) -> dict:
    """A SIM_STATE as ArduPilot SITL sends it at HOME, heading 250 deg (yaw -110 deg), level."""
    f = {"q1": 1.0, "q2": 0.0, "q3": 0.0, "q4": 0.0, "roll": math.radians(2.0), "pitch": math.radians(-3.0),
         "yaw": math.radians(-110.0), "xacc": 0.0, "yacc": 0.0, "zacc": -9.8, "xgyro": 0.0, "ygyro": 0.0,
         "zgyro": 0.0, "lat": HOME[0] * 1e7, "lon": HOME[1] * 1e7, "alt": HOME[2], "std_dev_horz": 0.0,
         "std_dev_vert": 0.0, "vn": 1.0, "ve": -2.0, "vd": 0.5, "lat_int": 375663801, "lon_int": 1269781502}
    f.update(over)
    return f


def _wire(fields: dict) -> dict:
    """``fields`` through MAVLink 2 encoding and decoding (float32 fields, extensions truncated when zero)."""
    keys = [k for k in _fields() if k in fields]
    msg = mavlink.MAVLink_sim_state_message(*(fields[k] for k in keys))
    buf = msg.pack(mavlink.MAVLink(None, srcSystem=1, srcComponent=1))
    return mavlink.MAVLink(None).decode(bytearray(buf)).to_dict()


def test_the_int_extensions_give_the_exact_position():
    assert sim_state_lat_lon(_wire(_fields())) == (37.5663801, 126.9781502)


def test_without_extensions_the_degE7_floats_are_read_as_degE7():
    """ArduPilot's floats carry degrees * 1e7 (float32: ~0.3 m steps); an older sender leaves the extensions out."""
    lat, lon = sim_state_lat_lon(_wire(_fields(lat_int=0, lon_int=0)))
    assert (lat, lon) == pytest.approx(HOME[:2], abs=5e-6)
    assert (lat, lon) != pytest.approx(HOME[:2], abs=1e-9)  # float32 really did round them


def test_a_sender_of_real_degrees_is_read_as_degrees():
    """MAVLink's own definition says degrees: a sender that follows it is not divided by 1e7."""
    assert sim_state_lat_lon({"lat": -33.5, "lon": 151.25}) == (-33.5, 151.25)
    assert sim_state_lat_lon({"lat": -33.5e7, "lon": 151.25e7}) == pytest.approx((-33.5, 151.25))
    assert sim_state_lat_lon({"lat": 45.0e7, "lon": 5.0}) == pytest.approx((45.0, 5.0e-7))  # either out of range


def test_yaw_wraps_into_0_360_clockwise_from_north():
    assert yaw_0_360(math.radians(-110.0)) == pytest.approx(250.0)
    assert yaw_0_360(math.pi) == pytest.approx(180.0)
    assert yaw_0_360(0.0) == 0.0


def test_the_pose_line_has_the_keys_the_camera_reads():
    pose = pose_from_sim_state(_wire(_fields()), t_s=12.3456, gimbal=Gimbal(-10.0, 5.0), home=Home(*HOME))
    assert pose["t_s"] == 12.3456 and pose["time_boot_ms"] == 12346
    assert (pose["lat"], pose["lon"], pose["alt_amsl_m"]) == pytest.approx((37.5663801, 126.9781502, 30.0))
    assert pose["yaw_deg"] == pytest.approx(250.0, abs=1e-4)
    assert (pose["roll_deg"], pose["pitch_deg"]) == pytest.approx((2.0, -3.0), abs=1e-4)
    assert (pose["vn_m_s"], pose["ve_m_s"], pose["vd_m_s"]) == (1.0, -2.0, 0.5)
    assert (pose["gimbal_pitch_deg"], pose["gimbal_yaw_deg"]) == (-10.0, 5.0)
    assert pose["home"] == {"lat": HOME[0], "lon": HOME[1], "alt_amsl_m": HOME[2]}
    frame = FacadeFrame.from_wall(GeoPoint(*HOME), GeoPoint(HOME[0], HOME[1] + 1e-4, HOME[2]))
    cam = camera_pose(pose, frame)  # the camera takes it as it is
    assert cam.yaw_deg == pytest.approx(255.0, abs=1e-4) and cam.pitch_deg == -10.0


def test_a_position_that_is_not_finite_is_no_pose():
    assert pose_from_sim_state(_fields(lat_int=0, lon_int=0, alt=float("nan")), t_s=1.0) is None


def test_mount_status_gives_the_gimbal_relative_to_the_vehicle():
    assert gimbal_from_mount_status({"pointing_a": -4500, "pointing_b": 0, "pointing_c": 1000}) == Gimbal(-45.0, 10.0)


def _msg(name: str, **fields):
    cls = next(c for c in mavlink.mavlink_map.values() if c.msgname == name)
    names = cls.fieldnames
    msg = cls(*(fields.get(k, 0) for k in names))
    msg._header = mavlink.MAVLink_header(cls.id, srcSystem=1, srcComponent=1)
    return msg


def test_the_bridge_stamps_sim_state_with_the_latest_autopilot_clock():
    bridge = PoseBridge(BridgeConfig(connect="udpin:127.0.0.1:0"))
    try:
        bridge.target = (1, 1)
        sim_state = _msg("SIM_STATE", **_fields())
        assert bridge.handle(sim_state) is None and bridge.unstamped == 1  # no clock yet: no time to give it
        bridge.handle(_msg("ATTITUDE", time_boot_ms=4020))
        bridge.handle(_msg("HOME_POSITION", latitude=375663800, longitude=1269781500, altitude=30000))
        pose = bridge.handle(sim_state)
        assert pose["t_s"] == 4.02 and pose["home"]["alt_amsl_m"] == 30.0
        assert (pose["gimbal_pitch_deg"], pose["gimbal_yaw_deg"]) == (0.0, 0.0)  # level and forward by default
        bridge.handle(_msg("MOUNT_STATUS", pointing_a=-3000, pointing_c=0))
        assert bridge.handle(sim_state) is None and bridge.same_clock == 1  # the clock has not moved: no 2nd pose
        bridge.handle(_msg("ATTITUDE", time_boot_ms=4040))
        assert bridge.handle(sim_state)["gimbal_pitch_deg"] == -30.0
        other = _msg("SIM_STATE", **_fields())
        other._header = mavlink.MAVLink_header(other.id, srcSystem=7, srcComponent=1)
        assert bridge.handle(other) is None  # another vehicle on the link
    finally:
        bridge.close()


# --- the simulator's ArduPilot flavour ------------------------------------------------------------------------------
def _vehicle(autopilot: str, **cfg) -> SimVehicle:
    return SimVehicle(VehicleConfig(autopilot=autopilot, pose_port=None, target=("127.0.0.1", 9),
                                    home=GeoPoint(*HOME), **cfg))


def test_ardupilot_flavour_sends_sim_state_from_the_truth_not_the_biased_estimate():
    v = _vehicle("ardupilot", gnss_bias_enu_m=(0.0, -1.5, 0.0), home_yaw_deg=250.0)
    try:
        assert v._set_interval(mavlink.MAVLINK_MSG_ID_SIM_STATE, 20000)
        assert v._set_interval(mavlink.MAVLINK_MSG_ID_SIMSTATE, 20000)
        truth = v.true_pose()
        m = _wire(v._sim_state().to_dict())
        assert (m["lat_int"], m["lon_int"]) == (int(truth["lat"] * 1e7), int(truth["lon"] * 1e7))
        assert (m["lat"], m["lon"]) == pytest.approx((truth["lat"] * 1e7, truth["lon"] * 1e7), rel=1e-7)  # degE7
        assert m["alt"] == pytest.approx(truth["alt_amsl_m"])
        assert m["yaw"] == pytest.approx(math.radians(-110.0), abs=1e-6)  # wrapped as ArduPilot does
        pose = pose_from_sim_state(m, t_s=0.0)
        n, e, _ = pymap3d.geodetic2ned(truth["nav_lat"], truth["nav_lon"], HOME[2], pose["lat"], pose["lon"], HOME[2])
        assert (float(n), float(e)) == pytest.approx((-1.5, 0.0), abs=0.02)  # the estimate is the bias away
        s = v._simstate()
        assert (s.lat, s.lng) == (m["lat_int"], m["lon_int"]) and s.yaw == pytest.approx(m["yaw"])
    finally:
        v.close()


def test_px4_flavour_refuses_sim_state_as_px4_sih_has_none():
    v = _vehicle("px4")
    try:
        assert not v._set_interval(mavlink.MAVLINK_MSG_ID_SIM_STATE, 20000)
        assert v._requested(mavlink.MAVLINK_MSG_ID_SIM_STATE) is None
        assert "SIM_STATE" not in v.rates
    finally:
        v.close()

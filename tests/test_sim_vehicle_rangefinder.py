"""The simulator's forward rangefinder (issue 26): DISTANCE_SENSOR measures the wall from the TRUE position, so
with a GNSS bias it says what the estimate cannot."""

from __future__ import annotations

import argparse
import math
import socket
import time

import numpy as np
import pymap3d
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.geo import GeoPoint
from companion.mission import load_mission
from companion.mission.geometry import wall_ends
from sim.process import SimulatorProcess, with_mission_wall
from sim.vehicle import flavours as fl
from sim.vehicle.autopilot import SimVehicle, VehicleConfig
from sim.vehicle.cli import add_arguments, config_from_args
from sim.vehicle.rangefinder import WallNed, WallSpec, forward_ray, parse_wall
from tests.sitl import ROOT, SitlVehicle

HOME = GeoPoint(37.56638, 126.97815, 30.0)


def _wall_north(distance_m: float, half_width_m: float = 10.0, base_alt: float = 29.0, height_m: float = 10.0):
    """A west->east wall ``distance_m`` north of home (its drone side faces south, towards home)."""
    ends = [pymap3d.ned2geodetic(distance_m, e, 0.0, HOME.lat, HOME.lon, HOME.alt_amsl_m)
            for e in (-half_width_m, half_width_m)]
    return WallSpec(GeoPoint(ends[0][0], ends[0][1], base_alt), GeoPoint(ends[1][0], ends[1][1], base_alt), height_m)


def test_the_ray_meets_the_wall_rectangle_or_nothing():
    wall = WallNed.from_spec(_wall_north(10.0), HOME)  # base 1 m below home, 10 m high: down from -9 to +1
    at = np.array([0.0, 0.0, -5.0])
    assert wall.ray_distance(at, forward_ray(0.0, 0.0)) == pytest.approx(10.0, abs=1e-3)
    assert wall.ray_distance(at, forward_ray(30.0, 0.0)) == pytest.approx(10.0 / math.cos(math.radians(30)), abs=1e-3)
    assert wall.ray_distance(at, forward_ray(-40.0, 0.0)) == pytest.approx(10.0 / math.cos(math.radians(40)), abs=1e-3)
    assert wall.ray_distance(at, forward_ray(60.0, 0.0)) is None  # past the wall's east end (10 m along)
    assert wall.ray_distance(at, forward_ray(180.0, 0.0)) is None  # facing away
    assert wall.ray_distance(at, forward_ray(90.0, 0.0)) is None  # along the wall
    assert wall.ray_distance(at, forward_ray(0.0, -10.0)) == pytest.approx(10.0 / math.cos(math.radians(10)), abs=1e-3)
    assert wall.ray_distance(np.array([0.0, 0.0, -9.5]), forward_ray(0.0, 0.0)) is None  # above the top
    assert wall.ray_distance(np.array([0.0, 0.0, -9.5]), forward_ray(0.0, -10.0)) is not None  # nose down: hits


def _hovering(**cfg) -> SimVehicle:
    v = SimVehicle(VehicleConfig(pose_port=None, target=("127.0.0.1", 9), home=HOME, home_shift_m=0.0, **cfg))
    assert v.arm() is None and v.set_mode(fl.TAKEOFF) is None
    for _ in range(int(12 / 0.02)):
        v.step()
    assert v.mode == fl.HOLD and not v.on_ground
    return v


def test_distance_sensor_reports_the_true_distance_whatever_the_estimate_says():
    # the estimate is 1.5 m north of the truth (towards the wall): it thinks the wall is 6.5 m away; it is 8 m
    v = _hovering(rangefinder=True, rangefinder_wall=_wall_north(8.0), gnss_bias_enu_m=(0.0, 1.5, 0.0))
    try:
        readings = []
        for _ in range(50):
            v.step()
            m = v._distance_sensor()
            assert (m.orientation, m.min_distance, m.max_distance) == (mavlink.MAV_SENSOR_ROTATION_NONE, 20, 4000)
            assert m.type == mavlink.MAV_DISTANCE_SENSOR_LASER and m.time_boot_ms == int(v.t * 1000)
            readings.append(m.current_distance / 100.0)
        true_d = 8.0 - float(v.model.state.pos[0])
        assert true_d == pytest.approx(8.0, abs=0.1) and v.nav[0] - v.model.state.pos[0] == pytest.approx(1.5)
        assert np.mean(readings) == pytest.approx(true_d, abs=0.02)
        assert 0.005 < np.std(readings) < 0.04  # the sensor's 2 cm noise
        v.model.state.yaw_deg = 180.0  # nothing in front: max + 1 cm, MAVLink's "no reading"
        assert v._distance_sensor().current_distance == 4001
    finally:
        v.close()


def _sent(v: SimVehicle, seconds: float) -> list:
    out = []
    v._send = out.append
    for _ in range(int(seconds / 0.02)):
        v.step()
        v.send_streams()
    return [m for m in out if m.get_type() == "DISTANCE_SENSOR"]


@pytest.mark.parametrize("autopilot", ["px4", "ardupilot"])
def test_distance_sensor_streams_at_10_hz_only_with_the_rangefinder_and_obeys_message_intervals(autopilot):
    on = SimVehicle(VehicleConfig(pose_port=None, target=("127.0.0.1", 9), home=HOME, autopilot=autopilot,
                                  rangefinder=True, rangefinder_wall=_wall_north(8.0), init_s=0.0))
    off = SimVehicle(VehicleConfig(pose_port=None, target=("127.0.0.1", 9), home=HOME, autopilot=autopilot,
                                   init_s=0.0))
    try:
        assert 18 <= len(_sent(on, 2.0)) <= 22
        assert on._set_interval(mavlink.MAVLINK_MSG_ID_DISTANCE_SENSOR, 500_000)  # SET_MESSAGE_INTERVAL: 2 Hz
        assert 3 <= len(_sent(on, 2.0)) <= 5
        assert _sent(off, 2.0) == []
        assert off._requested(mavlink.MAVLINK_MSG_ID_DISTANCE_SENSOR) is None
    finally:
        on.close()
        off.close()


def _args(*argv: str) -> argparse.Namespace:
    p = argparse.ArgumentParser()
    add_arguments(p)
    return p.parse_args(list(argv))


def test_the_rig_hands_the_mission_wall_to_the_vehicle(capsys):
    mission = load_mission(ROOT / "missions/demo-facade.yaml")
    options = with_mission_wall({"rangefinder": "true", "gusts": "2"}, mission)
    argv = SimulatorProcess(**options).args
    assert "--rangefinder" in argv and argv[argv.index("--rangefinder") + 1].startswith("--")  # a switch alone
    cfg = config_from_args(_args(*argv[argv.index("vehicle") + 1:]))
    start, end = wall_ends(mission)
    assert cfg.rangefinder and cfg.rangefinder_wall == WallSpec(start, end, mission.facade.height_m)
    assert with_mission_wall({"gusts": "2"}, mission) == {"gusts": "2"}  # no rangefinder: no wall
    assert "--rangefinder" not in SimulatorProcess(rangefinder="false").args
    assert parse_wall(cfg.rangefinder_wall.option()) == cfg.rangefinder_wall
    for bad in ("1,2,3", "37.5,126.9,37.5,126.9,30,10", "37.5,126.9,37.6,126.9,30,0", "a,b,c,d,e,f"):
        with pytest.raises(SystemExit):
            _args("--rangefinder-wall", bad)
        assert "--rangefinder-wall wants START_LAT,START_LON,END_LAT,END_LON,BASE_ALT_AMSL,HEIGHT" in \
            capsys.readouterr().err


@pytest.mark.sitl
def test_distance_sensor_over_mavlink_is_the_true_distance():
    """The simulator process on the ground facing a wall 12 m north, its estimate 2 m nearer: DISTANCE_SENSOR
    says 12 m."""
    readings, positions = [], []
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        sock.settimeout(0.2)
        wall = _wall_north(12.0)
        with SitlVehicle(speedup=5, mavlink_port=sock.getsockname()[1], home=f"{HOME.lat},{HOME.lon},30.0",
                         rangefinder=True, rangefinder_wall=wall.option(), gnss_bias=(0.0, 2.0, 0.0)):
            parser = mavlink.MAVLink(None)
            deadline = time.monotonic() + 60.0
            while time.monotonic() < deadline and (len(readings) < 10 or not positions):
                try:
                    data = sock.recv(65535)
                except TimeoutError:
                    continue
                for m in parser.parse_buffer(data) or []:
                    if m.get_type() == "DISTANCE_SENSOR":
                        readings.append(m)
                    elif m.get_type() == "GLOBAL_POSITION_INT":
                        positions.append(m)
    assert len(readings) >= 10 and positions
    assert all(m.orientation == 0 and m.max_distance == 4000 for m in readings)
    assert np.mean([m.current_distance for m in readings]) == pytest.approx(1200, abs=3)
    n, _, _ = pymap3d.geodetic2ned(positions[-1].lat / 1e7, positions[-1].lon / 1e7, 30.0, HOME.lat, HOME.lon, 30.0)
    assert float(n) == pytest.approx(2.0, abs=0.02)  # the estimate: 10 m from the wall

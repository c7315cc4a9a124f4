"""Vehicle model, guidance tasks and flavour encodings, without processes or sockets."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sim.vehicle import flavours as fl
from sim.vehicle.environment import Battery, GpsError, Wind
from sim.vehicle.model import Limits, Multirotor, limit_velocity, track_line
from sim.vehicle.tasks import Line

DT = 0.02


class _Ctx:
    def __init__(self, model: Multirotor, cruise: float = 5.0):
        self.model = model
        self.limits = model.limits
        self.cruise_m_s = cruise
        self.land_speed_m_s = 0.7

    @property
    def yaw_deg(self) -> float:
        return self.model.state.yaw_deg


def _airborne(limits: Limits | None = None) -> Multirotor:
    m = Multirotor(limits or Limits())
    m.state.pos = np.array([0.0, 0.0, -10.0])
    m.state.on_ground = False
    return m


def test_speed_and_acceleration_limits_hold_in_calm_air():
    lim = Limits(max_speed_h_m_s=8.0, max_accel_m_s2=3.0)
    m = _airborne(lim)
    speeds, accels = [], []
    for _ in range(int(20 / DT)):
        v_before = m.state.vel.copy()
        m.step(DT, [50.0, 0.0, 0.0], None)  # ask for far more than allowed: the guidance clamps
        v_cmd = limit_velocity(np.array([50.0, 0.0, 0.0]), lim)
        assert np.linalg.norm(v_cmd) <= lim.max_speed_h_m_s + 1e-9
        m.step(0.0, v_cmd, None)
        speeds.append(float(np.linalg.norm(m.state.vel)))
        accels.append(float(np.linalg.norm(m.state.vel - v_before)) / DT)
        assert np.linalg.norm(m.thrust_accel) <= lim.max_accel_m_s2 + 1e-9
    assert max(accels) <= lim.max_accel_m_s2 + 1e-6  # drag only ever slows the vehicle down here
    assert max(speeds) > 5.0  # it does accelerate towards the commanded speed


def test_velocity_envelope_scales_uniformly_to_keep_direction():
    lim = Limits(max_speed_h_m_s=10.0, max_climb_m_s=2.0, max_descent_m_s=1.0)
    v = limit_velocity(np.array([4.0, 0.0, -4.0]), lim)  # 45 degrees up: climb-limited
    assert v[2] == pytest.approx(-2.0)
    assert v[0] == pytest.approx(2.0)  # same direction
    v = limit_velocity(np.array([0.0, 0.0, 3.0]), lim)
    assert v[2] == pytest.approx(1.0)


def test_line_tracking_pulls_back_onto_the_line():
    m = _airborne()
    m.state.pos = np.array([0.0, 1.0, -10.0])  # 1 m to the side of the line along north
    a, b = np.array([0.0, 0.0, -10.0]), np.array([40.0, 0.0, -10.0])
    for _ in range(int(15 / DT)):
        m.step(DT, track_line(m.state.pos, a, b, 3.0, m.limits), None)
    assert abs(m.state.pos[1]) < 0.05
    assert 20.0 < m.state.pos[0] < 40.5


def test_waypoint_is_reached_inside_acceptance_radius_after_heading_and_hold():
    m = _airborne()
    ctx = _Ctx(m, cruise=4.0)
    task = Line(m.state.pos.copy(), [10.0, 0.0, -10.0], radius_m=0.3, hold_s=1.0, yaw_deg=90.0)
    t = 0.0
    t_reached = None
    while not task.done and t < 60.0:
        v = task.command(m.state.pos, m.state.on_ground, DT, ctx)
        m.step(DT, v, task.yaw_deg)
        t += DT
        if task.reached and t_reached is None:
            t_reached = t
            assert np.linalg.norm(m.state.pos - task.b) <= 0.3
            assert abs(m.state.yaw_deg - 90.0) < 10.0
    assert task.done
    assert t - t_reached == pytest.approx(1.0, abs=2 * DT)
    assert np.linalg.norm(m.state.pos - task.b) < 0.3


def test_yaw_rate_is_limited():
    m = _airborne(Limits(max_yaw_rate_deg_s=30.0))
    for _ in range(int(1.0 / DT)):
        m.step(DT, [0.0, 0.0, 0.0], 180.0)
    assert m.state.yaw_deg == pytest.approx(30.0, abs=0.5)


def test_gusts_push_the_vehicle_and_stay_bounded():
    rng = np.random.default_rng(3)
    wind = Wind(0.0, 5.0, rng, from_deg=0.0)
    samples = np.array([wind.step(DT) for _ in range(int(120 / DT))])
    assert np.abs(samples[:, :2]).max() <= 5.0 + 1e-9
    assert samples[:, :2].std() > 0.5


def test_gps_glitch_only_inside_its_window():
    gps = GpsError(0.0, np.random.default_rng(0), glitch_at_s=10.0, glitch_m=5.0, glitch_s=3.0)
    assert np.linalg.norm(gps.step(9.9, DT)) == 0.0
    assert np.linalg.norm(gps.step(11.0, DT)) == pytest.approx(5.0)
    assert np.linalg.norm(gps.step(13.1, DT)) == 0.0


def test_battery_drains_only_while_armed():
    b = Battery()
    b.step(600.0, armed=False, speed_m_s=0.0)
    idle = b.remaining
    b.step(600.0, armed=True, speed_m_s=5.0)
    assert idle > 0.98
    assert b.remaining < idle - 0.3
    assert b.voltage_v < 4 * 4.2


def test_px4_custom_mode_bits_match_what_mavsdk_decodes():
    px4 = fl.Px4()
    # main mode in bits 16-23, sub mode in bits 24-31 (PX4 px4_custom_mode union)
    assert px4.custom_mode(fl.MISSION) == (4 << 16) | (4 << 24)
    assert px4.custom_mode(fl.HOLD) == (4 << 16) | (3 << 24)
    assert px4.custom_mode(fl.RTL) == (4 << 16) | (5 << 24)
    assert px4.mode_from_set_mode(1, 4, 4) == fl.MISSION
    assert px4.mode_from_set_mode(0, 4, 4) is None  # custom-mode flag missing
    assert px4.mode_from_set_mode(1, float("nan"), 0) is None


def test_ardupilot_flavour_refuses_nan_takeoff_and_arming_in_brake():
    from companion.mission.items import MissionItem
    ap = fl.ArduCopter()
    takeoff = MissionItem(1, 3, 22, 0, 1, math.nan, math.nan, math.nan, math.nan, 375663800, 1269781500, 10.0)
    assert ap.validate(takeoff, 1) == fl.mavlink.MAV_MISSION_INVALID_PARAM1
    assert ap.arm_refusal(fl.BRAKE)
    assert ap.arm_refusal(fl.GUIDED) is None
    assert ap.custom_mode(fl.GUIDED) == 4 and ap.custom_mode(fl.MISSION) == 3

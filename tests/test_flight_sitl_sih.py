"""End to end over MAVLink + mavsdk: the simulator's PX4 flavour boots with PX4 SIH SITL's markers and EKF2 defaults
(sim/vehicle/flavours.py). ``fly`` tells EKF2 SIH's sensor noise for the flight, and restores it after, only when
asked by the SITL profile (sim/sitl/px4-sih.yaml); unasked it sets no estimator parameter on the same simulator,
as on a real vehicle: the companion does not detect simulators."""

from __future__ import annotations

import asyncio

import pytest

from companion.flight import fly_mission_sync
from companion.flight.connection import connect
from companion.flight.parameters import read_parameter
from companion.flight.sitl_profile import load_sitl_profile
from tests.sitl import ROOT, SitlVehicle, small_demo_plan

pytestmark = pytest.mark.sitl
EKF2_DEFAULTS = {"EKF2_ACC_NOISE": 0.35, "EKF2_GYR_NOISE": 0.015}
PX4_SIH_PROFILE = ROOT / "sim/sitl/px4-sih.yaml"


@pytest.fixture(scope="module")
def small_plan():
    """The demo mission shrunk to an 8 m x 6 m wall (~80 s simulated)."""
    return small_demo_plan()


def _fly_and_read_back(plan, tmp_path, **fly):
    home = f"{plan.home.lat},{plan.home.lon},{plan.home.alt_amsl_m}"
    with SitlVehicle(speedup=20, home=home, log_path=tmp_path / "sim.log") as v:
        result = fly_mission_sync(plan, v.url, progress=False, handle_signals=False, flight_timeout_s=600.0,
                                  connect_timeout_s=60.0, **fly)

        async def read_back():
            vehicle = await connect(v.url, timeout_s=60)
            try:
                return {n: (await read_parameter(vehicle.param, n)).value for n in EKF2_DEFAULTS}
            finally:
                vehicle.close()

        return result, asyncio.run(read_back())


def test_the_px4_sih_profile_tells_ekf2_the_simulator_noise_for_the_flight_and_restores_it(small_plan, tmp_path):
    profile = load_sitl_profile(PX4_SIH_PROFILE)
    assert profile.parameters == {"EKF2_ACC_NOISE": 1.0, "EKF2_GYR_NOISE": 0.1} and profile.restore_home
    result, after = _fly_and_read_back(small_plan, tmp_path, sitl_profile=profile)
    assert result.completed, result
    changed = {c.name: (c.before, c.during) for c in result.parameter_changes}
    for name, value in profile.parameters.items():
        assert changed[name] == pytest.approx((EKF2_DEFAULTS[name], value)), changed
    assert after == pytest.approx(EKF2_DEFAULTS)


def test_without_the_profile_the_simulator_keeps_its_estimator_as_a_real_vehicle_does(small_plan, tmp_path):
    result, after = _fly_and_read_back(small_plan, tmp_path)
    assert result.completed, result
    assert not {c.name for c in result.parameter_changes} & set(EKF2_DEFAULTS), result.parameter_changes
    assert {c.name for c in result.parameter_changes} >= {"MPC_Z_V_AUTO_UP", "NAV_MC_ALT_RAD"}
    assert after == pytest.approx(EKF2_DEFAULTS)

"""End to end over MAVLink + mavsdk: the simulator's PX4 flavour boots with PX4 SIH SITL's markers and EKF2
defaults (sim/vehicle/flavours.py), so ``fly`` tells EKF2 SIH's sensor noise for the flight and restores it after;
the same flavour given a real flight controller's IMU and airframe (``--params``) keeps its estimator untouched."""

from __future__ import annotations

import asyncio

import pytest

from companion.flight import fly_mission_sync
from companion.flight.connection import connect
from companion.flight.parameters import read_parameter
from companion.mission.firmware import PX4_SIH_ESTIMATOR_PARAMETERS
from tests.sitl import ROOT, SitlVehicle, small_demo_plan

pytestmark = pytest.mark.sitl
DEMO = ROOT / "missions/demo-facade.yaml"
EKF2_DEFAULTS = {"EKF2_ACC_NOISE": 0.35, "EKF2_GYR_NOISE": 0.015}
REAL_FMU = "CAL_ACC0_ID=2490378,CAL_GYRO0_ID=2490378,SYS_AUTOSTART=4001"  # ICM-42688-P on SPI 1, a quad X airframe


@pytest.fixture(scope="module")
def small_plan():
    """The demo mission shrunk to an 8 m x 6 m wall (~80 s simulated)."""
    return small_demo_plan()


def _fly_and_read_back(plan, params: str | None, tmp_path):
    home = f"{plan.home.lat},{plan.home.lon},{plan.home.alt_amsl_m}"
    with SitlVehicle(speedup=20, home=home, params=params, log_path=tmp_path / "sim.log") as v:
        result = fly_mission_sync(plan, v.url, progress=False, handle_signals=False, flight_timeout_s=600.0,
                                  connect_timeout_s=60.0)

        async def read_back():
            vehicle = await connect(v.url, timeout_s=60)
            try:
                return {n: (await read_parameter(vehicle.param, n)).value for n in EKF2_DEFAULTS}
            finally:
                vehicle.close()

        return result, asyncio.run(read_back())


def test_px4_sih_flight_tells_ekf2_the_simulator_noise_and_restores_it(small_plan, tmp_path):
    result, after = _fly_and_read_back(small_plan, None, tmp_path)
    assert result.completed, result
    changed = {c.name: (c.before, c.during) for c in result.parameter_changes}
    for name, value in PX4_SIH_ESTIMATOR_PARAMETERS.items():
        assert changed[name] == pytest.approx((EKF2_DEFAULTS[name], value)), changed
    assert after == pytest.approx(EKF2_DEFAULTS)


def test_a_real_px4_vehicle_keeps_its_estimator(small_plan, tmp_path):
    result, after = _fly_and_read_back(small_plan, REAL_FMU, tmp_path)
    assert result.completed, result
    assert not {c.name for c in result.parameter_changes} & set(EKF2_DEFAULTS), result.parameter_changes
    assert {c.name for c in result.parameter_changes} >= {"MPC_Z_V_AUTO_UP", "NAV_MC_ALT_RAD"}
    assert after == pytest.approx(EKF2_DEFAULTS)

"""The simulator's PX4 flavour moves home in flight as real PX4 SIH does (sim/vehicle/home_drift.py); its ArduCopter
flavour keeps home where it armed, as ArduCopter does. Checked against every home update of 22 real PX4 SIH flights
(tests/data/real-px4-sih-home.json, from the flights' own logs)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import pytest

from companion.errors import CompanionError
from companion.mission import load_mission, plan_scan
from sim.vehicle import flavours as fl
from sim.vehicle.autopilot import SimVehicle, VehicleConfig
from sim.vehicle.home_drift import PX4_HOME_CORRECTION_WINDOW_S, hover_flight

DATA = Path(__file__).parent / "data"
DEMO = Path(__file__).resolve().parents[1] / "missions/demo-facade.yaml"


@pytest.fixture(scope="module")
def real_flights() -> list[dict]:
    flights = json.loads((DATA / "real-px4-sih-home.json").read_text())["flights"]
    return [f for f in flights if f["full_window"]]


@pytest.fixture(scope="module")
def demo_plan():
    return plan_scan(load_mission(DEMO))


def _fly(plan, seconds: float, flavour: str = "px4", **cfg) -> tuple[SimVehicle, list[tuple[float, float, int]]]:
    """The plan's items flown in process for ``seconds`` of simulated time; every home move as (time after take-off,
    home altitude now minus at arming, HOME_POSITION altitude in mm)."""
    v = SimVehicle(VehicleConfig(pose_port=None, target=("127.0.0.1", 9), home=plan.home, autopilot=flavour,
                                 gps_ready_after_s=0.0, **cfg))
    v._on_new_mission(plan.mavlink_items(flavour))
    assert v.set_mode(fl.GUIDED if flavour == "ardupilot" else fl.HOLD) is None
    assert v.arm() is None and v.set_mode(fl.MISSION) is None
    moves, takeoff_t = [], None
    for _ in range(int(seconds / 0.02)):
        before = v.home_alt_shift_m
        v.step()
        if takeoff_t is None and v.took_off:
            takeoff_t = v.t
        if v.home_alt_shift_m != before:
            moves.append((v.t - takeoff_t, v.home_alt_shift_m, v._home_position().altitude))
    v.close()
    return v, moves


def test_px4_flavour_moves_home_within_the_window_after_take_off_by_default(demo_plan):
    """A default PX4 flight (the demo's items: climb, transit, the hold above the wall, the first strips): home moves
    many times within 120 s of take-off, as much as real SIH moved it, HOME_POSITION says so, and it stays put after.
    Before, the simulator kept home where it armed unless told to move it."""
    v, moves = _fly(demo_plan, 160.0)
    assert len(moves) >= 20, moves
    assert all(0.0 <= t < PX4_HOME_CORRECTION_WINDOW_S for t, _, _ in moves), moves[-3:]
    offsets = [m for _, m, _ in moves]
    assert 0.5 < max(abs(m) for m in offsets) < 3.5  # real SIH: in flight -2.36 .. +2.78 m
    home_mm = round(v.cfg.home.alt_amsl_m * 1000)
    assert all(alt == int((v.cfg.home.alt_amsl_m + m) * 1000) for _, m, alt in moves)
    assert moves[-1][2] != home_mm or moves[-1][1] == 0.0
    assert v.home_alt_shift_m == offsets[-1]  # no move after the window: home stays where the last one put it


def test_the_same_seed_moves_home_the_same_way(demo_plan):
    _, first = _fly(demo_plan, 60.0, seed=7)
    _, again = _fly(demo_plan, 60.0, seed=7)
    _, other = _fly(demo_plan, 60.0, seed=8)
    assert first == again and first != other


def test_ardupilot_keeps_home_and_an_explicit_move_replaces_px4_sihs(demo_plan):
    assert _fly(demo_plan, 60.0, flavour="ardupilot")[1] == []  # ArduCopter keeps home where it armed
    assert _fly(demo_plan, 60.0, home_shift_m=0.0)[1] == []  # told to keep home still
    _, once = _fly(demo_plan, 60.0, home_shift_m=-1.2, home_shift_after_takeoff_s=30.0)
    assert [m for _, m, _ in once] == [-1.2] and once[0][0] == pytest.approx(30.0, abs=0.05)


def test_px4_sets_home_again_at_arming_and_its_window_restarts_at_the_next_take_off(demo_plan):
    v = SimVehicle(VehicleConfig(pose_port=None, target=("127.0.0.1", 9), home=demo_plan.home))
    v.home_alt_shift_m = 1.3  # left by the last flight's correction
    assert v.arm() is None and v.home_alt_shift_m == 0.0
    v.disarm()
    assert v.set_home(False, 31.0) and v.manual_home  # set by hand (DO_SET_HOME at an altitude): kept at arming
    assert v.arm() is None and v.home_alt_shift_m == pytest.approx(1.0)
    v.close()


def test_home_moves_are_the_size_and_number_real_px4_sih_made(real_flights):
    """Side by side with the 18 real SIH flights that lasted the whole window: how many moves, how far home swung
    each way and where it ended, over 60 seeds."""
    sim = np.array([hover_flight(seed) for seed in range(60)])
    real = np.array([[f["moves"], f["lowest_m"], f["highest_m"], f["final_m"]] for f in real_flights])
    assert len(real) == 18
    sim_med, real_med = np.median(sim, axis=0), np.median(real, axis=0)
    assert 0.7 * real_med[0] <= sim_med[0] <= 1.3 * real_med[0], (sim_med, real_med)  # real median 135 moves
    assert sim_med[1:3] == pytest.approx(real_med[1:3], abs=0.4), (sim_med, real_med)  # real -1.56 / +1.48 m
    assert abs(np.median(sim[:, 3])) < 0.4 and 0.4 < np.std(sim[:, 3]) < 0.9  # real: median -0.08, std 0.57 m
    assert np.all(sim[:, 1] <= 0.0) and np.all(sim[:, 2] >= 0.0)


def test_explicit_home_moves_are_checked():
    from sim.vehicle.cli import add_arguments, config_from_args

    parser = argparse.ArgumentParser()
    add_arguments(parser)
    refused = {("--autopilot", "ardupilot", "--home-shift-after-takeoff", "30", "--home-shift-m", "-1"): "only PX4",
               ("--home-shift-after-takeoff", "200", "--home-shift-m", "-1"): "only within 120 s",
               ("--home-shift-after-takeoff", "30"): "without --home-shift-m",
               ("--home-shift-m", "-1.2"): "without --home-shift-after-takeoff"}
    for argv, said in refused.items():
        with pytest.raises(CompanionError, match=said):
            config_from_args(parser.parse_args(list(argv)))
    assert config_from_args(parser.parse_args([])).home_shift_m is None  # PX4 SIH's moves
    assert config_from_args(parser.parse_args(["--home-shift-m", "0"])).home_shift_m == 0.0
    assert config_from_args(parser.parse_args(["--autopilot", "ardupilot", "--home-shift-m", "0"])).home_shift_m == 0

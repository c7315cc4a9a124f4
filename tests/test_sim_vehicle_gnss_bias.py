"""The simulator's GNSS bias (issue 26): the estimate the autopilot reports and flies is off the truth by a constant
plus a slow random walk, so the true vehicle sits at minus the bias while telemetry says it is on the plan."""

from __future__ import annotations

import argparse
import json
import math
import socket
import time

import numpy as np
import pymap3d
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.errors import CompanionError
from companion.mission import items as mi
from sim.process import SimulatorProcess
from sim.vehicle import flavours as fl
from sim.vehicle.autopilot import SimVehicle, VehicleConfig
from sim.vehicle.cli import add_arguments, config_from_args
from sim.vehicle.environment import GpsError
from sim.vehicle.gnss_bias import GnssBias
from tests.sitl import SitlVehicle

HOME = (37.56638, 126.97815, 30.0)
HOME_X, HOME_Y = 375663800, 1269781500


def _vehicle(**cfg) -> SimVehicle:
    return SimVehicle(VehicleConfig(pose_port=None, target=("127.0.0.1", 9), home_shift_m=0.0, **cfg))


def _item(seq, command, p=(0.0, 0.0, 0.0, float("nan")), x=HOME_X, y=HOME_Y, z=6.0):
    return mi.MissionItem(seq, mi.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, command, 0, 1, *p, x, y, z)


def _reported_ned(v: SimVehicle) -> tuple[float, float, float]:
    """Where GLOBAL_POSITION_INT puts the vehicle, in metres from home (north, east, up above home)."""
    m = v._global_position()
    n, e, _ = pymap3d.geodetic2ned(m.lat / 1e7, m.lon / 1e7, HOME[2], *HOME)
    return float(n), float(e), m.relative_alt / 1000.0


def _hold_at_waypoint(**cfg) -> tuple[SimVehicle, list[tuple]]:
    """Take off to 6 m, fly to a waypoint 10 m north of home and hold there 20 s; (reported, true) samples of the
    last 10 s of the hold."""
    v = _vehicle(**cfg)
    v._on_new_mission([_item(0, mi.MAV_CMD_NAV_TAKEOFF),
                       _item(1, mi.MAV_CMD_NAV_WAYPOINT, p=(20.0, 0.5, 0.0, 0.0), x=HOME_X + 900)])
    assert v.arm() is None and v.set_mode(fl.MISSION) is None
    samples, arrived = [], None
    for _ in range(int(90 / 0.02)):
        v.step()
        if arrived is None and v.mission_seq == 1 and np.hypot(v.nav[0] - 10.0, v.nav[1]) < 0.3:
            arrived = v.t  # by its own estimate: it holds there 20 s
        if arrived is not None and v.t > arrived + 8.0:
            samples.append((_reported_ned(v), v.true_pose()))
        if arrived is not None and v.t > arrived + 16.0:
            break
    assert samples, "the vehicle never reached the waypoint"
    return v, samples


def test_a_biased_vehicle_reports_the_waypoint_while_it_truly_sits_at_minus_the_bias():
    v, samples = _hold_at_waypoint(gnss_bias_enu_m=(1.5, 0.0, 1.0))
    try:
        for (north, east, up), truth in samples:
            # GLOBAL_POSITION_INT: on the plan (10 m north of home, 6 m up) ...
            assert (north, east, up) == pytest.approx((10.0, 0.0, 6.0), abs=0.15)
            # ... the true vehicle: 1.5 m west and 1 m lower (minus the bias) ...
            assert (truth["north_m"], truth["east_m"], -truth["down_m"]) == pytest.approx((10.0, -1.5, 5.0), abs=0.15)
            # ... and the truth log holds both, and the bias
            assert (truth["nav_north_m"], truth["nav_east_m"], -truth["nav_down_m"]) == pytest.approx(
                (north, east, up), abs=0.02)
            assert truth["gnss_bias_enu_m"] == [1.5, 0.0, 1.0]
            tn, te, _ = pymap3d.geodetic2ned(truth["lat"], truth["lon"], HOME[2], *HOME)
            nn, ne, _ = pymap3d.geodetic2ned(truth["nav_lat"], truth["nav_lon"], HOME[2], *HOME)
            assert (ne - te, nn - tn) == pytest.approx((1.5, 0.0), abs=1e-3)
            assert truth["nav_alt_amsl_m"] - truth["alt_amsl_m"] == pytest.approx(1.0, abs=1e-3)
    finally:
        v.close()


def test_without_a_bias_the_vehicle_is_where_it_says():
    v, samples = _hold_at_waypoint()
    try:
        for (north, east, up), truth in samples:
            assert (truth["north_m"], truth["east_m"], -truth["down_m"]) == pytest.approx((north, east, up), abs=0.02)
            assert truth["gnss_bias_enu_m"] == [0.0, 0.0, 0.0]
    finally:
        v.close()


def _nav_errors(steps: int, **cfg) -> np.ndarray:
    v = _vehicle(**cfg)
    try:
        out = []
        for _ in range(steps):
            v.step()
            out.append(v.nav - v.model.state.pos)
        return np.array(out)
    finally:
        v.close()


def test_zero_bias_is_the_old_estimate_and_a_bias_leaves_the_other_faults_random_sequences_alone():
    noisy = dict(seed=7, gps_noise_m=0.8, gps_glitch_at_s=2.0, gps_glitch_s=1.0)
    steps = 300
    old = _nav_errors(steps, **noisy)
    # the old simulator's estimate error: GpsError alone, on the vehicle's seed + 2
    gps = GpsError(0.8, np.random.default_rng(7 + 2), 2.0, 5.0, 1.0)
    expected = np.array([gps.step(k * 0.02, 0.02) for k in range(1, steps + 1)])
    assert np.array_equal(old, expected)  # bit for bit: zeros add nothing, draw nothing
    assert np.array_equal(_nav_errors(steps, gnss_bias_enu_m=(0.0, 0.0, 0.0), gnss_drift_m_per_min=0.0, **noisy),
                          old)
    # with a drifting bias the noise and glitch are the same draws, the bias comes on top (its own generator)
    v = _vehicle(gnss_bias_enu_m=(1.0, -2.0, 0.5), gnss_drift_m_per_min=1.0, **noisy)
    try:
        for k in range(steps):
            v.step()
            bias = v.gnss_bias.ned
            assert v.nav - v.model.state.pos - bias == pytest.approx(expected[k], abs=1e-9)
        assert np.linalg.norm(v.gnss_bias.walk) > 0.0
    finally:
        v.close()


def test_the_drift_grows_at_the_stated_rate_and_repeats_with_the_seed():
    rate, dt = 0.6, 0.1
    finals_1, finals_4 = [], []
    for seed in range(150):
        walk = GnssBias((0.0, 0.0, 0.0), rate, np.random.default_rng(seed))
        for k in range(int(240 / dt)):
            walk.step(dt)
            if k == int(60 / dt) - 1:
                finals_1.append(walk.walk.copy())
        finals_4.append(walk.walk.copy())
    rms_1 = float(np.sqrt(np.mean(np.square(finals_1))))  # over 150 walks x 3 axes
    rms_4 = float(np.sqrt(np.mean(np.square(finals_4))))
    assert rms_1 == pytest.approx(rate, rel=0.12)  # metres per minute: RMS after one minute, per axis
    assert rms_4 == pytest.approx(2.0 * rate, rel=0.12)  # a random walk: sqrt(4 minutes)
    assert abs(float(np.mean(finals_4))) < 0.3 * rate  # no direction preferred

    def bias_track(seed: int) -> np.ndarray:
        v = _vehicle(seed=seed, gnss_drift_m_per_min=2.0)
        try:
            track = []
            for _ in range(500):
                v.step()
                track.append(v.gnss_bias.ned.copy())
            return np.array(track)
        finally:
            v.close()

    a, b, c = bias_track(3), bias_track(3), bias_track(4)
    assert np.array_equal(a, b) and not np.array_equal(a, c)
    assert 0.05 < float(np.max(np.abs(a))) < 3.0  # 10 s at 2 m/min: about 0.5 m RMS


def test_the_drift_bound_clamps_each_axis():
    walk = GnssBias((1.0, 0.0, 0.0), 30.0, np.random.default_rng(1), max_walk_m=0.5)
    for _ in range(3000):
        walk.step(0.1)
        assert np.all(np.abs(walk.walk) <= 0.5)
    assert float(np.max(np.abs(walk.walk))) == pytest.approx(0.5)
    assert walk.ned[1] == pytest.approx(1.0 + walk.walk[1])  # the constant is East: NED's second axis


def _args(*argv: str) -> argparse.Namespace:
    p = argparse.ArgumentParser()
    add_arguments(p)
    return p.parse_args(list(argv))


def test_command_line_bias_and_drift(capsys):
    cfg = config_from_args(_args("--gnss-bias=-1.5,0.5,2", "--gnss-drift", "0.4", "--gnss-drift-max", "3"))
    assert (cfg.gnss_bias_enu_m, cfg.gnss_drift_m_per_min, cfg.gnss_drift_max_m) == ((-1.5, 0.5, 2.0), 0.4, 3.0)
    default = config_from_args(_args())
    assert (default.gnss_bias_enu_m, default.gnss_drift_m_per_min, default.gnss_drift_max_m) == ((0, 0, 0), 0, None)
    for bad in ("1.5,0", "east,0,0", "1,2,3,4", "nan,0,0"):
        with pytest.raises(SystemExit):
            _args("--gnss-bias", bad)
        assert "--gnss-bias wants EAST,NORTH,UP" in capsys.readouterr().err
    with pytest.raises(CompanionError, match="--gnss-drift -1 is not a rate"):
        config_from_args(_args("--gnss-drift", "-1"))
    with pytest.raises(CompanionError, match="--gnss-drift-max 0 is not a positive size"):
        config_from_args(_args("--gnss-drift-max", "0"))
    # the rig and `fly --sitl` hand options to the process as keywords: a tuple and a negative value arrive whole
    argv = SimulatorProcess(gnss_bias=(-1.5, 0, 0.25), gnss_drift="0.5").args
    assert "--gnss-bias=-1.5,0,0.25" in argv and argv[argv.index("--gnss-drift") + 1] == "0.5"
    parsed = config_from_args(_args(*argv[argv.index("vehicle") + 1:]))
    assert parsed.gnss_bias_enu_m == (-1.5, 0.0, 0.25) and parsed.gnss_drift_m_per_min == 0.5


@pytest.mark.sitl
def test_global_position_int_is_the_biased_estimate_over_mavlink(tmp_path):
    """The simulator process on the ground with a 2 m East, 1 m South bias: GLOBAL_POSITION_INT puts it there, the
    truth log at home, where it stands."""
    truth = tmp_path / "truth.jsonl"
    positions = []
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        sock.settimeout(0.2)
        with SitlVehicle(speedup=5, mavlink_port=sock.getsockname()[1], truth_log=truth,
                         home=",".join(str(v) for v in HOME), gnss_bias=(2.0, -1.0, 0.0)):
            parser = mavlink.MAVLink(None)
            deadline = time.monotonic() + 60.0
            while time.monotonic() < deadline and len(positions) < 5:
                try:
                    data = sock.recv(65535)
                except TimeoutError:
                    continue
                positions += [m for m in parser.parse_buffer(data) or [] if m.get_type() == "GLOBAL_POSITION_INT"]
    assert len(positions) >= 5
    for m in positions:
        n, e, _ = pymap3d.geodetic2ned(m.lat / 1e7, m.lon / 1e7, HOME[2], *HOME)
        assert (float(e), float(n)) == pytest.approx((2.0, -1.0), abs=0.02)
    rows = [json.loads(line) for line in truth.read_text().splitlines()]
    assert rows and all(math.isclose(r["lat"], HOME[0], abs_tol=1e-9) and math.isclose(r["lon"], HOME[1],
                                                                                        abs_tol=1e-9) for r in rows)
    assert rows[-1]["gnss_bias_enu_m"] == [2.0, -1.0, 0.0]

"""End-to-end: the simulator as its own process, MAVLink over UDP, companion.flight through mavsdk.

Speed-up 20 keeps each flight of the demo mission (about 4.5 simulated minutes) near 15 s of wall time. The plain
demo flight to completion is judged in tests/test_flight_sitl_firmware.py, on the flight flown there.
"""

from __future__ import annotations

import math
import time

import pytest

from companion.errors import CompanionError
from companion.flight import fly_mission_sync, read_telemetry_log
from companion.mission import items as mi
from companion.mission import load_mission, plan_scan
from tests.sitl import ROOT, STILL_HOME_ARGS, SitlVehicle, free_port, small_demo_plan, still_home_demo

pytestmark = pytest.mark.sitl


@pytest.fixture(scope="module")
def plan():
    return plan_scan(load_mission(ROOT / "missions/demo-facade.yaml"))


@pytest.fixture(scope="module")
def small_plan():
    """The demo mission shrunk to an 8 m x 6 m wall (18 items, ~80 s simulated): for the slow lossy-link test."""
    return small_demo_plan()


def _fly(plan, url, **kw):
    kw.setdefault("progress", False)
    kw.setdefault("handle_signals", False)
    kw.setdefault("flight_timeout_s", 600.0)  # wall seconds: a loaded 2-core machine ran the simulator at ~3x, not 20x
    kw.setdefault("connect_timeout_s", 60.0)  # a loaded machine can take 15 s to start the simulator process
    return fly_mission_sync(plan, url, **kw)


def test_twenty_percent_packet_loss_still_completes(small_plan, tmp_path):
    home = small_plan.home
    with SitlVehicle(speedup=20, packet_loss=20, seed=4, log_path=tmp_path / "sim.log",
                     home=f"{home.lat},{home.lon},{home.alt_amsl_m}") as v:
        result = _fly(small_plan, v.url, connect_timeout_s=15.0)
    assert result.completed, result
    assert result.items_reached == result.items_total == 18


def test_five_second_link_outage_is_survived(plan, tmp_path):
    log = tmp_path / "telemetry.jsonl"
    # outage 40 s after take-off (simulated time: timed from the take-off, a slow start-up on a loaded machine cannot
    # move it before the flight) lasting 5 s of wall time; the vehicle's own link-loss failsafe waits 10 s, so it
    # flies on and the companion must just ride the gap out
    with SitlVehicle(speedup=20, outage_after_takeoff=40, outage_s=5, log_path=tmp_path / "sim.log") as v:
        result = _fly(plan, v.url, telemetry_log=log, link_loss_s=2.0)
    assert result.completed, result
    # the outage, counted once with its length; on a loaded machine (load average 12-18 on 2 cores) telemetry also
    # paused for 1.1-1.3 s now and then, which a 1 s threshold counted as six more losses
    outages = [loss for loss in result.link_losses if loss.duration_s >= 4.0]
    assert len(outages) == 1 and all(loss.closed for loss in result.link_losses), result.link_losses
    assert 4.0 <= outages[0].duration_s <= 9.0
    rows = read_telemetry_log(log)
    gaps = [b["t_wall"] - a["t_wall"] for a, b in zip(rows, rows[1:], strict=False)]
    assert max(gaps) > 4.0  # the gap is in the log, and recording went on after it
    assert rows[-1]["armed"] is False


def test_no_vehicle_gives_a_clear_error_within_the_timeout(plan):
    url = f"udpin://127.0.0.1:{free_port()}"
    t0 = time.monotonic()
    with pytest.raises(CompanionError) as err:
        _fly(plan, url, connect_timeout_s=2.0)
    assert time.monotonic() - t0 < 6.0
    assert "no autopilot heartbeat" in err.value.problem and err.value.fix


def test_upload_the_vehicle_rejects_gives_a_clear_error(plan, tmp_path):
    sim = SitlVehicle(speedup=20, max_mission_items=10, log_path=tmp_path / "sim.log")
    with sim as v, pytest.raises(CompanionError) as err:
        _fly(plan, v.url)
    assert "rejected the mission upload" in err.value.problem
    assert "TOO_MANY_MISSION_ITEMS" in err.value.problem and "shorten" in err.value.fix


def test_rejected_upload_errors_before_the_health_wait(plan, tmp_path):
    """Real ArduCopter SITL refused a too-long mission only after its ~40 s EKF wait, because the companion
    uploaded after the health wait. The upload now comes first (once the vehicle sends SYS_STATUS): the refusal is
    the error, not the health timeout."""
    sim = SitlVehicle(speedup=1, autopilot="ardupilot", gps_ready_after=600, max_mission_items=10,
                      log_path=tmp_path / "sim.log")
    with sim as v, pytest.raises(CompanionError) as err:
        _fly(plan, v.url, health_timeout_s=30.0, connect_timeout_s=60.0)
    assert "rejected the mission upload" in err.value.problem and "TOO_MANY_MISSION_ITEMS" in err.value.problem
    # the vehicle's own words (real ArduCopter: NO_SPACE, then "Only 650 items are supported") and the fix from them
    assert "it said: WARNING: Only 10 items are supported" in err.value.problem
    assert f"at most 10 items and this mission has {len(plan.mavlink_items('ardupilot'))}" in err.value.fix


def test_unsupported_item_is_rejected(tmp_path):
    items = [
        mi.MissionItem(0, 6, mi.MAV_CMD_NAV_TAKEOFF, 1, 1, 0.0, 0.0, 0.0, math.nan, 375663800, 1269781500, 5.0),
        mi.MissionItem(1, 2, 31000, 0, 1, 0.0, 0.0, 0.0, 0.0, 0, 0, 0.0),  # a command the vehicle does not know
    ]
    with SitlVehicle(speedup=20, log_path=tmp_path / "sim.log") as v, pytest.raises(CompanionError) as err:
        _fly(items, v.url)
    assert "UNSUPPORTED" in err.value.problem
    # PX4 says why before it acks (MavlinkMissionManager::handle_mission_item), its trailing tab not quoted
    assert err.value.problem.endswith("it said: CRITICAL: IGN MISSION_ITEM: Invalid item")


def test_sigint_pauses_returns_home_and_exits_cleanly(tmp_path):
    """``companion fly --sitl`` as a user runs it; Ctrl-C in the middle of the scan."""
    import json
    import os
    import signal
    import subprocess
    import sys

    log = tmp_path / "telemetry.jsonl"
    # not about home: the simulator keeps it still and the demo starts its scan at once (no 2-minute hold)
    cmd = [sys.executable, "-m", "companion.cli", "fly", str(still_home_demo(tmp_path)), "--sitl", *STILL_HOME_ARGS,
           "--speedup", "20", "--telemetry-log", str(log), "--no-progress",
           "--connect-timeout", "60"]  # a loaded machine can take 15 s to start the simulator process
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
    try:
        deadline = time.monotonic() + 180  # a loaded machine starts and runs the simulator slowly
        while time.monotonic() < deadline:  # wait until it is scanning (past the first scan leg)
            if log.exists():
                rows = [json.loads(x) for x in log.read_text().splitlines() if x.strip()]
                if rows and rows[-1]["mission_item"] >= 8:
                    break
            time.sleep(0.2)
        else:
            pytest.fail("the flight never reached the scan")
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=300)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, out
    assert "stopped by signal" in out and "landed, disarmed" in out
    last = json.loads(log.read_text().splitlines()[-1])
    assert last["armed"] is False and last["in_air"] is False
    assert last["flight_mode"] == "RETURN_TO_LAUNCH"
    assert abs(last["lat"] - 37.56638) < 5e-6 and abs(last["lon"] - 126.97815) < 5e-6  # back at home


def test_home_at_the_wrong_altitude_is_refused(plan, tmp_path):
    # 8 m higher than the planned takeoff: every relative scan height would be 8 m off
    sim = SitlVehicle(speedup=20, home="37.56638,126.97815,38.0", log_path=tmp_path / "sim.log")
    with sim as v, pytest.raises(CompanionError) as err:
        _fly(plan, v.url)
    assert "+8.0 m from the planned takeoff altitude" in err.value.problem

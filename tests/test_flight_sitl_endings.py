"""How flights start and end against the firmware behaviours seen on real PX4 and ArduCopter (shared/notes/
real-firmware.md), reproduced by the simulator (sim/vehicle/firmware.py), end to end over MAVLink + mavsdk:

* a re-fly after an interrupted flight starts at the first item (PX4 keeps its current item across an identical
  upload, and the interrupted flight left the vehicle in Return mode, where PX4 does not arm);
* an autopilot restart mid-flight is a failed flight with a non-zero exit, whatever the progress said;
* a mission PX4 refuses at start (geofence) ends with the vehicle's reason within seconds;
* a link that never comes back ends supervision at the configured limit, non-zero, and the loss is counted;
* ArduCopter's EKF (GPS only ~38 s after boot): arming refused with its "PreArm:" text, the health wait covers it;
* failsafe parameters set for the flight with explicit options and restored after (the default failsafe's warnings:
  tests/test_flight_sitl_firmware.py, on its ArduCopter demo flight).
"""

from __future__ import annotations

import asyncio
import logging
import os
import re
import signal
import subprocess
import sys
import time

import pytest

from companion.errors import CompanionError
from companion.flight import fly_mission_sync, read_telemetry_log
from companion.flight.connection import connect, request_rates, wait_healthy
from companion.flight.parameters import read_parameter
from companion.flight.start import arm_with_reason, select_arming_mode
from companion.mission import load_mission, plan_scan
from tests.sitl import ROOT, STILL_HOME_ARGS, SitlVehicle, small_demo_plan, still_home_demo

pytestmark = pytest.mark.sitl
DEMO = ROOT / "missions/demo-facade.yaml"
ENV = dict(os.environ, PYTHONPATH=str(ROOT))


@pytest.fixture(scope="module")
def small_plan():
    """The demo mission shrunk to an 8 m x 6 m wall (18 items, ~80 s simulated)."""
    return small_demo_plan()


def _home(plan) -> str:
    return f"{plan.home.lat},{plan.home.lon},{plan.home.alt_amsl_m}"


def _fly(plan, url, **kw):
    kw.setdefault("progress", False)
    kw.setdefault("handle_signals", False)
    kw.setdefault("flight_timeout_s", 600.0)  # wall seconds: generous, a loaded machine slows the simulator down
    kw.setdefault("connect_timeout_s", 60.0)  # the simulator process alone can take 10 s to start under load
    return fly_mission_sync(plan, url, **kw)


def _cli(*args: str) -> list[str]:
    # a generous heartbeat wait: on a loaded machine the simulator process alone can take 10 s to start
    return [sys.executable, "-m", "companion.cli", "fly", "--connect-timeout", "60", *args]


def test_refly_after_an_interrupted_flight_starts_at_the_first_item(tmp_path):
    """First flight: Ctrl-C in the middle of the scan (RTL, lands in Return mode, PX4 keeps item N as current).
    Second flight of the same mission: identical upload, so the vehicle still holds item N; the companion must set
    and confirm item 0 and switch out of Return mode to arm."""
    first_log, second_log = tmp_path / "first.jsonl", tmp_path / "second.jsonl"
    demo = still_home_demo(tmp_path)  # not about home: home kept still (SitlVehicle), the scan starts at once
    with SitlVehicle(speedup=20, log_path=tmp_path / "sim.log") as v:
        proc = subprocess.Popen(_cli(str(demo), "--connect", v.url, "--telemetry-log", str(first_log),
                                     "--no-progress"), cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                text=True, env=ENV)
        try:
            deadline = time.monotonic() + 300
            while time.monotonic() < deadline:
                rows = read_telemetry_log(first_log) if first_log.exists() else []
                if rows and rows[-1]["mission_item"] >= 9:
                    break
                time.sleep(0.2)
            else:
                pytest.fail("the first flight never reached the scan")
            proc.send_signal(signal.SIGINT)
            out, _ = proc.communicate(timeout=300)
        finally:
            if proc.poll() is None:
                proc.kill()
        assert proc.returncode == 130, out
        result = _fly(plan_scan(load_mission(demo)), v.url, telemetry_log=second_log)
    sim_log = (tmp_path / "sim.log").read_text()
    kept = [line for line in sim_log.splitlines() if "current item" in line and "kept" in line]
    assert kept and not kept[-1].rstrip().endswith("item 0 kept"), sim_log[-3000:]  # the vehicle did keep it
    starts = [line.rsplit(" ", 1)[-1] for line in sim_log.splitlines() if "mission mode from item" in line]
    assert starts == ["0", "0"], starts  # both flights started at their first item
    assert result.completed, result
    rows = [r for r in read_telemetry_log(second_log) if r["armed"]]
    known = [r["mission_item"] for r in rows if r["mission_item"] >= 0]  # -1: no MISSION_CURRENT received yet
    assert known and known[0] == 0, known[:5]
    assert max(r["rel_alt_m"] for r in rows) > 15.0  # it climbed to the transit altitude first


def test_autopilot_restart_mid_flight_exits_non_zero(tmp_path):
    cmd = _cli(str(still_home_demo(tmp_path)), "--sitl", "--speedup", "20", "--no-progress", *STILL_HOME_ARGS,
               "--sim-arg", "reboot-after-takeoff=60", "--link-dead", "30")
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, env=ENV, timeout=600)
    out = proc.stdout + proc.stderr
    assert proc.returncode == 1, out
    assert "mission NOT complete" in out and "stopped by reboot" in out
    assert "the autopilot restarted" in out and "cannot be trusted" in out


def test_streams_lagging_each_other_are_not_a_restart(small_plan, tmp_path, monkeypatch):
    """The simulator's streams stall behind each other by up to 2.5 s of autopilot time (real SITL at speed-up: up
    to 7 s on the link, and 1.2 s in mavsdk's queues on ArduCopter): the companion saw stamps more than the
    1 s a cross-stream check allows out of order, and the flight completed, because each stream is compared only
    with itself."""
    from companion.flight.telemetry_log import TelemetryRecorder

    seen: list[tuple[str, float]] = []
    original = TelemetryRecorder._on_boot_time

    def spy(self, t_boot_s, stream=""):
        seen.append((stream, t_boot_s))
        original(self, t_boot_s, stream)

    monkeypatch.setattr(TelemetryRecorder, "_on_boot_time", spy)
    with SitlVehicle(speedup=20, stream_stall=2.5, stream_stall_every=5, home=_home(small_plan),
                     log_path=tmp_path / "sim.log") as v:
        result = _fly(small_plan, v.url)
    assert result.completed and result.aborted is None, result.problem
    latest: dict[str, float] = {}
    behind = 0.0
    for stream, t in seen:
        latest[stream] = max(latest.get(stream, t), t)
        behind = max([behind] + [top - t for name, top in latest.items() if name != stream])
    assert behind > 1.0  # a cross-stream restart check would have ended this good flight


def test_ardupilot_restart_is_seen_although_it_streams_nothing_until_asked_again(small_plan, tmp_path):
    """After a restart ArduCopter streams only HEARTBEAT: the companion asks for telemetry again while the link is
    silent, and the restart shows in the time since boot (not as a dead link at the limit)."""
    cmd = _cli(str(DEMO), "--sitl", "--autopilot", "ardupilot", "--speedup", "20", "--no-progress",
               "--sim-arg", "reboot-after-takeoff=40", "--link-dead", "40")
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, env=ENV, timeout=600)
    out = proc.stdout + proc.stderr
    assert proc.returncode == 1, out
    assert "stopped by reboot" in out and "the autopilot restarted" in out


def test_mission_the_vehicle_refuses_at_start_errors_within_seconds(small_plan, tmp_path, caplog):
    caplog.set_level(logging.INFO, logger="companion.flight.fly")
    with SitlVehicle(speedup=20, geofence_max_dist=5, home=_home(small_plan), log_path=tmp_path / "sim.log") as v:
        with pytest.raises(CompanionError) as err:
            _fly(small_plan, v.url, flight_timeout_s=600.0)
        ended = time.time()
    started = [r.created for r in caplog.records if r.getMessage().startswith("armed; starting the mission")]
    assert started and ended - started[0] < 10.0
    assert "refused the mission start" in err.value.problem
    assert "Geofence violation for waypoint" in err.value.problem and "geofence" in err.value.fix
    # real PX4's second text, and no PX4 tab inside the quote
    assert "CRITICAL: Switching to Mission is currently not available" in err.value.problem
    assert "\t" not in err.value.problem


def test_a_start_the_vehicle_refuses_quotes_its_result_and_words(tmp_path):
    """ArduCopter refuses AUTO on the ground unless the mission starts with a takeoff: CRITICAL "Auto: Missing
    Takeoff Cmd", WARNING "Mode change to AUTO failed: init failed", the mode command answered FAILED (ArduCopter 4.7
    ModeAuto::init, Copter::set_mode, GCS_MAVLINK::_set_mode_common). The error quotes both, once, with the result:
    it used to be "mission start failed: ..." after three tries of a refusal that repeating cannot change."""
    from companion.mission import items as mi

    lat, lon = 375663800, 1269781500
    items = [mi.MissionItem(0, 0, mi.MAV_CMD_NAV_WAYPOINT, 1, 1, 0.0, 0.0, 0.0, 0.0, lat, lon, 30.0),
             mi.MissionItem(1, 6, mi.MAV_CMD_NAV_WAYPOINT, 0, 1, 0.0, 0.0, 0.0, 0.0, lat + 900, lon, 8.0),
             mi.MissionItem(2, 2, mi.MAV_CMD_NAV_RETURN_TO_LAUNCH, 0, 1, 0.0, 0.0, 0.0, 0.0, 0, 0, 0.0)]
    with SitlVehicle(speedup=20, autopilot="ardupilot", gps_ready_after=0, log_path=tmp_path / "sim.log") as v:
        with pytest.raises(CompanionError) as err:
            _fly(items, v.url)
        log = (tmp_path / "sim.log").read_text()
    problem = err.value.problem
    assert problem.startswith("the vehicle refused the mission start (DO_SET_MODE FAILED; mavsdk: ")
    assert "WARNING: Mode change to AUTO failed: init failed" in problem
    assert "CRITICAL: Auto: Missing Takeoff Cmd" in problem and "takeoff" in err.value.fix
    assert log.count("statustext: Auto: Missing Takeoff Cmd") == 1  # asked once: a refusal is not retried


def test_dead_link_ends_supervision_at_the_configured_limit(tmp_path):
    cmd = _cli(str(still_home_demo(tmp_path)), "--sitl", "--speedup", "20", "--no-progress", *STILL_HOME_ARGS,
               "--sim-arg", "outage-after-takeoff=30", "--sim-arg", "outage-s=100000", "--link-loss", "1",
               "--link-dead", "5")
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, env=ENV, timeout=600)
    out = proc.stdout + proc.stderr
    assert proc.returncode == 1, out
    # the open loss is counted; on a loaded machine a 1 s threshold may also count short, closed losses before it
    assert "stopped by link" in out and re.search(r"\d+ link loss\(es\) \(1 never restored\)", out), out
    assert "limit 5 s" in out
    flown_s = int(re.search(r"NOT landed, still ARMED, (\d+) s,", out).group(1))
    assert flown_s < 60, out  # supervision ended at the limit, not at the 1800 s flight timeout


def test_ardupilot_refuses_to_arm_until_its_ekf_uses_gps_and_says_why(tmp_path):
    from companion.flight.telemetry_log import TelemetryRecorder

    async def go():
        vehicle = await connect(sim.url, timeout_s=60)
        try:
            await request_rates(vehicle, 5.0)
            assert await select_arming_mode(vehicle)
            async with TelemetryRecorder(vehicle) as rec:
                await asyncio.sleep(0.5)
                await arm_with_reason(vehicle, lambda n: rec.status_texts[n:], lambda: len(rec.status_texts))
        finally:
            vehicle.close()

    sim = SitlVehicle(speedup=5, autopilot="ardupilot", gps_ready_after=10000, log_path=tmp_path / "sim.log")
    with sim, pytest.raises(CompanionError) as err:
        asyncio.run(go())
    assert "refused to arm" in err.value.problem and "PreArm: Need Position Estimate" in err.value.problem


def test_ardupilot_health_wait_covers_ekf_convergence_and_says_what_is_missing(tmp_path, caplog):
    """38 simulated seconds (the real firmware's 35-40 s) before home and position: the default wait covers it and
    reports what it still waits for while waiting."""
    caplog.set_level(logging.INFO, logger="companion.flight.connection")
    m = load_mission(DEMO)
    with SitlVehicle(speedup=4, autopilot="ardupilot", home=_home(plan_scan(m)), log_path=tmp_path / "sim.log") as v:
        async def until_healthy():
            vehicle = await connect(v.url, timeout_s=60)
            try:
                await request_rates(vehicle, 5.0)
                t0 = time.monotonic()
                await wait_healthy(vehicle, report_every_s=2.0)
                return time.monotonic() - t0
            finally:
                vehicle.close()

        waited = asyncio.run(until_healthy())
    assert waited > 4.0  # 38 s simulated at speed-up 4 is ~9.5 s wall
    waiting = [r.getMessage() for r in caplog.records if r.getMessage().startswith("waiting for the vehicle")]
    assert waiting and "home position" in waiting[0]


def test_failsafe_options_set_parameters_for_the_flight_and_restore_them(small_plan, tmp_path):
    with SitlVehicle(speedup=20, home=_home(small_plan), log_path=tmp_path / "sim.log") as v:
        result = _fly(small_plan, v.url, lost_link_action="rtl", return_alt="auto",
                      flight_parameters={"MPC_XY_CRUISE": 4.0})
        assert result.completed, result
        changed = {c.name: (c.before, c.during) for c in result.parameter_changes}
        assert changed["NAV_DLL_ACT"] == (0.0, 2.0)  # an int, byte-wise encoded by PX4
        assert "RTL_RETURN_ALT" not in changed  # PX4's 30 m is above the 10 m this scan needs: never lowered
        assert changed["MPC_XY_CRUISE"] == (5.0, 4.0)
        assert result.warnings == []

        async def read_back():
            vehicle = await connect(v.url, timeout_s=60)
            try:
                return [(await read_parameter(vehicle.param, n)).value for n in ("NAV_DLL_ACT", "MPC_XY_CRUISE")]
            finally:
                vehicle.close()

        assert asyncio.run(read_back()) == [0.0, 5.0]
    sim_log = (tmp_path / "sim.log").read_text()
    assert "data link lost" not in sim_log

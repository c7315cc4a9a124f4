"""A companion killed with SIGKILL mid-scan (issue 31), end to end over MAVLink against the ArduCopter-flavoured
simulator: with ``--lost-link-action rtl`` the vehicle returns within its failsafe timeout (FS_GCS_TIMEOUT, 5 s:
the simulator counts only its GCS id's heartbeats, as real ArduCopter does), and ``companion restore`` puts every
parameter the killed run changed back to its value before the run, read back over MAVLink, and leaves the vehicle
armable (the GCS failsafe the kill left on cleared before FS_GCS_ENABLE goes back to 0)."""

from __future__ import annotations

import asyncio
import json
import os
import subprocess
import sys
import time

import pytest
from pymavlink import mavutil

from companion.flight import read_telemetry_log
from companion.flight.connection import connect, request_rates, wait_healthy
from companion.flight.parameters import read_parameter
from companion.flight.start import select_arming_mode
from companion.mission import load_mission, plan_scan
from tests.sitl import ROOT, SitlVehicle, still_home_demo

pytestmark = pytest.mark.sitl
CHANGED = ("WP_YAW_BEHAVIOR", "FS_GCS_ENABLE", "RTL_ALT", "MAV_GCS_SYSID")  # what the demo's flight sets
COPTER_RTL = 6
FS_GCS_TIMEOUT_S = 5.0


def _read(url: str, *, armable: bool = False) -> dict[str, float]:
    """The parameters over MAVLink; ``armable``: also wait (15 s at most) until the vehicle could arm again."""
    async def go():
        vehicle = await connect(url, timeout_s=60)
        try:
            values = {name: (await read_parameter(vehicle.param, name)).value for name in CHANGED}
            if armable:  # a GCS failsafe left on refuses arming ("PreArm: GCS failsafe on")
                await request_rates(vehicle, 2.0)
                await wait_healthy(vehicle, 15.0, when_only_armable_missing=lambda: select_arming_mode(vehicle))
            return values
        finally:
            vehicle.close()

    return asyncio.run(go())


def _wait_for_scan(proc, telemetry_log, min_item: int, timeout_s: float = 120.0) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        assert proc.poll() is None, proc.stdout.read()
        rows = read_telemetry_log(telemetry_log) if telemetry_log.exists() else []
        if rows and rows[-1]["mission_item"] >= min_item:
            return
        time.sleep(0.1)
    raise AssertionError("the scan did not start")


def _seconds_to_rtl(port: int, since: float, timeout_s: float = 20.0) -> float:
    """Listen where the dead companion listened (sending nothing): seconds from ``since`` to the first HEARTBEAT in
    RTL."""
    link = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=99)
    try:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            hb = link.recv_match(type="HEARTBEAT", blocking=True, timeout=0.5)
            if hb is not None and hb.custom_mode == COPTER_RTL:
                return time.monotonic() - since
        raise AssertionError(f"no RTL within {timeout_s:g} s of the kill")
    finally:
        link.close()


def test_killed_companion_vehicle_returns_and_restore_puts_every_parameter_back(tmp_path):
    mission = still_home_demo(tmp_path)
    plan = plan_scan(load_mission(mission))
    home = f"{plan.home.lat},{plan.home.lon},{plan.home.alt_amsl_m}"
    state, telemetry = tmp_path / "state", tmp_path / "flight.jsonl"
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    with SitlVehicle(speedup=20, autopilot="ardupilot", gps_ready_after=1, home=home,
                     log_path=tmp_path / "sim.log") as v:
        before = _read(v.url)
        proc = subprocess.Popen([sys.executable, "-m", "companion.cli", "fly", str(mission), "--connect", v.url,
                                 "--connect-timeout", "60", "--lost-link-action", "rtl", "--return-alt", "auto",
                                 "--no-progress", "--telemetry-log", str(telemetry), "--state-dir", str(state)],
                                cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
        try:
            _wait_for_scan(proc, telemetry, min_item=8)
        finally:
            proc.kill()  # SIGKILL: no way out of the companion runs
            killed = time.monotonic()
            out = proc.communicate()[0]
        assert "MAV_GCS_SYSID set to 245 for this flight" in out, out
        journal = json.loads(next((state / "parameter-journal").glob("system1-*.json")).read_text())
        assert sorted(c["name"] for c in journal["changes"]) == sorted(CHANGED)

        rtl_s = _seconds_to_rtl(v.port, killed)
        assert rtl_s <= FS_GCS_TIMEOUT_S + 1.5  # last heartbeat <= 1 s before the kill

        restore = subprocess.run([sys.executable, "-m", "companion.cli", "restore", "--connect", v.url,
                                  "--connect-timeout", "60", "--state-dir", str(state)], cwd=ROOT,
                                 capture_output=True, text=True, env=env, timeout=120)
        assert restore.returncode == 0, restore.stdout + restore.stderr
        assert f"restored {len(CHANGED)}" in restore.stdout, restore.stdout + restore.stderr
        assert _read(v.url, armable=True) == before  # and the kill's failsafe cleared: the next flight can arm
    assert not list((state / "parameter-journal").glob("*.json"))

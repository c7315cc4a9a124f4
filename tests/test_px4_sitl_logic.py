"""sim/px4_sitl.py and bench/real_px4_checks.py: the pure parts (no PX4 binary: CI has none)."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest

from companion.errors import CompanionError
from sim.px4_sitl import (
    Px4Home,
    Px4Ports,
    find_binary,
    heartbeat_systems,
    prepare_run_dir,
    px4_arguments,
    sitl_environment,
)

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def bench():
    spec = importlib.util.spec_from_file_location("real_px4_checks", ROOT / "bench" / "real_px4_checks.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules["real_px4_checks"] = module
    spec.loader.exec_module(module)
    return module


def test_environment_puts_sih_at_home():
    env = sitl_environment(Px4Home(37.56638, 126.97815, 30.0), speed_factor=4)
    assert env == {"PX4_SIM_MODEL": "sihsim_quadx", "PX4_HOME_LAT": "37.56638000", "PX4_HOME_LON": "126.97815000",
                   "PX4_HOME_ALT": "30.00", "PX4_SIM_SPEED_FACTOR": "4"}
    assert "PX4_SIM_SPEED_FACTOR" not in sitl_environment(Px4Home(0, 0, 0), speed_factor=1.0)


def test_ports_of_an_instance():
    p = Px4Ports(1)
    assert (p.system_id, p.onboard_port, p.companion_url) == (2, 14541, "udp://:14541")
    assert p.watch_url == "udpin:127.0.0.1:14550"


def test_missing_binary_says_how_to_build(tmp_path):
    with pytest.raises(CompanionError) as e:
        find_binary(tmp_path)
    assert "no PX4 SITL binary" in e.value.problem and "built for SITL" in e.value.fix


def test_run_dir_is_fresh_and_px4_runs_in_it(tmp_path):
    run = tmp_path / "run"
    (run / "log").mkdir(parents=True)
    (run / "parameters.bson").write_bytes(b"stale")
    assert prepare_run_dir(run) == run.resolve() and list(run.iterdir()) == []
    # without -w, px4 -i 1 would run in the build's shared rootfs/1 and start from the last run's parameters
    args = px4_arguments(Path("/px4/bin/px4"), Path("/px4/etc"), run, 1)
    assert args == ["/px4/bin/px4", "-d", "-i", "1", "-w", str(run), "/px4/etc"]


def test_heartbeats_are_told_by_their_system():
    """PX4 instance 1 is system 2: its HEARTBEAT counts, another system's or another message does not."""
    from pymavlink.dialects.v20 import common as mavlink

    def packet(system: int, heartbeat: bool = True) -> bytes:
        mav = mavlink.MAVLink(None, srcSystem=system, srcComponent=1)
        msg = (mavlink.MAVLink_heartbeat_message(2, 12, 0, 0, 3, 3) if heartbeat
               else mavlink.MAVLink_system_time_message(0, 1000))
        return msg.pack(mav)

    assert heartbeat_systems(packet(2)) == [2]
    assert heartbeat_systems(packet(1)) == [1] and heartbeat_systems(packet(2, heartbeat=False)) == []
    assert heartbeat_systems(packet(3) + packet(2)) == [3, 2] and heartbeat_systems(b"") == []


def test_px4_mode_decodes_return(bench):
    assert bench.px4_mode((5 << 24) | (4 << 16)) == (4, 5)  # AUTO / RTL
    assert bench.px4_mode((4 << 24) | (4 << 16)) == (4, 4)  # AUTO / MISSION


def test_airborne_is_take_off_to_landing(bench):
    rows = [{"t_boot_s": 10.0, "in_air": False}, {"t_boot_s": 11.0, "in_air": True},
            {"t_boot_s": 12.0, "in_air": None}, {"t_boot_s": 300.0, "in_air": True},
            {"t_boot_s": 301.5, "in_air": False}, {"t_boot_s": 400.0, "in_air": False}]
    assert bench.airborne_s(rows) == 290.5
    assert bench.airborne_s(rows[:4]) is None  # still flying
    assert bench.airborne_s([{"t_boot_s": 1.0, "in_air": False}]) is None


def test_integer_parameters_are_read_from_their_bytes(bench):
    import struct

    as_float = struct.unpack("<f", struct.pack("<i", 2))[0]  # how PX4 sends NAV_DLL_ACT = 2
    assert bench.param_number(as_float, 6) == 2.0  # MAV_PARAM_TYPE_INT32
    assert bench.param_number(0.716, 9) == 0.716  # REAL32


def test_kill_mid_scan_kills_the_companion_once_it_flies_the_item(bench, tmp_path):
    """The lost-link checks SIGKILL the companion mid-scan: only once the telemetry log shows the scan's item, and
    the process is killed (not left flying) whatever happens."""
    import json
    import subprocess
    import threading

    log = tmp_path / "flight.jsonl"
    log.write_text(json.dumps({"mission_item": 2}) + "\n")
    proc = subprocess.Popen([sys.executable, "-c", "import time; print('flying', flush=True); time.sleep(60)"],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    late_item = threading.Timer(
        1.0, lambda: log.write_text(log.read_text() + json.dumps({"mission_item": 5}) + "\n"))
    late_item.start()
    to_item_s, killed, said = bench.kill_mid_scan(proc, log, item=5, after_s=0.1, timeout_s=30.0)
    late_item.join()
    assert 0.9 < to_item_s < 10.0 and proc.returncode == -9 and "flying" in said
    proc = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"], stdout=subprocess.PIPE, text=True)
    with pytest.raises(SystemExit, match="did not reach item 9"):
        bench.kill_mid_scan(proc, log, item=9, after_s=0.0, timeout_s=1.0)
    assert proc.returncode == -9

"""A companion killed mid-scan on REAL ArduCopter SITL: does the vehicle return, and are its parameters put back?
(issue 31's judged check; ``tests/test_flight_sitl_journal.py`` runs the same on the project's simulator.)

Starts ArduPilot's own SITL (a binary the user built, ``sim/ardupilot_sitl.py``) at the demo mission's take-off
point, reads the parameters the flight changes, runs ``companion fly missions/demo-facade.yaml --lost-link-action
rtl --return-alt auto`` as a user would, waits until the scan has begun, kills the companion with SIGKILL, and
listens on the SITL's third port (sending nothing, so no heartbeat of ours keeps the failsafe off) for the first
HEARTBEAT in RTL. Then ``companion restore`` and the parameters read back.

    python bench/real_sitl_lost_link.py --ardupilot ~/ardupilot --out /tmp/real-lost-link [--runs 2]

Prints, per run: seconds from the kill to RTL (ArduCopter's FS_GCS_TIMEOUT is 5 s), what the journal held, what
``restore`` said and whether every parameter read back equal to its value before the flight.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
import time
from pathlib import Path

from pymavlink import mavutil

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench.real_px4_checks import kill_mid_scan  # noqa: E402
from bench.real_px4_checks import read_parameters as _read  # noqa: E402
from companion.mission import load_mission, plan_scan  # noqa: E402
from companion.resources import demo_mission  # noqa: E402
from sim.ardupilot_sitl import ArduCopterSitl  # noqa: E402

CHANGED = ("WP_YAW_BEHAVIOR", "FS_GCS_ENABLE", "RTL_ALT", "MAV_GCS_SYSID")  # what the demo's flight sets on Copter
COPTER_RTL = 6


def read_parameters(url: str) -> dict[str, float]:
    """The parameters the flight changes, as ArduPilot sends them (integers cast into the float)."""
    return _read(url, CHANGED, ints_bytewise=False)


def seconds_to_rtl(link, since: float, timeout_s: float = 30.0) -> float | None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        hb = link.recv_match(type="HEARTBEAT", blocking=True, timeout=0.5)
        if hb is not None and hb.type not in (mavutil.mavlink.MAV_TYPE_GCS,) and hb.custom_mode == COPTER_RTL:
            return round(time.monotonic() - since, 2)
    return None


def one_run(k: int, args, mission: Path, plan) -> dict:
    run = args.out / f"run{k}"
    if run.exists():
        shutil.rmtree(run)
    run.mkdir(parents=True)
    home = (plan.home.lat, plan.home.lon, plan.home.alt_amsl_m, plan.frame.yaw_facing_wall_deg)
    state, telemetry = run / "state", run / "flight.jsonl"
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    with ArduCopterSitl(args.ardupilot, home=home, run_dir=run / "sitl", instance=args.instance) as sitl:
        before = read_parameters(sitl.watch_url)
        proc = subprocess.Popen([sys.executable, "-m", "companion.cli", "fly", str(mission), "--connect",
                                 sitl.companion_url, "--connect-timeout", "90", "--lost-link-action", "rtl",
                                 "--return-alt", "auto", "--no-progress", "--telemetry-log", str(telemetry),
                                 "--state-dir", str(state)],
                                cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
        watch = mavutil.mavlink_connection(sitl.watch_url, source_system=99)  # listens, sends nothing
        to_scan_s, killed, said = kill_mid_scan(proc, telemetry, args.kill_at_item, args.kill_after_s, 300.0)
        rtl_s = seconds_to_rtl(watch, killed)
        watch.close()
        journal = sorted(c["name"] for f in (state / "parameter-journal").glob("*.json")
                         for c in json.loads(f.read_text())["changes"])
        during = read_parameters(sitl.watch_url)
        restore = subprocess.run([sys.executable, "-m", "companion.cli", "restore", "--connect", sitl.companion_url,
                                  "--connect-timeout", "60", "--state-dir", str(state)], cwd=ROOT,
                                 capture_output=True, text=True, env=env, timeout=180)
        after = read_parameters(sitl.watch_url)
    (run / "fly.log").write_text(said)
    (run / "restore.log").write_text(restore.stdout + restore.stderr)
    return {"run": k, "kill_at_item": args.kill_at_item, "seconds_to_scan": round(to_scan_s, 1),
            "gcs_sysid_line": next((ln for ln in said.splitlines() if "MAV_GCS_SYSID" in ln), None),
            "seconds_kill_to_rtl": rtl_s, "journal": journal, "before": before, "after_kill": during,
            "restore_rc": restore.returncode,
            "restore_said": [ln for ln in restore.stdout.splitlines() if "restor" in ln.lower()][-3:],
            "after_restore": after, "restored_all": after == before,
            "journal_left": sorted(p.name for p in (state / "parameter-journal").glob("*.json"))}


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--ardupilot", type=Path, required=True, help="an ArduPilot source tree built for SITL")
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--runs", type=int, default=1)
    p.add_argument("--instance", type=int, default=0, help="SITL instance: TCP ports 5760 + 10 x instance")
    p.add_argument("--kill-at-item", type=int, default=8, help="kill once the mission reached this item")
    p.add_argument("--kill-after-s", type=float, default=3.0, help="... and this many seconds more")
    args = p.parse_args()
    mission = demo_mission()
    plan = plan_scan(load_mission(mission))
    print(f"# {platform.node()}, python {platform.python_version()}; demo mission on real ArduCopter SITL "
          f"({args.ardupilot}); companion killed with SIGKILL at item {args.kill_at_item} + {args.kill_after_s:g} s")
    rows = []
    for k in range(args.runs):
        rows.append(one_run(k, args, mission, plan))
        print(json.dumps(rows[-1]), flush=True)
    (args.out / "real_sitl_lost_link.json").write_text(json.dumps(rows, indent=1))
    ok = all(r["seconds_kill_to_rtl"] is not None and r["restored_all"] and r["restore_rc"] == 0 for r in rows)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())

"""Issue 31's judged checks on REAL PX4 SITL (SIH quadx): the companion killed mid-scan, and the demo flown whole.
(``bench/real_sitl_lost_link.py`` runs the first on real ArduCopter; ``tests/test_flight_sitl_journal.py`` on the
project's simulator.)

Starts PX4's own SITL (a binary the user built, ``sim/px4_sitl.py``) at the demo mission's take-off point in a fresh
working directory per run and runs ``companion fly`` as a user would (``--connect udp://:1454N``).

``lost-link``: reads the parameters the flight changes, flies with ``--lost-link-action rtl``, waits until the scan
has begun, kills the companion with SIGKILL and listens on PX4's GCS port (UDP 14550, sending nothing: no heartbeat
of ours keeps the failsafe off) for the first HEARTBEAT in Return (custom_mode main mode AUTO 4, sub mode RTL 5).
Then ``companion restore`` and the parameters read back. PX4 sees the link lost COM_DL_LOSS_T after the last
heartbeat, holds COM_FAIL_ACT_T (5 s), then returns. PX4's SITL startup (init.d-posix/rcS) sets COM_DL_LOSS_T to
10 s x PX4_SIM_SPEED_FACTOR (40 s at 4x), so the bench prints autopilot seconds (from the last logged sample to the
first Return heartbeat) beside the wall's.

``demo``: flies the whole demo and prints the take-off-to-landing time in autopilot time (first to last in-air row
of the telemetry log: the speed factor and the machine's load do not change it) and ``bench/flight_judge.py``'s
figures (standoff, heading, speed per scan leg).

    python bench/real_px4_checks.py lost-link --px4 ~/PX4-Autopilot --out /tmp/px4-lost-link
    python bench/real_px4_checks.py demo --px4 ~/PX4-Autopilot --out /tmp/px4-demo --runs 2 \\
        [--companion /path/to/another/checkout] [--speed-factor 4] [--sitl-profile sim/sitl/px4-sih.yaml]

``--companion`` flies another checkout of the project (e.g. a ``git worktree`` at an older commit) against the same
PX4, to compare flight times; the judge and this script stay this checkout's.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import struct
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from companion.flight import read_telemetry_log  # noqa: E402
from companion.mission import load_mission, plan_scan  # noqa: E402
from companion.resources import demo_mission  # noqa: E402
from sim.px4_sitl import Px4Home, Px4Sitl  # noqa: E402

# what a PX4 demo flight may change: the lost-link pair, flight_parameters' vertical-scan set and gains, the SIH
# profile's
CHANGED = ("NAV_DLL_ACT", "COM_DLL_EXCEPT", "MPC_Z_V_AUTO_UP", "MPC_Z_V_AUTO_DN", "NAV_MC_ALT_RAD",
           "MPC_Z_VEL_MAX_UP", "MPC_Z_VEL_MAX_DN", "MPC_XY_P", "MPC_XY_VEL_P_ACC", "EKF2_ACC_NOISE", "EKF2_GYR_NOISE")
PX4_MAIN_AUTO, PX4_SUB_AUTO_RTL = 4, 5


def px4_mode(custom_mode: int) -> tuple[int, int]:
    """PX4's HEARTBEAT custom_mode -> (main mode, sub mode): bits 16-23 and 24-31 (px4_custom_mode.h)."""
    return (custom_mode >> 16) & 0xFF, (custom_mode >> 24) & 0xFF


def airborne_s(rows: list[dict]) -> float | None:
    """Autopilot seconds from the first in-air row to the first landed row after the last in-air one (take-off to
    landing), or None when the log never shows both."""
    stamped = [r for r in rows if r.get("t_boot_s") is not None and r.get("in_air") is not None]
    air = [k for k, r in enumerate(stamped) if r["in_air"]]
    if not air or air[-1] + 1 >= len(stamped):
        return None
    return round(stamped[air[-1] + 1]["t_boot_s"] - stamped[air[0]]["t_boot_s"], 1)


def param_number(value: float, param_type: int, ints_bytewise: bool = True) -> float:
    """A PARAM_VALUE's value: PX4 sends integer parameters as their bytes in the float (NAV_DLL_ACT 2 arrives as
    2.8e-45, which reads 0.0 rounded), so an integer type is read back from those bytes; ArduPilot casts them
    (``ints_bytewise=False``)."""
    if ints_bytewise and param_type in (1, 2, 3, 4, 5, 6):  # MAV_PARAM_TYPE_UINT8 .. INT32
        return float(struct.unpack("<i", struct.pack("<f", value))[0])
    return round(float(value), 4)


def read_parameters(url: str, names=CHANGED, timeout_s: float = 30.0, ints_bytewise: bool = True) -> dict[str, float]:
    """PARAM_REQUEST_READ for each name over a plain MAVLink link (no heartbeats sent). PX4 answers integers as
    their bytes in the float (``param_number``)."""
    from pymavlink import mavutil

    link = mavutil.mavlink_connection(url, source_system=98)
    try:
        hb = link.wait_heartbeat(timeout=timeout_s)
        if hb is None:
            raise SystemExit(f"no HEARTBEAT on {url}")
        out: dict[str, float] = {}
        deadline = time.monotonic() + timeout_s
        while len(out) < len(names) and time.monotonic() < deadline:
            for name in names:
                if name not in out:
                    link.mav.param_request_read_send(link.target_system, link.target_component, name.encode(), -1)
            end = time.monotonic() + 1.0
            while time.monotonic() < end:
                msg = link.recv_match(type="PARAM_VALUE", blocking=True, timeout=0.2)
                if msg is not None and msg.param_id in names:
                    out[msg.param_id] = param_number(msg.param_value, msg.param_type, ints_bytewise)
        return out
    finally:
        link.close()


def wait_for_item(proc, telemetry_log: Path, min_item: int, timeout_s: float) -> float:
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout_s:
        if proc.poll() is not None:
            raise SystemExit(f"companion fly ended before item {min_item}:\n{proc.stdout.read()}")
        rows = read_telemetry_log(telemetry_log) if telemetry_log.exists() else []
        if rows and rows[-1]["mission_item"] >= min_item:
            return time.monotonic() - t0
        time.sleep(0.5)
    raise SystemExit(f"the flight did not reach item {min_item} in {timeout_s:g} s")


def kill_mid_scan(proc, telemetry_log: Path, item: int, after_s: float, timeout_s: float) -> tuple[float, float, str]:
    """Wait until the companion ``proc`` flies mission item ``item``, let ``after_s`` pass and SIGKILL it (it has no
    way to say goodbye): (seconds to that item, monotonic time of the kill, what it printed). Killed on any error."""
    try:
        to_scan_s = wait_for_item(proc, telemetry_log, item, timeout_s=timeout_s)
        time.sleep(after_s)
    finally:
        proc.kill()
        killed = time.monotonic()
        said = proc.communicate()[0]
    return to_scan_s, killed, said


def seconds_to_rtl(url: str, since: float, system_id: int,
                   timeout_s: float = 60.0) -> tuple[float | None, float | None]:
    """Wall seconds from ``since`` to the first HEARTBEAT in Return, and the autopilot's time_boot_ms (s) then, from
    the last timed message before it (HEARTBEAT has no time): PX4's timeouts run on its clock, which the speed
    factor runs faster than the wall's."""
    from pymavlink import mavutil

    link = mavutil.mavlink_connection(url, source_system=99)  # listens, sends nothing
    boot_s = None
    try:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            msg = link.recv_match(blocking=True, timeout=0.5)
            if msg is None or msg.get_srcSystem() != system_id:
                continue
            if getattr(msg, "time_boot_ms", None) is not None:
                boot_s = msg.time_boot_ms / 1000.0
            if msg.get_type() == "HEARTBEAT" and px4_mode(msg.custom_mode) == (PX4_MAIN_AUTO, PX4_SUB_AUTO_RTL):
                return round(time.monotonic() - since, 2), boot_s
        return None, boot_s
    finally:
        link.close()


def fly_command(args, mission: Path, url: str, telemetry: Path, state: Path, extra=()) -> list[str]:
    cmd = [sys.executable, "-m", "companion.cli", "fly", str(mission), "--connect", url, "--connect-timeout", "90",
           "--no-progress", "--telemetry-log", str(telemetry), "--state-dir", str(state), *extra]
    if args.sitl_profile:
        cmd += ["--sitl-profile", str(Path(args.sitl_profile).resolve())]
    return cmd


def sitl(args, run: Path, plan) -> Px4Sitl:
    return Px4Sitl(args.px4, home=Px4Home(plan.home.lat, plan.home.lon, plan.home.alt_amsl_m), run_dir=run / "px4",
                   instance=args.instance, speed_factor=args.speed_factor)


def lost_link_run(k: int, args, mission: Path, plan) -> dict:
    run = args.out / f"lost-link{k}"
    state, telemetry = run / "state", run / "flight.jsonl"
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    with sitl(args, run, plan) as px4:
        before = read_parameters(px4.ports.watch_url)
        proc = subprocess.Popen(fly_command(args, mission, px4.ports.companion_url, telemetry, state,
                                            ["--lost-link-action", "rtl"]),
                                cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
        to_scan_s, killed, said = kill_mid_scan(proc, telemetry, args.kill_at_item, args.kill_after_s, 900.0)
        rows = read_telemetry_log(telemetry)
        last_heard_s = max((r["t_boot_s"] for r in rows if r.get("t_boot_s") is not None), default=None)
        rtl_s, rtl_boot_s = seconds_to_rtl(px4.ports.watch_url, killed, px4.ports.system_id, timeout_s=120.0)
        journal = sorted(c["name"] for f in (state / "parameter-journal").glob("*.json")
                         for c in json.loads(f.read_text())["changes"])
        during = read_parameters(px4.ports.watch_url)
        restore = subprocess.run([sys.executable, "-m", "companion.cli", "restore", "--connect",
                                  px4.ports.companion_url, "--connect-timeout", "60", "--state-dir", str(state)],
                                 cwd=ROOT, capture_output=True, text=True, env=env, timeout=300)
        after = read_parameters(px4.ports.watch_url)
    (run / "fly.log").write_text(said)
    (run / "restore.log").write_text(restore.stdout + restore.stderr)
    return {"run": k, "kill_at_item": args.kill_at_item, "seconds_to_item": round(to_scan_s, 1),
            "seconds_kill_to_rtl_wall": rtl_s, "autopilot_s_last_logged_to_rtl":
                None if rtl_boot_s is None or last_heard_s is None else round(rtl_boot_s - last_heard_s, 2),
            "speed_factor": args.speed_factor, "journal": journal,
            "before": before, "after_kill": during, "restore_rc": restore.returncode,
            "restore_said": [ln for ln in restore.stdout.splitlines() if "restor" in ln.lower()][-3:],
            "after_restore": after, "restored_all": after == before,
            "journal_left": sorted(p.name for p in (state / "parameter-journal").glob("*.json"))}


def demo_run(k: int, args, mission: Path, plan) -> dict:
    run = args.out / f"demo{k}"
    state, telemetry = run / "state", run / "flight.jsonl"
    checkout = Path(args.companion).resolve() if args.companion else ROOT
    env = dict(os.environ, PYTHONPATH=str(checkout))
    t0 = time.monotonic()
    with sitl(args, run, plan) as px4:
        fly = subprocess.run(fly_command(args, mission, px4.ports.companion_url, telemetry, state), cwd=checkout,
                             capture_output=True, text=True, env=env, timeout=args.flight_timeout_s)
    (run / "fly.log").write_text(fly.stdout + fly.stderr)
    judge = subprocess.run([sys.executable, str(ROOT / "bench" / "flight_judge.py"), str(mission), str(telemetry)],
                           capture_output=True, text=True, env=dict(os.environ, PYTHONPATH=str(ROOT)))
    (run / "judge.txt").write_text(judge.stdout + judge.stderr)
    worst = next((ln for ln in judge.stdout.splitlines() if ln.startswith("worst:")), None)
    return {"run": k, "companion": str(checkout), "commit": _commit(checkout), "fly_rc": fly.returncode,
            "airborne_s": airborne_s(read_telemetry_log(telemetry)) if telemetry.exists() else None,
            "wall_s": round(time.monotonic() - t0, 1), "speed_factor": args.speed_factor,
            "judge_rc": judge.returncode, "judge_worst": worst,
            "judge_tail": judge.stdout.splitlines()[-3:]}


def _commit(checkout: Path) -> str:
    r = subprocess.run(["git", "-C", str(checkout), "rev-parse", "--short", "HEAD"], capture_output=True, text=True)
    return r.stdout.strip() or "?"


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("check", choices=("lost-link", "demo"))
    p.add_argument("--px4", type=Path, required=True, help="a PX4-Autopilot tree built for SITL (px4_sitl_default)")
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--runs", type=int, default=1)
    p.add_argument("--instance", type=int, default=1, help="PX4 SITL instance: the companion on UDP 14540 + N")
    p.add_argument("--speed-factor", type=float, default=4.0, help="PX4_SIM_SPEED_FACTOR (SIH is lockstep)")
    p.add_argument("--sitl-profile", default=str(ROOT / "sim" / "sitl" / "px4-sih.yaml"),
                   help="companion fly --sitl-profile (default the SIH profile; '' for none)")
    p.add_argument("--companion", help="demo: fly this checkout of the project instead of this one")
    p.add_argument("--kill-at-item", type=int, default=8, help="lost-link: kill once the mission reached this item")
    p.add_argument("--kill-after-s", type=float, default=3.0, help="... and this many seconds more")
    p.add_argument("--flight-timeout-s", type=float, default=1500.0)
    args = p.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    mission = demo_mission()
    plan = plan_scan(load_mission(mission))
    print(f"# {' '.join(sys.argv)}\n# {platform.node()} ({os.cpu_count()} cores, load "
          f"{os.getloadavg()[0]:.2f}), python {platform.python_version()}, "
          f"{datetime.datetime.now(datetime.UTC):%Y-%m-%d %H:%M} UTC; demo mission on real PX4 SITL SIH "
          f"({args.px4}, instance {args.instance}, speed factor {args.speed_factor:g})", flush=True)
    one = lost_link_run if args.check == "lost-link" else demo_run
    rows = []
    for k in range(args.runs):
        rows.append(one(k, args, mission, plan))
        print(json.dumps(rows[-1]), flush=True)
    (args.out / f"real_px4_{args.check}.json").write_text(json.dumps(rows, indent=1))
    if args.check == "lost-link":
        ok = all(r["seconds_kill_to_rtl_wall"] is not None and r["restored_all"] and r["restore_rc"] == 0
                 for r in rows)
    else:
        ok = all(r["fly_rc"] == 0 and r["judge_rc"] == 0 for r in rows)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())

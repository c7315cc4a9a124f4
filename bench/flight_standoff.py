"""Standoff error along the scan legs, flown in SITL: calm air and gusts.

Flies the demo mission through the real stack (simulator process <-MAVLink-> mavsdk <- companion.flight),
reads the companion's telemetry log, and measures for every sample taken while the vehicle flies a scan leg
the horizontal distance to the wall line minus the planned standoff (companion.geo.FacadeFrame). Also counts
scan waypoints reached (a telemetry sample within the item's acceptance radius) and, from the simulator's
truth log, the same error on the true position.

    python bench/flight_standoff.py [--speedup 5] [--mission missions/demo-facade.yaml]
"""

from __future__ import annotations

import argparse
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from companion.files import read_jsonl  # noqa: E402
from companion.flight import fly_mission_sync, read_telemetry_log  # noqa: E402
from companion.mission import items as mi  # noqa: E402
from companion.mission import load_mission, plan_scan  # noqa: E402
from tests.sitl import SitlVehicle  # noqa: E402

CONDITIONS = {
    "calm": {},
    "gusts 5 m/s": {"gusts": 5.0},
    "wind 3 m/s + gusts 5 m/s": {"wind": 3.0, "gusts": 5.0},
}


def waypoint_seqs(plan, items) -> list[int]:
    """Mission seq of each plan waypoint (matched in order by position)."""
    seqs, start = [], 0
    nav = (mi.MAV_CMD_NAV_WAYPOINT, mi.MAV_CMD_NAV_TAKEOFF, mi.MAV_CMD_NAV_LAND)
    for wp in plan.waypoints:
        for k in range(start, len(items)):
            it = items[k]
            if it.command in nav and abs(it.x - wp.lat * 1e7) <= 2 and abs(it.y - wp.lon * 1e7) <= 2 and (
                    it.command == mi.MAV_CMD_NAV_LAND or abs(it.z - wp.rel_alt_m) < 0.05):
                seqs.append(k)
                start = k + 1
                break
        else:
            raise RuntimeError(f"waypoint {wp} not found in the mission items")
    return seqs


def measure(plan, items, rows, standoff_m: float) -> dict:
    seqs = waypoint_seqs(plan, items)
    leg_targets = {seqs[j] for _, j in plan.scan_legs}
    frame = plan.frame
    on_leg = [r for r in rows if r["mission_item"] in leg_targets and r["lat"] is not None and r["in_air"]]
    lat = np.array([r["lat"] for r in on_leg])
    lon = np.array([r["lon"] for r in on_leg])
    alt = np.array([r["alt_amsl_m"] for r in on_leg])
    _, out, _ = frame.geodetic_to_facade(lat, lon, alt)
    err = np.abs(np.asarray(out) - standoff_m)
    # waypoints reached: some sample within the acceptance radius (scan waypoints only)
    all_lat = np.array([r["lat"] for r in rows if r["lat"] is not None])
    all_lon = np.array([r["lon"] for r in rows if r["lat"] is not None])
    all_alt = np.array([r["alt_amsl_m"] for r in rows if r["lat"] is not None])
    a_all, o_all, u_all = frame.geodetic_to_facade(all_lat, all_lon, all_alt)
    scan_wps = sorted({i for leg in plan.scan_legs for i in leg})
    reached = 0
    for i in scan_wps:
        wp = plan.waypoints[i]
        d = np.sqrt((a_all - wp.along_m) ** 2 + (o_all - wp.out_m) ** 2 + (u_all - wp.up_m) ** 2)
        radius = items[seqs[i]].param2 or 2.0
        reached += bool(d.min() <= radius + 0.05) if d.size else 0  # 5 cm: telemetry resolution (mm alt, 1e-7 deg)
    return {"samples": int(err.size), "max": float(err.max()), "p95": float(np.percentile(err, 95)),
            "mean": float(err.mean()), "reached": reached, "scan_waypoints": len(scan_wps)}


def truth_error(plan, truth_path: Path, standoff_m: float, t_ranges) -> dict:
    """Same error on the simulator's true position (50 Hz) during the scan-leg time ranges (boot seconds)."""
    t, lat, lon, alt = [], [], [], []
    for p in read_jsonl(truth_path, skip_bad=False):
        t.append(p["t_s"])
        lat.append(p["lat"])
        lon.append(p["lon"])
        alt.append(p["alt_amsl_m"])
    t = np.array(t)
    mask = np.zeros(t.size, bool)
    for a, b in t_ranges:
        mask |= (t >= a) & (t <= b)
    _, out, _ = plan.frame.geodetic_to_facade(np.array(lat)[mask], np.array(lon)[mask], np.array(alt)[mask])
    err = np.abs(np.asarray(out) - standoff_m)
    return {"samples": int(err.size), "max": float(err.max()), "p95": float(np.percentile(err, 95)),
            "mean": float(err.mean())}


def leg_time_ranges(plan, items, rows):
    seqs = waypoint_seqs(plan, items)
    targets = {seqs[j] for _, j in plan.scan_legs}
    ranges, cur = [], None
    for r in rows:
        ts = r.get("t_boot_s")
        if ts is None:
            continue
        if r["mission_item"] in targets:
            cur = [ts, ts] if cur is None else [cur[0], ts]
        elif cur is not None:
            ranges.append(tuple(cur))
            cur = None
    if cur is not None:
        ranges.append(tuple(cur))
    return ranges


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--mission", default=str(ROOT / "missions/demo-facade.yaml"))
    ap.add_argument("--speedup", type=float, default=5.0)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--rate", type=float, default=10.0, help="requested telemetry rate, Hz of simulated time")
    ap.add_argument("--only", choices=list(CONDITIONS), action="append")
    args = ap.parse_args()
    mission = load_mission(args.mission)
    plan = plan_scan(mission)
    items = plan.mavlink_items("px4")
    print(f"mission {mission.name}: standoff {mission.standoff_m} m, {len(plan.scan_legs)} scan legs, "
          f"{len(items)} items; speedup {args.speedup:g}, seed {args.seed}; machine: {platform.platform()}, "
          f"{platform.processor() or platform.machine()}")
    print(f"{'condition':28s} {'samples':>7s} {'max m':>6s} {'p95 m':>6s} {'mean m':>6s} {'truth max':>9s} "
          f"{'reached':>8s} {'items':>6s} {'wall s':>6s}")
    ok = True
    for name, opts in CONDITIONS.items():
        if args.only and name not in args.only:
            continue
        with tempfile.TemporaryDirectory() as tmp:
            tel, truth = Path(tmp) / "telemetry.jsonl", Path(tmp) / "truth.jsonl"
            t0 = time.time()
            with SitlVehicle(speedup=args.speedup, seed=args.seed, truth_log=truth, **opts) as v:
                res = fly_mission_sync(plan, v.url, telemetry_log=tel, progress=False, telemetry_rate_hz=args.rate,
                                       handle_signals=False)
            wall = time.time() - t0
            rows = read_telemetry_log(tel)
            m = measure(plan, items, rows, mission.standoff_m)
            tm = truth_error(plan, truth, mission.standoff_m, leg_time_ranges(plan, items, rows))
        target = 0.5 if name == "calm" else 1.0
        ok &= res.completed and m["max"] <= target and m["reached"] == m["scan_waypoints"]
        print(f"{name:28s} {m['samples']:7d} {m['max']:6.3f} {m['p95']:6.3f} {m['mean']:6.3f} {tm['max']:9.3f} "
              f"{m['reached']:>3d}/{m['scan_waypoints']:<4d} {res.items_reached:>2d}/{res.items_total:<3d} "
              f"{wall:6.1f}  {'OK' if res.completed else 'NOT COMPLETED'} (target max <= {target} m)")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())

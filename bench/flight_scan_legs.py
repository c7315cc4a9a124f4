"""Heading and speed on the scan legs of the demo mission, per autopilot flavour, with and without the parameters
``flight_parameters`` (``companion.mission.autopilot``) lists (set by the companion, as in a user's flight),
through the simulator process + mavsdk + companion.flight.

Simulator figures (the simulator's PX4 / ArduCopter flavours), judged from its truth log: worst relative speed
error along a scan leg (middle 60 % of each leg), worst heading error against wall-facing (whole leg), and how far
before its planned end each leg turned (PX4 accepts a waypoint within NAV_MC_ALT_RAD vertically).

    PYTHONPATH=. python bench/flight_scan_legs.py [--speedup 25]
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

from companion.flight import fly_mission_sync
from companion.mission import load_mission, plan_scan
from companion.mission.autopilot import flight_parameters
from sim.evaluate_scan import read_truth_log, scan_leg_reports, worst
from sim.process import SimulatorProcess

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mission", type=Path, default=ROOT / "missions/demo-facade.yaml")
    ap.add_argument("--speedup", type=float, default=25.0)
    args = ap.parse_args()
    plan = plan_scan(load_mission(args.mission))
    print(f"{args.mission.name}: {plan.estimates.strips} scan legs, planned scan speed "
          f"{plan.estimates.scan_speed_m_s:.3f} m/s, wall-facing heading {plan.frame.yaw_facing_wall_deg:.2f} deg")
    h = plan.home
    for autopilot, label, what, boot_params in _cases(plan):
        truth = Path(tempfile.mkdtemp()) / "truth.jsonl"
        text = ",".join(f"{k}={v:g}" for k, v in boot_params.items()) or None
        with SimulatorProcess(speedup=args.speedup, autopilot=autopilot, truth_log=truth, params=text,
                              home=f"{h.lat},{h.lon},{h.alt_amsl_m}") as sim:
            result = fly_mission_sync(what, sim.url, progress=False, handle_signals=False,
                                      flight_timeout_s=300.0, connect_timeout_s=20.0)
        reports = scan_leg_reports(plan, read_truth_log(truth))
        speed_error, yaw_error = worst(reports)
        speeds = [r.median_speed_m_s for r in reports]
        shorts = [r.end_short_m for r in reports]
        changed = ",".join(f"{c.name}={c.during:g}" for c in result.parameter_changes) or "none"
        print(f"{autopilot:9s} {label:24s} completed={result.completed} set by the companion: {changed}; "
              f"worst speed error {speed_error * 100:6.1f} %  worst heading error {yaw_error:5.2f} deg  "
              f"leg speeds {min(speeds):.3f}..{max(speeds):.3f} m/s  "
              f"strip ends short {min(shorts):.2f}..{max(shorts):.2f} m (last {shorts[-1]:.2f})", flush=True)


def _cases(plan):
    """(autopilot, label, what to fly, parameters set at the simulator's boot). The companion sets the plan's
    flight parameters itself when it flies a plan, and none for a bare list of items: so the items list flies the
    firmware defaults (or what was set at boot), the plan flies what a user's flight does."""
    for autopilot in ("px4", "ardupilot"):
        items = plan.mavlink_items(autopilot)
        yield autopilot, "defaults", items, {}
        if autopilot == "px4":
            speeds_only = {k: v for k, v in flight_parameters(plan, autopilot).items() if k != "NAV_MC_ALT_RAD"}
            yield autopilot, "MPC_Z_V_AUTO_* only", items, speeds_only
        yield autopilot, "the plan's parameters", plan, {}

if __name__ == "__main__":
    main()

"""Heading and speed on the scan legs of the demo mission, per autopilot flavour, with and without the parameters
``firmware.flight_parameters`` lists, through the simulator process + mavsdk + companion.flight.

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
from companion.mission.firmware import flight_parameters
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
    for autopilot in ("px4", "ardupilot"):
        for with_params in (False, True):
            params = flight_parameters(plan, autopilot) if with_params else {}
            text = ",".join(f"{k}={v:g}" for k, v in params.items()) or None
            truth = Path(tempfile.mkdtemp()) / "truth.jsonl"
            h = plan.home
            with SimulatorProcess(speedup=args.speedup, autopilot=autopilot, truth_log=truth, params=text,
                                  home=f"{h.lat},{h.lon},{h.alt_amsl_m}") as sim:
                result = fly_mission_sync(plan, sim.url, progress=False, handle_signals=False,
                                          flight_timeout_s=300.0, connect_timeout_s=20.0)
            reports = scan_leg_reports(plan, read_truth_log(truth))
            speed_error, yaw_error = worst(reports)
            speeds = [r.median_speed_m_s for r in reports]
            shorts = [r.end_short_m for r in reports]
            print(f"{autopilot:9s} params {text or '(defaults)':45s} completed={result.completed} "
                  f"worst speed error {speed_error * 100:6.1f} %  worst heading error {yaw_error:5.2f} deg  "
                  f"leg speeds {min(speeds):.3f}..{max(speeds):.3f} m/s  "
                  f"strip ends short {min(shorts):.2f}..{max(shorts):.2f} m (last {shorts[-1]:.2f})", flush=True)


if __name__ == "__main__":
    main()

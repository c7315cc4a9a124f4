"""The demo flown on REAL ArduCopter SITL with a GNSS offset: the true standoff flown and the map's scale (issue 26).

``bench/standoff_bias.py`` flies the project's simulator. This flies ArduPilot's own SITL (a binary the user
built; ``sim/ardupilot_sitl.py`` starts it, nothing here builds one): its EKF and position controller fly the
mission on a GPS that ArduPilot's simulator offsets (``SIM_GPS1_GLTCH``), the simulated camera renders from the
SITL's own truth (SIM_STATE, through ``sim/pose_bridge.py``), and the companion flies and culls exactly as
``companion fly --capture`` does (``run_live_scan``). For each condition it prints:

* the TRUE standoff on the scan legs (SIM_STATE; the legs matched where the vehicle THOUGHT it was, from the
  companion's telemetry log): median and the range after the first strip;
* what the chain measured and the flight's standoff corrections;
* the map stitched with the wall measured (default) and from telemetry alone: scale and placement error against
  the camera's wall texture, beside the placement sigma the report claims.

    python bench/real_sitl_standoff.py --ardupilot ~/ardupilot --out /tmp/real-sitl [--conditions none,away,towards]
        [--rangefinder]

Conditions as ``bench/standoff_bias.py`` (along, out, up metres of GNSS error in the facade frame; ArduPilot's
glitch is constant, so no drift). ``--rangefinder`` adds ArduPilot's SITL rangefinder facing forward, which
measures the ground along its beam and never the wall (``sim/ardupilot_sitl.py``).
"""

from __future__ import annotations

import argparse
import bisect
import json
import platform
import shutil
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench.standoff_bias import (  # noqa: E402
    CONDITIONS,
    _corrections,
    camera_arguments,
    condition_names,
    enu_bias,
    run_conditions,
    stitch_both_ways,
)
from companion.files import read_jsonl  # noqa: E402
from companion.onboard.live import run_live_scan  # noqa: E402
from companion.resources import demo_mission  # noqa: E402
from sim.ardupilot_sitl import ArduCopterSitl, SitlParameters  # noqa: E402
from sim.demo import plan_for_camera, true_standoff  # noqa: E402
from sim.external_rig import ExternalSitlRig  # noqa: E402


def with_estimate(truth: list[dict], telemetry: list[dict]) -> list[dict]:
    """The bridge's true poses, each with the autopilot's estimate at its time (``nav_lat``, ``nav_lon``,
    ``nav_alt_amsl_m``: linear between the telemetry log's rows) and ``in_air`` from the log; poses outside the
    log's span are left out."""
    rows = [r for r in telemetry if r.get("t_boot_s") is not None and r.get("lat") is not None]
    times = [r["t_boot_s"] for r in rows]
    out = []
    for pose in truth:
        t = pose["t_s"]
        k = bisect.bisect_left(times, t)
        if k == 0 or k >= len(rows):
            continue
        a, b = rows[k - 1], rows[k]
        w = 0.0 if b["t_boot_s"] == a["t_boot_s"] else (t - a["t_boot_s"]) / (b["t_boot_s"] - a["t_boot_s"])
        nav = {f"nav_{key}": a[key] + w * (b[key] - a[key]) for key in ("lat", "lon", "alt_amsl_m")}
        out.append({**pose, **nav, "in_air": b.get("in_air") is not False})
    return out


def run_condition(name: str, args, plan, mission_path: Path) -> dict:
    (along, out, up), drift = CONDITIONS[name]
    if drift:
        raise SystemExit(f"{name}: ArduPilot's SIM_GPS1_GLTCH is a constant offset; drift is not simulated there")
    bias = enu_bias(plan.frame, along, out, up)
    run = args.out / name
    if run.exists():
        shutil.rmtree(run)
    home = (plan.home.lat, plan.home.lon, plan.home.alt_amsl_m, plan.frame.yaw_facing_wall_deg)
    params = SitlParameters(gnss_offset_enu_m=bias, forward_rangefinder=args.rangefinder)
    t0 = time.monotonic()
    with ArduCopterSitl(args.ardupilot, home=home, run_dir=run / "sitl", parameters=params) as sitl, \
            ExternalSitlRig(mission_path, sitl.bridge_url, log_dir=run / "sim", seed=args.seed, width_px=args.width,
                            fps=args.fps, truth_log=run / "sim" / "truth.jsonl") as rig:
        scan = run_live_scan(plan, sitl.companion_url, rig.capture, run / "spool", model=None, mask=True,
                             end_action=plan.mission.end_action, progress=True)
    flight_s = time.monotonic() - t0
    truth = with_estimate(read_jsonl(run / "sim" / "truth.jsonl"), read_jsonl(scan.telemetry_log))
    joined = run / "sim" / "truth-with-estimate.jsonl"
    joined.write_text("".join(json.dumps(r) + "\n" for r in truth))
    cull = json.loads((run / "spool" / "cull_report.json").read_text())
    maps = stitch_both_ways(run, plan, args.seed)
    flight = scan.flight
    ranges = [r["range_forward_m"] for r in read_jsonl(scan.telemetry_log) if r.get("range_forward_m") is not None]
    return {"condition": name, "bias_facade_m": [along, out, up], "rangefinder": args.rangefinder,
            "true_standoff": true_standoff(plan, joined), "measured_standoff": cull.get("standoff"),
            "flight_standoff": None if flight.standoff is None else flight.standoff.line(),
            "corrections": _corrections(flight), "forward_ranges_logged": len(ranges),
            "keyframes": scan.stats.keyframes, "flight_completed": flight.completed,
            "items": f"{flight.items_reached}/{flight.items_total}", "landed": flight.landed,
            "flight_s": round(flight_s, 1), "maps": maps}


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--ardupilot", type=Path, required=True, help="an ArduPilot source tree built for SITL")
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--conditions", default="none,away,towards", help="comma list of none, towards, away")
    p.add_argument("--rangefinder", action="store_true", help="ArduPilot's SITL rangefinder, facing forward")
    camera_arguments(p)
    args = p.parse_args()
    names = condition_names(p, args.conditions)
    mission_path = demo_mission()
    plan = plan_for_camera(mission_path, args.fps)
    print(f"# {platform.node()} {platform.processor() or platform.machine()}, python {platform.python_version()}; "
          f"demo mission on real ArduCopter SITL ({args.ardupilot}), camera {args.width} px @ {args.fps:g} fps, "
          f"rangefinder {'on' if args.rangefinder else 'off'}")
    run_conditions(names, lambda name: run_condition(name, args, plan, mission_path), args.out,
                   "real_sitl_standoff.json")
    return 0


if __name__ == "__main__":
    sys.exit(main())

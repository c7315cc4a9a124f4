"""The demo flown with a biased GNSS: the TRUE standoff flown and the map's scale and placement, measured or not.

Issue 26: a non-RTK receiver is off by a metre or two for minutes. The simulated vehicle flies and reports its
GNSS estimate while the camera renders from the truth (``companion demo --gnss-bias``), so a bias across the wall
puts the vehicle metres off its standoff and scales a map placed by telemetry. For each condition this flies the
whole demo (SITL vehicle + live camera + onboard chain, as `companion demo`), then prints side by side:

* the TRUE standoff on the scan legs (the simulator's truth log): median, and the range after the first strip;
* what the chain measured (the cull report's ``standoff``) and the flight's corrections, when there are any;
* the map stitched twice from the same spool, with the wall measured (default) and from telemetry alone
  (``StitchConfig(measure_wall=False)``, the map before issue 26): its scale error and its placement error at the
  map's centre against the simulator's wall texture, beside the placement sigma its report claims.

    python bench/standoff_bias.py --out /tmp/standoff-bias [--conditions none,towards,away,drift] [--rangefinder]

Conditions are biases in the facade frame (along, out, up metres added to the true position: out negative is
the estimate nearer the wall than the vehicle, so it flies further out): ``none`` (0), ``towards`` (1 m along,
1.5 m nearer: flown at 5.5 m), ``away`` (-1 m along, 1.5 m further: flown at 2.5 m), ``drift`` (``towards`` plus a
0.5 m/min random walk). Every figure is from the simulator.
"""

from __future__ import annotations

import argparse
import json
import platform
import shutil
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from companion.flight.standoff_loop import StandoffOptions  # noqa: E402
from companion.resources import demo_mission  # noqa: E402
from companion.spool.reader import load_spool  # noqa: E402
from companion.stitch import StitchConfig, stitch  # noqa: E402
from companion.stitch.geometry import apply_h  # noqa: E402
from evaluation.stitch.evaluate import truth_homography, truth_on_grid  # noqa: E402
from sim.camera.scene import Scene  # noqa: E402
from sim.demo import fly_demo, plan_for_camera  # noqa: E402

CONDITIONS = {  # (along, out, up) metres of GNSS error, drift m/min
    "none": ((0.0, 0.0, 0.0), 0.0),
    "towards": ((1.0, -1.5, 0.0), 0.0),
    "away": ((-1.0, 1.5, 0.0), 0.0),
    "drift": ((1.0, -1.5, 0.0), 0.5),
}


def enu_bias(frame, along: float, out: float, up: float) -> tuple[float, float, float]:
    de, dn = frame.along_enu
    oe, on = frame.out_enu
    return along * de + out * oe, along * dn + out * on, up


def map_errors(result, texture: np.ndarray, tex_mm: float, wall_h: float) -> dict:
    """Scale error and placement error at the map's centre against the true texture on the map's own grid."""
    truth = truth_on_grid(texture, tex_mm / 1000.0, wall_h, result.grid)
    H = truth_homography(result.map_image, truth, equalize=True)
    if H is None:
        return {"scale_error_percent": None, "placement_error_m": None}
    scale = float(np.sqrt(abs(np.linalg.det(H[:2, :2] / H[2, 2]))))
    centre = np.array([[result.grid.width / 2, result.grid.height / 2]])
    off = float(np.linalg.norm(apply_h(H, centre)[0] - centre[0]) * result.grid.m_per_px)
    anchor = result.report.get("anchor") or {}
    return {"scale_error_percent": round(100 * (scale - 1.0), 2), "placement_error_m": round(off, 3),
            "placement_sigma_m": anchor.get("placement_sigma_m")}


def stitch_both_ways(run: Path, plan, seed: int) -> dict:
    """``run/spool`` stitched with the wall measured (default) and from telemetry alone (the map before issue 26),
    each scored against the camera's wall texture (scene ``seed``)."""
    scene = Scene.build(plan.frame.length_m, float(plan.mission.facade.height_m), seed=seed)
    tex_mm = 5.0
    texture = scene.texture.full_image(tex_mm)
    maps = {}
    for label, cfg in (("measured", StitchConfig()), ("telemetry", StitchConfig(measure_wall=False))):
        dest = run / f"map-{label}"
        if label == "telemetry":  # the same spool and settings: the features and pairs are the first map's
            shutil.copytree(run / "map-measured" / "cache", dest / "cache", dirs_exist_ok=True)
        res = stitch(load_spool(run / "spool"), dest, cfg, progress=False)
        maps[label] = {**map_errors(res, texture, tex_mm, float(plan.mission.facade.height_m)),
                       "mm_per_px": res.mm_per_px, "wall_distance": res.report.get("wall_distance"),
                       "anchored_by": (res.report.get("placement") or {}).get("anchored_by")}
    return maps


def camera_arguments(p: argparse.ArgumentParser) -> None:
    """The live camera's options both flight benches share."""
    p.add_argument("--fps", type=float, default=10.0)
    p.add_argument("--width", type=int, default=640)
    p.add_argument("--seed", type=int, default=0)


def condition_names(parser: argparse.ArgumentParser, text: str) -> list[str]:
    names = [c.strip() for c in text.split(",") if c.strip()]
    unknown = [c for c in names if c not in CONDITIONS]
    if unknown:
        parser.error(f"unknown condition(s) {unknown}; use {', '.join(CONDITIONS)}")
    return names


def run_conditions(names: list[str], run_one, out: Path, json_name: str) -> list[dict]:
    """``run_one(name)`` for each condition, a JSON line as each ends, then the table and ``out/json_name``."""
    rows = []
    for name in names:
        rows.append(run_one(name))
        print(json.dumps(rows[-1], default=str), flush=True)
    print_table(rows)
    out.mkdir(parents=True, exist_ok=True)
    (out / json_name).write_text(json.dumps(rows, indent=1, default=str))
    return rows


def run_condition(name: str, args, plan, mission_path: Path) -> dict:
    """One demo flight under condition ``name`` (``--no-correction``: the flight does not move the scan), its
    spool stitched with and without the wall measured."""
    (along, out, up), drift = CONDITIONS[name]
    bias = enu_bias(plan.frame, along, out, up)
    demo_args = argparse.Namespace(out=args.out / name, seed=args.seed, width=args.width, fps=args.fps,
                                   speedup=args.speedup, model=None, no_mask=False,
                                   gnss_bias=bias if any(bias) else None, gnss_drift=drift,
                                   rangefinder=args.rangefinder)
    t0 = time.monotonic()
    demo = fly_demo(plan, mission_path, demo_args,
                    standoff=StandoffOptions(correct=not args.no_correction) if args.no_correction else None)
    flight_s = time.monotonic() - t0
    cull = json.loads((args.out / name / "spool" / "cull_report.json").read_text())
    maps = stitch_both_ways(args.out / name, plan, args.seed)
    flight = demo.scan.flight
    return {"condition": name, "bias_facade_m": [along, out, up], "drift_m_per_min": drift,
            "true_standoff": demo.standoff, "measured_standoff": cull.get("standoff"),
            "corrections": _corrections(flight),
            "keyframes": demo.scan.stats.keyframes, "flight_completed": flight.completed,
            "flight_s": round(flight_s, 1), "maps": maps}


def _corrections(flight) -> list:
    """The flight's standoff corrections as plain records."""
    out = []
    for c in getattr(flight, "standoff_corrections", None) or []:
        out.append(c.as_json() if hasattr(c, "as_json") else c)
    return out


def print_table(rows: list[dict]) -> None:
    print("| condition | true standoff median (after 1st strip) | chain measured | corrections | scale error "
          "measured / telemetry | placement error (2 sigma) measured / telemetry |")
    print("|---|---|---|---|---|---|")
    for r in rows:
        ts = r["true_standoff"] or {}
        ms = r["measured_standoff"] or {}
        m, t = r["maps"]["measured"], r["maps"]["telemetry"]
        print(f"| {r['condition']} | {ts.get('median_m')} m ({ts.get('after_first_strip_min_m')}-"
              f"{ts.get('after_first_strip_max_m')}) | {ms.get('measured_median_m')} m | {len(r['corrections'])} | "
              f"{m['scale_error_percent']} % / {t['scale_error_percent']} % | {m['placement_error_m']} m "
              f"({_two(m['placement_sigma_m'])}) / {t['placement_error_m']} m ({_two(t['placement_sigma_m'])}) |")


def _two(sigma):
    return None if sigma is None else round(2 * sigma, 3)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--conditions", default="none,towards,away", help=f"comma list of {', '.join(CONDITIONS)}")
    p.add_argument("--rangefinder", action="store_true", help="the vehicle also has a forward rangefinder")
    p.add_argument("--no-correction", action="store_true",
                   help="the flight measures but does not move the scan (the flight before issue 26's loop)")
    p.add_argument("--speedup", type=float, default=1.0)
    camera_arguments(p)
    args = p.parse_args()
    names = condition_names(p, args.conditions)
    mission_path = demo_mission()
    plan = plan_for_camera(mission_path, args.fps)
    print(f"# {platform.node()} {platform.processor() or platform.machine()}, python {platform.python_version()}; "
          f"demo mission, camera {args.width} px @ {args.fps:g} fps, speed-up {args.speedup:g}, rangefinder "
          f"{'on' if args.rangefinder else 'off'}, flight correction {'off' if args.no_correction else 'on'}; "
          "simulator figures")
    run_conditions(names, lambda name: run_condition(name, args, plan, mission_path), args.out, "standoff_bias.json")
    return 0


if __name__ == "__main__":
    sys.exit(main())

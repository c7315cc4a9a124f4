"""Where a culled flight's keyframes are, by flight phase, with each pair's true overlap and the gate's measured R.

    python bench/keyframe_phases.py SPOOL [--mission missions/demo-facade.yaml] [--truth truth.jsonl] [--fps 10]
                                          [--list]

Issue 17: the demo kept 1.5x the planner's expected keyframes. This says where they are. Each keyframe is placed
on the planned path (facade coordinates of its pose; with ``--truth``, the simulator's true pose at its capture
time, else the spool's telemetry pose):

* ``take-off/transit/landing``: more than 0.5 m off the planned standoff (the vehicle climbs, crosses and descends
  facing the wall, 9-14 m out on the demo);
* ``approach`` / ``exit``: on the standoff before the first scan leg / after the last (the descent onto the first
  strip and the climb off the last one, over the roof margin);
* ``strip``: within 0.15 m of a planned scan leg, ``strip end`` within 0.3 m of its ends (the demo's climb off the
  last strip retraces that strip, so its keyframes count here);
* ``turn``: on the standoff between two scan legs (the strip-to-strip move).

Per phase: keyframes, the TRUE overlap of each keyframe with the previous one (footprints on the wall plane from
the poses, ``companion.keyframes.motion.WallMotionPredictor`` with the poses' own distance: the simulator's
definition), the gate's measured R and where it came from (image or telemetry). Against: the planner's expected
count (``--fps``: the camera rate the plan was made for; the demo's default is 10). Simulator figures when the spool
comes from ``companion demo`` / ``companion record``.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from companion.geo import FacadeFrame  # noqa: E402
from companion.keyframes.motion import WallMotionPredictor  # noqa: E402
from companion.mission.geometry import wall_ends  # noqa: E402
from companion.onboard.setup import scan_scope  # noqa: E402
from companion.records import OverlapSource, Pose  # noqa: E402

PHASES = ("take-off/transit/landing", "approach", "strip", "strip end", "turn", "exit")
_NOMINAL_W, _NOMINAL_H = 1600, 900  # overlap depends on the lens and aspect only


def _on_leg(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    """(distance from the segment a-b, distance from its nearer end along it) in the wall plane."""
    ab = b - a
    t = float(np.clip(np.dot(p - a, ab) / max(float(np.dot(ab, ab)), 1e-12), 0.0, 1.0))
    along = t * math.sqrt(float(np.dot(ab, ab)))
    return float(np.linalg.norm(p - (a + t * ab))), min(along, math.sqrt(float(np.dot(ab, ab))) - along)


def classify(plan, centres: list[tuple[float, float, float]]) -> list[str]:
    """One phase per keyframe (facade coordinates along, out, up), in capture order."""
    wps, legs, standoff = plan.waypoints, plan.scan_legs, plan.mission.standoff_m
    segments = [(np.array([wps[i].along_m, wps[i].up_m]), np.array([wps[j].along_m, wps[j].up_m])) for i, j in legs]
    on_strip = []
    for along, out, up in centres:
        p = np.array([along, up])
        best = min((_on_leg(p, a, b) for a, b in segments), key=lambda d: d[0])
        on_strip.append(None if abs(out - standoff) > 0.5 or best[0] > 0.15 else ("strip end" if best[1] < 0.3
                                                                                   else "strip"))
    strip_idx = [k for k, s in enumerate(on_strip) if s is not None]
    first, last = (strip_idx[0], strip_idx[-1]) if strip_idx else (len(centres), -1)
    phases = []
    for k, (_, out, _) in enumerate(centres):
        if abs(out - standoff) > 0.5:
            phases.append("take-off/transit/landing")
        elif on_strip[k] is not None:
            phases.append(on_strip[k])
        else:
            phases.append("approach" if k < first else "exit" if k > last else "turn")
    return phases


def _legs_over_spacing(plan) -> int:
    """The planner's count before issue 17: one keyframe per spacing along each scan leg, plus its start."""
    e, wps = plan.estimates, plan.waypoints
    return sum(math.ceil(math.dist((wps[i].along_m, wps[i].up_m), (wps[j].along_m, wps[j].up_m))
                         / e.keyframe_spacing_m - 1e-9) + 1 for i, j in plan.scan_legs)


def _truth_poses(path: Path, gimbal_pitch: float):
    from sim.evaluate_live import TruthTrack

    truth = TruthTrack(path)

    def at(t: float) -> Pose:
        lat, lon, alt, roll, pitch, yaw = truth.at(t)
        return Pose(t, lat, lon, alt, 0.0, roll, pitch, yaw, gimbal_pitch_deg=gimbal_pitch)

    return at


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("spool", type=Path)
    p.add_argument("--mission", type=Path, default=ROOT / "missions" / "demo-facade.yaml")
    p.add_argument("--truth", type=Path, help="the simulator's truth.jsonl (true poses); default: telemetry poses")
    p.add_argument("--fps", type=float, default=10.0, help="camera rate the plan is made for (demo default 10)")
    p.add_argument("--list", action="store_true", help="one line per keyframe")
    args = p.parse_args()

    from sim.demo import plan_for_camera

    plan = plan_for_camera(args.mission, args.fps)
    mission = plan.mission
    frame = FacadeFrame.from_wall(*wall_ends(mission))
    predictor = WallMotionPredictor(frame, mission.camera.hfov_deg)  # the poses' own distance: truth's definition
    rows = [json.loads(line) for line in (args.spool / "manifest.jsonl").read_text().splitlines() if line.strip()]
    true_pose = _truth_poses(args.truth, float(mission.gimbal_pitch_deg)) if args.truth else None
    poses = [true_pose(r["capture_time_s"]) if true_pose else Pose.from_json(r["pose"]) for r in rows]
    centres = [tuple(float(v) for v in frame.geodetic_to_facade(q.lat, q.lon, q.alt_amsl_m)) for q in poses]
    phases = classify(plan, centres)
    table: dict[str, list] = defaultdict(list)
    for k, r in enumerate(rows):
        side = json.loads((args.spool / r["sidecar"]).read_text())
        motion = None if k == 0 else predictor.predict(poses[k - 1], poses[k], _NOMINAL_W, _NOMINAL_H)
        true = None if motion is None else motion.overlap_percent
        table[phases[k]].append((true, side.get("overlap_to_previous"), side.get("overlap_source")))
        if args.list:
            a, o, u = centres[k]
            measured = side.get("overlap_to_previous")
            print(f"{r['index']:6d} t={r['capture_time_s']:7.1f} {phases[k]:25s} along {a:6.2f} out {o:5.2f} "
                  f"up {u:6.2f} true {'' if true is None else f'{true:5.1f}':>5} R "
                  f"{'' if measured is None else f'{measured:5.1f}':>5} "
                  f"{side.get('overlap_source')} {side.get('reason')}")  # fmt: skip
    expected = plan.estimates.expected_keyframes
    print(f"spool {args.spool}: {len(rows)} keyframes; planner expects {expected} at {args.fps:g} fps "
          f"({len(rows) / expected:.2f}x); poses: {'truth' if args.truth else 'telemetry'}")
    print(f"{'phase':26s} {'keyframes':>9s} {'true overlap mean/min %':>24s} {'measured R mean %':>18s} "
          f"{'R from telemetry':>16s}")
    for phase in PHASES:
        v = table.get(phase, [])
        if not v:
            continue
        t = [x[0] for x in v if x[0] is not None]
        r = [x[1] for x in v if x[1] is not None]
        tel = sum(x[2] in (OverlapSource.TELEMETRY, OverlapSource.TELEMETRY_VETO) for x in v)
        tm = f"{np.mean(t):.1f} / {min(t):.1f}" if t else "-"
        print(f"{phase:26s} {len(v):9d} {tm:>24s} {f'{np.mean(r):.1f}' if r else '-':>18s} {tel:16d}")
    scan = len(rows) - len(table.get("take-off/transit/landing", []))
    print(f"on the standoff (approach, strips, turns, exit): {scan} keyframes ({scan / expected:.2f}x the planner's)")
    # Side by side: the count before issue 17's fix (every frame judged; the planner's legs / spacing) and the
    # chain's gate scope replayed on these keyframes' own telemetry poses (what the chain decides on).
    scope = scan_scope(mission)
    off = sum(scope.off_scan(Pose.from_json(r["pose"]), bool(r.get("pose_stale"))) for r in rows)
    legs_only = _legs_over_spacing(plan)
    print(f"before: {len(rows)} keyframes against legs / spacing {legs_only} ({len(rows) / legs_only:.2f}x); "
          f"the gate scope puts {off} of them off the scan: {len(rows) - off} against the rule's count {expected} "
          f"({(len(rows) - off) / expected:.2f}x)")
    return 0


if __name__ == "__main__":
    sys.exit(main())

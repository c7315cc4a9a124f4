"""The onboard chain (every frame tracked, frames around each decision measured) on a mission flown in SITL.

    python bench/chain_tracker.py [--mission missions/demo-facade.yaml] [--fps 30] [--width 1280] [--speedup 1]
                                  [--busy-core] [--companion-cpus 0]

The chain that masked and measured every frame (the "measure-all" column of the first runs) is gone from the
product; to set a run beside it, run this script at a revision that still has it (``git worktree add ../before
2510c03`` and ``--chains measure-all`` there) with the same mission, seed and camera.

It prints: frames the chain considered per second of flight (tracked or measured, not dropped), frames measured (depth
mask + SIFT), CPU share of one core (the chain's thread, and the whole companion process), keyframes against the
planner's expected count and against the minimum from truth (the paper's rule on the vehicle's true poses, sampled by
the simulator's truth log, over the same span), the lowest true overlap of a keyframe pair (the footprint overlap on the
wall plane from the true poses, ``companion.keyframes.motion``, the simulator's definition), the share of the wall
inside the keyframes' true footprints, and the chain's warnings and gaps. ``--busy-core`` keeps one core busy with a
spinning process for the whole run (a companion computer that also records video); ``--companion-cpus 0`` gives the
companion one core (its threads pinned, as ``taskset -c 0``; the simulated vehicle and camera keep the machine). Figures
are from a simulator."""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import resource
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from busy_core import busy_core  # noqa: E402

from companion.attitude import camera_rotation_enu  # noqa: E402
from companion.geo import FacadeFrame  # noqa: E402
from companion.keyframes.gate_scope import ScanPhase  # noqa: E402
from companion.keyframes.motion import WallMotionPredictor  # noqa: E402
from companion.mission.geometry import wall_ends  # noqa: E402
from companion.onboard.live import run_live_scan  # noqa: E402
from companion.onboard.setup import scan_scope  # noqa: E402
from companion.records import Pose  # noqa: E402
from companion.wall_footprint import facade_from_enu, visible_footprint  # noqa: E402
from sim.evaluate_live import TruthTrack, read_jsonl  # noqa: E402
from sim.rig import SitlRig  # noqa: E402

_NOMINAL_W, _NOMINAL_H = 1600, 900  # the overlap share depends on the lens and the aspect, not the pixel count


def _cpu_s() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


class TrueOverlap:
    """Footprint overlap on the wall plane of two capture times, from the simulator's true poses."""

    def __init__(self, plan, truth: TruthTrack):
        mission = plan.mission
        self.truth = truth
        self.gimbal = float(mission.gimbal_pitch_deg)
        self.predictor = WallMotionPredictor(FacadeFrame.from_wall(*wall_ends(mission)), mission.camera.hfov_deg)

    def pose(self, t: float) -> Pose:
        lat, lon, alt, roll, pitch, yaw = self.truth.at(t)
        return Pose(t, lat, lon, alt, 0.0, roll, pitch, yaw, gimbal_pitch_deg=self.gimbal)

    def percent(self, ta: float, tb: float) -> float | None:
        motion = self.predictor.predict(self.pose(ta), self.pose(tb), _NOMINAL_W, _NOMINAL_H)
        return None if motion is None else motion.overlap_percent

    def coverage(self, times: list[float], length_m: float, height_m: float, cell_m: float = 0.05) -> float:
        """Share of the wall (length x height) inside at least one keyframe's true footprint, on a ``cell_m``
        grid: the coverage a map of these keyframes can reach (the stitcher's coverage is measured on the map)."""
        nx, ny = math.ceil(length_m / cell_m), math.ceil(height_m / cell_m)
        grid = np.zeros((ny, nx), np.uint8)
        to_cell = np.array([[1.0 / cell_m, 0.0], [0.0, -1.0 / cell_m]])
        for t in times:
            lat, lon, alt, roll, pitch, yaw = self.truth.at(t)
            centre = np.array(self.predictor.frame.geodetic_to_facade(lat, lon, alt), dtype=float)
            cam_yaw, cam_pitch, cam_roll = self.pose(t).camera_angles()
            rot = facade_from_enu(self.predictor.frame) @ camera_rotation_enu(
                yaw_deg=cam_yaw, pitch_deg=cam_pitch, roll_deg=cam_roll
            )
            f = (_NOMINAL_W / 2.0) / math.tan(math.radians(self.predictor.hfov_deg) / 2.0)
            K = np.array([[f, 0.0, _NOMINAL_W / 2.0], [0.0, f, _NOMINAL_H / 2.0], [0.0, 0.0, 1.0]])
            poly = visible_footprint(K, _NOMINAL_W, _NOMINAL_H, centre, rot)
            if len(poly) >= 3:
                cells = (poly @ to_cell.T + [0.0, height_m / cell_m]) * 16
                cv2.fillPoly(grid, [np.round(cells).astype(np.int32)], 1, cv2.LINE_8, shift=4)
        return float(grid.mean())

    def minimum_keyframes(self, t0: float, t1: float, rth: float, step_s: float = 1 / 30, scope=None) -> int:
        """The paper's rule on the truth, every ``step_s``: the next keyframe is the last time still >= Rth; a
        stretch with the wall out of view ends the segment (its last view kept, as the gate keeps its candidate)
        and the first time it is back starts a new one.
        ``scope`` (a ``ScanScope``): times whose true pose is off the scan (take-off, transit, landing) count as
        out of view, as the chain does not judge them."""
        count, key, last_ok = 0, None, None
        phase = None if scope is None else ScanPhase(scope)  # the chain's scope: opens on the planned scan only
        for t in np.arange(t0, t1 + 1e-9, step_s):
            if phase is not None and not phase.step(self.pose(t)).judged:
                count += int(key is not None and last_ok > key)  # the segment's last view (the gate's flush)
                key = last_ok = None
                continue
            if key is None:
                if self.percent(t, t) is not None:
                    key = last_ok = t
                    count += 1
                continue
            r = self.percent(key, t)
            if r is None:
                count += int(last_ok > key)  # the segment's last view: the gate keeps its candidate
                key = None
            elif r >= rth:
                last_ok = t
            else:
                key = last_ok if last_ok > key else t
                last_ok = key
                count += 1
        return count


def pin_this_process(cpus: set[int]) -> None:
    """Every thread of this process (the companion) onto ``cpus``; threads started later inherit it. The
    simulator's vehicle and camera processes, started before, keep every core: on a companion board they are
    the autopilot and the camera, not the board."""
    for tid in os.listdir("/proc/self/task"):
        with contextlib.suppress(ProcessLookupError):
            os.sched_setaffinity(int(tid), cpus)


def fly_one(args, out: Path) -> dict:
    rig = SitlRig(args.mission, log_dir=out / "logs", speedup=args.speedup, fps=args.fps, width_px=args.width,
                  truth_log=out / "truth.jsonl", seed=args.seed)  # fmt: skip
    all_cpus = os.sched_getaffinity(0)
    cpu0, wall0 = _cpu_s(), time.monotonic()
    with rig:
        if args.companion_cpus is not None:
            pin_this_process(args.companion_cpus)
        res = run_live_scan(rig.plan, rig.url, rig.capture, out / "spool", mask=True, progress=False,
                            handle_signals=False, end_action="land")  # fmt: skip
        camera = rig.camera_counts
    pin_this_process(all_cpus)
    wall, cpu = time.monotonic() - wall0, _cpu_s() - cpu0
    return _figures(args, "tracker", rig, res, camera() or {}, wall, cpu, out)


def _figures(args, chain, rig, res, camera: dict, wall: float, cpu: float, out: Path) -> dict:
    st = res.stats
    flight_s = res.flight.duration_s
    rth = 100.0 * rig.plan.mission.overlap
    lines = read_jsonl(out / "spool" / "manifest.jsonl")
    truth = TrueOverlap(rig.plan, TruthTrack(out / "truth.jsonl"))
    length_m, height_m = truth.predictor.frame.length_m, float(rig.plan.mission.facade.height_m)
    times = [kf["capture_time_s"] for kf in lines]
    # a keyframe after a gap or opening a new scan segment (the scan left and resumed, e.g. a landing in front of
    # the wall) is not judged against the one before: its pair is counted apart (the chain's gaps say which were
    # gaps within the scan)
    opens = [bool(kf.get("gap_before")) for kf in lines[1:]]
    pairs = [truth.percent(a, b) for a, b, new in zip(times, times[1:], opens, strict=False) if not new]
    known = [p for p in pairs if p is not None]
    considered = st.frames_in - st.skipped_backlog - st.before_telemetry
    return {
        "chain": chain,
        "companion_cpus": sorted(args.companion_cpus) if args.companion_cpus else "all",
        "busy_core": args.busy_core,
        "flight": f"{'completed' if res.flight.completed else 'NOT completed'}, {flight_s:.0f} s wall",
        "camera_frames_sent_dropped": [camera.get("frames_sent"), camera.get("frames_dropped")],
        "frames_received": st.frames_in,
        "frames_skipped_for_cpu": st.skipped_backlog,
        "frames_considered_per_s": round(considered / flight_s, 2),
        "frames_measured": st.frames_measured,
        "chain_thread_cpu_share_of_one_core": round(st.cpu_s / flight_s, 3),
        "companion_process_cpu_share_of_one_core": round(cpu / wall, 3),
        "keyframes": st.keyframes,
        "planner_expected": rig.plan.estimates.expected_keyframes,
        "minimum_from_truth": truth.minimum_keyframes(times[0], times[-1], rth) if times else None,
        "minimum_from_truth_on_the_scan": (truth.minimum_keyframes(times[0], times[-1], rth,
                                                                   scope=scan_scope(rig.plan.mission))
                                           if times else None),
        "lowest_true_overlap_of_a_pair_percent": round(min(known), 1) if known else None,
        "pairs_true_below_rth": sum(p < rth for p in known),
        "pairs_true_below_rth_minus_3": sum(p < rth - 3.0 for p in known),
        "pairs_without_wall_in_view": len(pairs) - len(known),
        "keyframes_after_a_gap_or_new_segment": sum(opens),
        "wall_covered_by_true_footprints": round(truth.coverage(times, length_m, height_m), 4) if times else 0.0,
        "overlap_warnings": st.overlap_warnings,
        "low_overlap_keyframes": st.low_overlap_keyframes,
        "gaps": st.gaps,
        "run_dir": str(out),
    }


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--mission", type=Path, default=ROOT / "missions" / "demo-facade.yaml")
    p.add_argument("--fps", type=float, default=30.0, help="camera frame rate in simulated time")
    p.add_argument("--width", type=int, default=1280)
    p.add_argument("--speedup", type=float, default=1.0)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--busy-core", action="store_true", help="keep one core busy with another process")
    p.add_argument("--companion-cpus", type=lambda v: {int(c) for c in v.split(",")}, default=None,
                   help="pin the companion process to these CPUs, e.g. 0 (a one-core budget, as taskset -c 0)")
    p.add_argument("--out", type=Path, help="keep the runs here (default: a temp dir)")
    args = p.parse_args()
    out = args.out or Path(tempfile.mkdtemp(prefix="chain-tracker-"))
    with busy_core(args.busy_core):
        print(json.dumps(fly_one(args, out / "tracker"), indent=1), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())

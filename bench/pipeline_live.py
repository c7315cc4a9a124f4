"""Onboard pipeline figures from a SITL flight with live culling: sustained frame rate, CPU use of the companion
process, keyframes per minute, tagging error against the true pose, and the true overlap of keyframe pairs.

    python bench/pipeline_live.py [--mission missions/demo-facade.yaml] [--speedup 1.5] [--fps 3] [--no-mask]

Prints the figures; docs/BENCHMARKS.md records them with this command, the input and the machine.
"""

from __future__ import annotations

import argparse
import json
import resource
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from companion.files import read_jsonl  # noqa: E402
from companion.onboard.live import run_live_scan  # noqa: E402
from companion.spool.layout import MANIFEST  # noqa: E402
from sim.evaluate_live import TruthTrack, keyframe_overlaps, tagging_errors  # noqa: E402
from sim.rig import SitlRig  # noqa: E402


def _cpu_s() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def _pct(values: list[float], q: float) -> float:
    v = sorted(values)
    return v[min(len(v) - 1, int(round(q * (len(v) - 1))))]


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--mission", type=Path, default=ROOT / "missions" / "demo-facade.yaml")
    p.add_argument("--speedup", type=float, default=1.5)
    p.add_argument("--fps", type=float, default=3.0, help="camera frame rate in simulated time")
    p.add_argument("--width", type=int, default=640)
    p.add_argument("--no-mask", action="store_true")
    p.add_argument("--out", type=Path, help="keep the run here (default: a temp dir)")
    args = p.parse_args()
    out = args.out or Path(tempfile.mkdtemp(prefix="pipeline-bench-"))
    rec, truth_log = out / "rec", out / "truth.jsonl"
    rig = SitlRig(args.mission, log_dir=out / "logs", speedup=args.speedup, fps=args.fps, width_px=args.width,
                  record_dir=rec, truth_log=truth_log, record_max_out_m=4.5)  # fmt: skip
    cpu0, wall0 = _cpu_s(), time.monotonic()
    with rig:
        res = run_live_scan(rig.plan, rig.url, rig.capture, out / "spool", mask=not args.no_mask, progress=False,
                            handle_signals=False, end_action="land")  # fmt: skip
    wall = time.monotonic() - wall0
    cpu = _cpu_s() - cpu0
    st = res.stats
    lines = read_jsonl(out / "spool" / MANIFEST)
    tag = tagging_errors(lines, TruthTrack(truth_log))
    pairs = keyframe_overlaps(lines, rec, 100.0 * rig.plan.mission.overlap)
    processed = st.frames_in - st.skipped_backlog - st.before_telemetry
    flight_s = res.flight.duration_s
    figures = {
        "mission": rig.plan.mission.name,
        "camera": f"{args.width} px @ {args.fps:g} fps simulated, speed-up {args.speedup:g} "
        f"({args.fps * args.speedup:g} frames/s offered)",
        "depth_mask": not args.no_mask,
        "flight_completed": res.flight.completed,
        "flight_wall_s": round(flight_s, 1),
        "frames_received": st.frames_in,
        "frames_processed": processed,
        "frames_skipped_for_cpu": st.skipped_backlog,
        "sustained_fps": round(processed / flight_s, 2),
        "companion_cpu_percent_of_one_core": round(100.0 * cpu / wall, 1),
        "keyframes": st.keyframes,
        "keyframes_per_minute_wall": round(60.0 * st.keyframes / flight_s, 1),
        "keyframes_per_minute_flight_time": round(60.0 * st.keyframes / (flight_s * args.speedup), 1),
        "overlap_warnings": st.overlap_warnings,
        "gaps": st.gaps,
        "telemetry_disagrees": st.telemetry_disagrees,
        "tagging_position_error_m": {
            "median": round(statistics.median(e.position_m for e in tag), 3),
            "p95": round(_pct([e.position_m for e in tag], 0.95), 3),
            "max": round(max(e.position_m for e in tag), 3),
        },
        "tagging_attitude_error_deg": {
            "median": round(statistics.median(e.attitude_deg for e in tag), 3),
            "max": round(max(e.attitude_deg for e in tag), 3),
        },
        "scan_keyframe_pairs": len(pairs),
        "pairs_true_overlap_ge_rth_minus_3": sum(pr.true_overlap >= rig.plan.mission.overlap - 0.03 for pr in pairs),
        "pairs_flagged_by_gate": sum(pr.flagged for pr in pairs),
        "pairs_unflagged_below_rth_minus_3": sum(
            (not pr.flagged) and pr.true_overlap < rig.plan.mission.overlap - 0.03 for pr in pairs
        ),
        "run_dir": str(out),
    }
    print(json.dumps(figures, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Where the onboard chain's CPU goes, stage by stage, on a recorded flight fed as the live camera feeds it.

Why: issue 17 asks the chain to keep up with a 1280x720 camera at 30 fps in about 0.6 of one core; before cutting
anything the cost has to be known per stage and per frame. The recording (``companion record --fast``: frames/,
times.csv, telemetry.jsonl) is replayed frame by frame, each frame as the JPEG the simulator camera sends
(``EncodedFrame``: the chain decodes it at its working size, as live), through the chain ``companion cull`` and
``companion demo`` build (``build_chain`` with the mission: scan scope, tracker, depth mask with parallax, gate with
telemetry, cross-check, spool). Nothing is dropped, so the figures are CPU per frame whatever the machine's load.

Run it with another checkout first on ``PYTHONPATH`` (e.g. ``git archive`` of main) to compare code side by side on
the same frames: the script only uses ``build_chain`` and the chain's public counters.
"""

from __future__ import annotations

import argparse
import cProfile
import csv
import json
import pstats
import sys
import tempfile
import time
from pathlib import Path

import cv2

from companion.capture.tagging import FrameTagger
from companion.capture.telemetry import ClockMap, buffer_from_log
from companion.flight.telemetry_log import read_telemetry_log
from companion.onboard.setup import build_chain
from companion.records import EncodedFrame

# (label, module path suffix, function name): cumulative CPU of each, nested stages indented in the print
STAGES = [
    ("process (whole chain)", "onboard/chain.py", "process"),
    ("  decode to the working copy", "onboard/working.py", "of"),
    ("  tag (pose at capture time)", "capture/tagging.py", "tag"),
    ("  scan scope", "keyframes/gate_scope.py", "step"),
    ("  tracker: LK flow", "keyframes/tracker.py", "track"),
    ("    working grey copy", "keyframes/tracker.py", "_working_gray"),
    ("    points seeded", "keyframes/tracker.py", "_seed"),
    ("  tracker: telemetry predictions", "onboard/tracked.py", "_motion"),
    ("  parallax reference (remember)", "depth/masker.py", "remember"),
    ("  held frames bookkeeping", "onboard/tracked.py", "_hold"),
    ("  depth mask (measured frames)", "depth/masker.py", "mask_measured"),
    ("    depth network", "depth/session.py", "disparity"),
    ("    ROI (Eq. 1)", "depth/roi.py", "extract_roi"),
    ("    parallax", "depth/masker.py", "_with_parallax"),
    ("  gate measure", "keyframes/gate.py", "measure"),
    ("  gate push", "keyframes/gate.py", "push"),
    ("    SIFT features", "keyframes/features.py", "extract"),
    ("    overlap (match + RANSAC)", "keyframes/overlap.py", "estimate"),
    ("      FLANN matching", "companion/matching.py", "ratio_test"),
    ("      findHomography", "~", "<built-in method cv2.findHomography>"),
    ("  spool (full decode, JPEG, fsync)", "onboard/chain.py", "_spool"),
    ("  full-resolution bookkeeping", "onboard/working.py", "release_below"),
]


def encoded_frames(folder: Path, start: int, limit: int | None):
    frames = folder / "frames"
    with open(frames / "times.csv", newline="") as fh:
        rows = [(name, float(t)) for name, t in csv.reader(fh) if not name.startswith("#") and name != "name"]
    rows = rows[start:start + limit] if limit else rows[start:]
    first = cv2.imread(str(frames / rows[0][0]))
    h, w = first.shape[:2]
    for k, (name, t) in enumerate(rows):
        yield EncodedFrame(start + k, t, (frames / name).read_bytes(), w, h)


def stage_table(profile: cProfile.Profile, frames: int) -> list[dict]:
    stats = pstats.Stats(profile).stats  # (file, line, name) -> (cc, nc, tt, ct, callers)
    out = []
    for label, path, name in STAGES:
        calls = ct = 0.0
        for (file, _line, fn), (_cc, nc, _tt, cum, _callers) in stats.items():
            if fn == name and file.replace("\\", "/").endswith(path):
                calls += nc
                ct += cum
        out.append({"stage": label, "calls": int(calls), "cpu_s": round(ct, 3),
                    "ms_per_frame": round(1e3 * ct / frames, 2) if frames else None,
                    "ms_per_call": round(1e3 * ct / calls, 2) if calls else None})
    return out


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("recording", type=Path, help="a `companion record` folder (frames/, telemetry.jsonl)")
    p.add_argument("--telemetry", type=Path, help="telemetry log (default: the recording's telemetry.jsonl)")
    p.add_argument("--mission", type=Path, default=Path("missions/demo-facade.yaml"))
    p.add_argument("--start", type=int, default=0, help="first frame (times.csv order)")
    p.add_argument("--limit", type=int, default=None, help="frames to replay (default: all)")
    p.add_argument("--fps", type=float, default=30.0, help="the camera's rate, for the share of one core")
    p.add_argument("--profile", action="store_true", help="per-stage CPU (cProfile inflates Python-heavy stages)")
    p.add_argument("--top", type=int, default=0, help="with --profile: also the N functions with most own CPU")
    p.add_argument("--label", default="", help="name of the code under test, printed with the figures")
    p.add_argument("--out", type=Path, help="spool folder (default: a temp dir)")
    args = p.parse_args()
    rows = read_telemetry_log(args.telemetry or args.recording / "telemetry.jsonl")
    tagger = FrameTagger(buffer_from_log(rows), ClockMap(fixed_offset_s=0.0))
    out = args.out or Path(tempfile.mkdtemp(prefix="chain-profile-"))
    chain = build_chain(out, tagger, mission_path=args.mission)
    profile = cProfile.Profile(time.thread_time) if args.profile else None
    n = 0
    cpu0, wall0 = time.process_time(), time.monotonic()
    for frame in encoded_frames(args.recording, args.start, args.limit):
        if profile is not None:
            profile.enable()
        chain.process(frame)
        if profile is not None:
            profile.disable()
        n += 1
    if profile is not None:
        profile.enable()
    chain.finish()
    if profile is not None:
        profile.disable()
    process_cpu = time.process_time() - cpu0
    st = chain.stats
    kept = [json.loads(x) for x in (out / "manifest.jsonl").read_text().splitlines()]
    overlaps = [k.get("overlap_to_previous") for k in kept[1:] if k.get("overlap_to_previous") is not None]
    simulated_s = n / args.fps
    result = {
        "code": args.label,
        "frames": n,
        "off_scan": st.off_scan,
        "tracked": st.frames_tracked,
        "measured": st.frames_measured,
        "skipped_far_not_decoded": getattr(st, "skipped_far", 0),
        "keyframes": st.keyframes,
        "keyframe_indices_hash": hash(tuple(k["index"] for k in kept)) & 0xFFFFFFFF,
        "lowest_measured_R": round(min(overlaps), 2) if overlaps else None,
        "overlap_warnings": st.overlap_warnings,
        "low_overlap_keyframes": st.low_overlap_keyframes,
        "gaps": st.gaps,
        "chain_cpu_s": round(st.cpu_s, 2),
        "chain_ms_per_frame": round(1e3 * st.cpu_s / n, 2),
        "chain_share_of_one_core_at_fps": round(st.cpu_s / simulated_s, 3),
        "process_cpu_s": round(process_cpu, 2),
        "wall_s": round(time.monotonic() - wall0, 1),
        "spool": str(out),
    }
    print(json.dumps(result, indent=1), flush=True)
    if profile is not None:
        print(f"{'stage':40s} {'calls':>7s} {'CPU s':>8s} {'ms/frame':>9s} {'ms/call':>8s}")
        for row in stage_table(profile, n):
            print(f"{row['stage']:40s} {row['calls']:7d} {row['cpu_s']:8.2f} {row['ms_per_frame'] or 0:9.2f} "
                  f"{row['ms_per_call'] or 0:8.2f}")
        if args.top:
            pstats.Stats(profile).sort_stats("tottime").print_stats(args.top)
    return 0


if __name__ == "__main__":
    sys.exit(main())

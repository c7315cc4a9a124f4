"""`companion cull`: the offline twin of live culling, for recorded flights (video/images + telemetry log)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from companion.capture.sources import open_source
from companion.capture.tagging import FrameTagger
from companion.capture.telemetry import ClockMap, buffer_from_log
from companion.errors import CompanionError
from companion.files import write_atomic
from companion.onboard.diagnose import EmptyCause, EmptyCull, explain_empty_cull
from companion.onboard.setup import build_chain
from companion.progress import progress_bar
from companion.spool.clock import TelemetryWallClock
from companion.spool.layout import CULL_REPORT


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("cull", help="cull a recorded flight into a keyframe spool (offline twin of live culling)")
    p.add_argument("video", help="video file or image folder of the flight")
    p.add_argument("--telemetry", type=Path, required=True, help="telemetry log (JSON lines from companion fly)")
    p.add_argument("--out", type=Path, required=True, help="keyframe spool directory (resumable)")
    p.add_argument("--mission", type=Path, help="mission YAML: overlap threshold, camera and facade for the spool")
    p.add_argument("--model", type=Path, help="depth model (.onnx); default: the shipped model")
    p.add_argument("--no-mask", action="store_true", help="skip background removal (whole frame is ROI)")
    p.add_argument(
        "--time-offset",
        type=float,
        default=0.0,
        help="autopilot boot time (s) at video time 0; frame times + offset = telemetry t_boot_s",
    )
    p.add_argument("--fps", type=float, default=30.0, help="frame rate of an image folder without times.csv")
    p.set_defaults(func=run_cull)


def run_cull(args: argparse.Namespace) -> int:
    from companion.flight.telemetry_log import read_telemetry_log

    if not args.telemetry.is_file():
        raise CompanionError(f"telemetry log {args.telemetry} does not exist", "pass the --telemetry-log of the flight")
    rows = read_telemetry_log(args.telemetry)
    buffer = buffer_from_log(rows)
    if len(buffer) == 0:
        raise CompanionError(f"telemetry log {args.telemetry} holds no usable samples", "check the file")
    camera_to_autopilot = ClockMap(fixed_offset_s=-args.time_offset)
    tagger = FrameTagger(buffer, camera_to_autopilot)
    # EXIF capture times: video time -> autopilot boot time -> Unix time from the log's t_wall beside t_boot_s
    wall_clock = TelemetryWallClock.from_log_rows(rows, camera_to_autopilot)
    if not wall_clock.has_wall_time:
        print(
            f"warning: telemetry log {args.telemetry} has no t_wall times, so keyframe images carry no capture date "
            "(logs from companion fly --telemetry-log have them)"
        )
    chain = build_chain(
        args.out,
        tagger,
        mission_path=args.mission,
        model=args.model,
        mask=not args.no_mask,
        capture_clock=wall_clock,
    )
    source = open_source(args.video, fps=args.fps)
    total = getattr(source, "files", None)
    with source, progress_bar(total=len(total) if total else None, unit="frame", desc="culling") as bar:
        for frame in source:
            chain.process(frame)
            bar.update(1)
            bar.set_postfix(keyframes=chain.stats.keyframes)
        chain.finish()
    chain.stats.capture.corrupt = source.stats.corrupt
    stats = chain.stats.as_dict()
    write_atomic(args.out / CULL_REPORT, json.dumps(stats, indent=1), durable=True)
    print(
        f"{stats['frames_in']} frames -> {chain.stats.keyframes} keyframes in {args.out} "
        f"({stats['corrupt']} corrupt, {stats['dropped_no_roi']} without ROI, {stats['stale_pose']} without pose, "
        f"{stats['before_telemetry']} not placed in the telemetry)"
    )
    empty = explain_empty_cull(chain.stats, tagger)
    if empty is not None:
        raise CompanionError(f"culling {args.video} kept no keyframe: {empty.problem}", _cull_fix(empty, args))
    return 0


def _cull_fix(empty: EmptyCull, args: argparse.Namespace) -> str:
    if empty.shift_s is not None:
        return (
            "frame times + --time-offset must fall inside the telemetry log's t_boot_s: e.g. --time-offset "
            f"{args.time_offset + empty.shift_s:.2f} puts the first frame on the first telemetry sample; or give the "
            "image folder a times.csv (name,seconds) on the autopilot clock, or use the log of this recording's flight"
        )
    if empty.cause is EmptyCause.NO_USABLE_FRAME:
        return "check that the frames show the facade at the standoff; try --no-mask or another --model"
    if empty.cause is EmptyCause.NO_FRAMES:
        return f"check {args.video}: its frames are unreadable (see the warnings above)"
    return "see the warnings above"

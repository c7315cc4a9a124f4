"""The offline twin of live culling: a recorded flight (video file or image folder + telemetry log) through the
same chain (tag -> mask -> gate -> spool), with the frames tagged by a fixed camera-to-autopilot time offset."""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass
from pathlib import Path

from companion.capture.sources import open_source
from companion.capture.tagging import FrameTagger
from companion.capture.telemetry import ClockMap, buffer_from_log
from companion.capture.telemetry_file import load_telemetry_file
from companion.errors import CompanionError
from companion.files import NewOutput, write_atomic
from companion.onboard.chain_stats import ChainStats
from companion.onboard.diagnose import EmptyCause, EmptyCull, explain_empty_cull
from companion.onboard.setup import build_chain
from companion.progress import progress_bar
from companion.spool.clock import TelemetryWallClock
from companion.spool.layout import CULL_REPORT, MANIFEST

log = logging.getLogger(__name__)

@dataclass(frozen=True)
class OfflineCull:
    """A recorded flight to cull; ``time_offset_s`` is the autopilot boot time (s) at video time 0."""

    video: str
    telemetry_log: Path
    spool_dir: Path
    mission_path: Path | None = None
    model: Path | None = None
    mask: bool = True
    parallax: bool = True  # confirm the network's mask by motion parallax (docs/DEPTH.md)
    time_offset_s: float = 0.0
    fps: float = 30.0  # frame rate of an image folder without times.csv


@dataclass(frozen=True)
class OfflineCullResult:
    stats: ChainStats
    # why the run kept no keyframe (e.g. the time_offset_s that would align the clocks); the caller reports the
    # counts first, then raises it
    no_keyframes: CompanionError | None = None


def cull_recorded_flight(request: OfflineCull) -> OfflineCullResult:
    """Cull every frame into the spool and write ``cull_report.json`` beside it.

    The inputs are checked before the spool folder is touched; a run that fails, or keeps no keyframe, after that
    removes what it created there (companion.files.NewOutput) unless the spool holds keyframes (a resumable
    spool's work is never thrown away)."""
    rows = load_telemetry_file(request.telemetry_log)  # every line checked: a wrong file names its line and the fix
    buffer = buffer_from_log(rows)
    camera_to_autopilot = ClockMap(fixed_offset_s=-request.time_offset_s)
    tagger = FrameTagger(buffer, camera_to_autopilot)
    # EXIF capture times: video time -> autopilot boot time -> Unix time from the log's t_wall beside t_boot_s
    wall_clock = TelemetryWallClock.from_log_rows(rows, camera_to_autopilot)
    if not wall_clock.has_wall_time:
        log.warning("telemetry log %s has no t_wall times, so keyframe images carry no capture date (logs from "
                    "companion fly --telemetry-log have them)", request.telemetry_log)
    source = open_source(request.video, fps=request.fps)
    output = NewOutput(request.spool_dir)
    try:
        with source:
            stats = _cull(request, source, tagger, wall_clock)
    except BaseException:
        _take_back(output)
        raise
    empty = explain_empty_cull(stats, tagger)
    if empty is None:
        return OfflineCullResult(stats)
    _take_back(output)
    problem = CompanionError(f"culling {request.video} kept no keyframe: {empty.problem}",
                             _empty_cull_fix(empty, request))
    return OfflineCullResult(stats, problem)


def _cull(request: OfflineCull, source, tagger: FrameTagger, wall_clock: TelemetryWallClock) -> ChainStats:
    """The chain over every frame of ``source``, and ``cull_report.json``."""
    chain = build_chain(request.spool_dir, tagger, mission_path=request.mission_path, model=request.model,
                        mask=request.mask, capture_clock=wall_clock, parallax=request.parallax)
    total = getattr(source, "files", None)
    with progress_bar(total=len(total) if total else None, unit="frame", desc="culling") as bar:
        for frame in source:
            chain.process(frame)
            bar.update(1)
            bar.set_postfix(keyframes=chain.stats.keyframes)
        chain.finish()  # spools the keyframe the gate still held: the bar's last line counts it too
        bar.set_postfix(keyframes=chain.stats.keyframes)
    chain.stats.capture.corrupt = source.stats.corrupt
    chain.stats.capture.corrupt_files = list(source.stats.corrupt_files)
    if source.stats.corrupt_files:
        chain.stats.warnings.append(_corrupt_warning(request.video, source.stats.corrupt_files))
    write_atomic(request.spool_dir / CULL_REPORT, json.dumps(chain.stats.as_dict(), indent=1), durable=True)
    return chain.stats


def _take_back(output: NewOutput) -> None:
    """A failed or empty cull's output removed, unless the spool holds keyframes (from this run or an earlier)."""
    manifest = output.folder / MANIFEST
    if not (manifest.is_file() and manifest.stat().st_size > 0):
        output.remove_created()


def _corrupt_warning(video: str, files: list[str]) -> str:
    """One warning naming the corrupt frames skipped (the first few; cull_report.json's corrupt_files has more)."""
    shown = "; ".join(files[:5]) + (f"; and {len(files) - 5} more" if len(files) > 5 else "")
    return f"{len(files)} corrupt frame(s) in {video} skipped, not culled: {shown}"


def _empty_cull_fix(empty: EmptyCull, request: OfflineCull) -> str:
    if empty.shift_s is not None:
        return (
            "frame times + --time-offset must fall inside the telemetry log's t_boot_s: e.g. --time-offset "
            f"{request.time_offset_s + empty.shift_s:.2f} puts the first frame on the first telemetry sample; or give "
            "the image folder a times.csv (name,seconds) on the autopilot clock, or use the log of this recording's "
            "flight"
        )
    if empty.cause is EmptyCause.OFF_SCAN:
        return "check that the mission's facade ends and standoff are those of the wall this flight scanned"
    if empty.cause is EmptyCause.NO_USABLE_FRAME:
        return "check that the frames show the facade at the standoff; try --no-mask or another --model"
    if empty.cause is EmptyCause.NO_FRAMES:
        return f"check {request.video}: its frames are unreadable (see the warnings above)"
    return "see the warnings above"

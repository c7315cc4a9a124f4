"""Why a cull kept no keyframe: a run that read frames but spooled none is an error, and the error says why.

The usual cause is time: frames are placed on the map by interpolating the telemetry at their capture time on
the autopilot clock, and a frame outside the telemetry's time span cannot be placed (so it is not culled). The
explanation names both spans, so the user sees at once whether the frames are older, later or on another clock,
and by how much (``shift_s`` moves the first frame onto the first telemetry sample).
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

from companion.capture.tagging import FrameTagger
from companion.onboard.chain_stats import ChainStats


class EmptyCause(Enum):
    NO_FRAMES = "no frames"  # nothing readable reached the chain
    NO_TELEMETRY = "no telemetry"  # not a single telemetry sample arrived
    NO_CLOCK = "no clock"  # the camera's clock was never mapped onto the autopilot clock
    BEFORE_TELEMETRY = "before telemetry"  # every frame is older than the first telemetry sample
    AFTER_TELEMETRY = "after telemetry"  # every frame is later than the last telemetry sample
    OUTSIDE_TELEMETRY = "outside telemetry"  # frames straddle the telemetry or fall in its gaps
    OFF_SCAN = "off the scan"  # every placed frame was off the scan (keyframes/gate_scope.py)
    NO_USABLE_FRAME = "no usable frame"  # placed frames, but no facade in the depth mask or no texture to match
    SPOOL = "spool"  # the spool refused every keyframe
    BACKLOG = "backlog"  # every frame was dropped because the worker could not keep up


@dataclass(frozen=True)
class EmptyCull:
    cause: EmptyCause
    problem: str
    shift_s: float | None = None  # add to the frame times to put the first frame on the first telemetry sample


def _span(a: float | None, b: float | None) -> str:
    return "none" if a is None or b is None else f"t = {a:.2f} .. {b:.2f} s"


def explain_empty_cull(stats: ChainStats, tagger: FrameTagger) -> EmptyCull | None:
    """None when the run kept keyframes (or found them already spooled); otherwise the cause and its numbers."""
    if stats.keyframes > 0 or stats.already_spooled > 0:
        return None
    processed = stats.frames_in - stats.skipped_backlog
    if stats.frames_in == 0:
        return EmptyCull(EmptyCause.NO_FRAMES, "no readable frame reached the culling chain")
    if processed <= 0:
        return EmptyCull(EmptyCause.BACKLOG, f"all {stats.frames_in} frames were dropped because culling could "
                                             "not keep up with the camera")
    if stats.spool_errors > 0:
        last = stats.warnings[-1] if stats.warnings else ""
        return EmptyCull(EmptyCause.SPOOL, f"the spool refused every keyframe ({stats.spool_errors} errors; {last})")
    placed = processed - stats.before_telemetry
    if placed > 0 and stats.off_scan >= placed:
        return EmptyCull(EmptyCause.OFF_SCAN, f"all {placed} placed frames were taken more than twice the mission's "
                                              "standoff from its wall or show none of it and its margins (take-off, "
                                              "transit or landing only, or another wall)")
    if placed > 0:
        return EmptyCull(EmptyCause.NO_USABLE_FRAME, f"none of the {placed} placed frames made a keyframe "
                                                     f"({stats.dropped_no_roi} showed no facade in the depth mask, "
                                                     "the others no texture the overlap gate could match)")
    buf = tagger.buffer
    tel_first, tel_last = buf.first_time_s, buf.newest_time_s
    frames_first, frames_last = tagger.earliest_frame_s, tagger.latest_frame_s
    n = processed
    if tel_first is None or tel_last is None:
        return EmptyCull(EmptyCause.NO_TELEMETRY, f"none of the {n} frames could be placed: no telemetry sample "
                                                  "arrived")
    telemetry = f"the telemetry covers {_span(tel_first, tel_last)} on the autopilot clock"
    if frames_first is None or frames_last is None:
        return EmptyCull(EmptyCause.NO_CLOCK, f"none of the {n} frames could be placed: the camera's clock was never "
                                              f"mapped onto the autopilot clock ({telemetry})")
    shift = tel_first - frames_first
    frames = f"frame times {_span(frames_first, frames_last)}"
    if frames_last < tel_first:
        cause, where = EmptyCause.BEFORE_TELEMETRY, f"all {n} frames are older than the first telemetry sample"
    elif frames_first > tel_last:
        cause, where = EmptyCause.AFTER_TELEMETRY, f"all {n} frames are later than the last telemetry sample"
    else:
        cause, where = EmptyCause.OUTSIDE_TELEMETRY, f"none of the {n} frames falls inside the telemetry (gaps?)"
    return EmptyCull(cause, f"no frame could be placed in the telemetry: {where} ({frames}, {telemetry})", shift)

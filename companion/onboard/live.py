"""Live culling during a flight: flight supervision and capture -> tag -> mask -> gate -> spool run concurrently.

The flight code writes every telemetry sample to its JSON-lines log as it arrives; a tailer thread feeds those
samples to the telemetry buffer that tags the frames. The same log therefore serves the live tagging, the
offline `companion cull` twin and the flight record, and the chain never touches the MAVLink connection.
"""

from __future__ import annotations

import json
import logging
import math
import threading
import time
from dataclasses import dataclass
from pathlib import Path

from companion.capture.pacing import RECORDED_TIME_FIX, AutopilotPacedSource, check_recorded_times
from companion.capture.sources import open_source
from companion.capture.tagging import FrameTagger
from companion.capture.telemetry import ClockMap, TelemetryBuffer, pose_from_log_row, row_attitude_held
from companion.errors import CompanionError
from companion.files import write_atomic
from companion.onboard.chain_stats import ChainStats
from companion.onboard.diagnose import EmptyCause, EmptyCull, explain_empty_cull
from companion.onboard.runner import TRACKED_BACKLOG, Backlog, LiveRunner
from companion.onboard.setup import build_chain
from companion.onboard.standoff_watch import standoff_line
from companion.spool.clock import CaptureClock, TelemetryWallClock, UnixCaptureClock
from companion.spool.layout import CULL_REPORT

log = logging.getLogger(__name__)


class TelemetryLogTailer(threading.Thread):
    """Follows a growing telemetry log and feeds each complete line to the buffer (and the clock map)."""

    def __init__(
        self,
        path: Path,
        buffer: TelemetryBuffer,
        clock: ClockMap | None = None,
        poll_s: float = 0.02,
        wall_clock: TelemetryWallClock | None = None,
    ):
        super().__init__(name="telemetry-tail", daemon=True)
        self.path, self.buffer, self.clock, self.poll_s = Path(path), buffer, clock, poll_s
        self.wall_clock = wall_clock  # learns the autopilot boot -> Unix offset for the images' capture times
        self._halt = threading.Event()
        self.rows = 0
        # The flight appends to its log: rows already there are an earlier flight's (another boot clock), and
        # feeding them first would make the buffer refuse this flight's earlier times.
        self.start_offset = self.path.stat().st_size if self.path.exists() else 0

    def stop(self) -> None:
        self._halt.set()

    def run(self) -> None:
        while not self.path.exists() and not self._halt.is_set():
            time.sleep(self.poll_s)
        if self._halt.is_set():
            return
        pending = ""
        with open(self.path) as fh:
            fh.seek(self.start_offset)
            while True:
                chunk = fh.readline()
                if not chunk:
                    if self._halt.is_set():
                        return
                    time.sleep(self.poll_s)
                    continue
                pending += chunk
                if not pending.endswith("\n"):
                    continue  # a line still being written
                line, pending = pending, ""
                try:
                    row = json.loads(line)
                except json.JSONDecodeError:
                    continue
                self.rows += 1
                pose = pose_from_log_row(row)
                if pose is None:
                    continue
                if self.wall_clock is not None and row.get("t_wall") is not None:  # before the pose can tag a frame
                    self.wall_clock.observe(float(row["t_wall"]), pose.time_s)
                self.buffer.add(pose, attitude_held=row_attitude_held(row))
                if self.clock is not None and row.get("t_wall") is not None:
                    self.clock.observe(float(row["t_wall"]), pose.time_s)


@dataclass
class LiveScanResult:
    flight: object  # companion.flight.fly.FlightResult
    stats: ChainStats
    spool_dir: Path
    telemetry_log: Path
    capture_error: str | None = None


class NoKeyframesError(CompanionError):
    """A flight with live culling ended without a single keyframe; ``result`` holds what the run did record."""

    def __init__(self, problem: str, fix: str, result: LiveScanResult):
        super().__init__(problem, fix)
        self.result = result


def run_live_scan(
    plan,
    connect_url: str,
    capture: str,
    out: Path,
    *,
    telemetry_log: Path | None = None,
    model: Path | None = None,
    mask: bool = True,
    parallax: bool = True,
    gcs_camera_url: str | None = None,
    backlog: Backlog | None = None,
    capture_time_offset_s: float = 0.0,
    **fly_kwargs,
) -> LiveScanResult:
    """Fly ``plan`` and cull ``capture`` into the spool ``out`` at the same time.

    ``capture`` is a source spec (see ``open_source``). Frames from the simulator camera are stamped on the
    vehicle's clock; live cameras and streams on the companion's wall clock, mapped to the autopilot clock from
    telemetry. A recording (video file, image folder) is replayed paced on the autopilot clock: its frame times
    + ``capture_time_offset_s`` are autopilot seconds, and each frame is released once the flight's telemetry
    reaches it (``companion.capture.pacing``); times it can never reach are refused before the flight.

    Every frame is followed by the wall tracker and only the frames around each keyframe decision are masked and
    measured (``companion.onboard.tracked``). Frames wait for the chain within ``backlog`` (default: a minute of
    camera time, ``runner.TRACKED_BACKLOG``); after the flight the chain finishes what waits.

    A run that ends without a keyframe raises ``NoKeyframesError`` (after the flight, with the report written),
    saying why: a flight with a camera and no keyframe is a failed capture, never a silent success.
    """
    # Tagging interpolates between telemetry samples: denser samples, smaller errors on fast legs (takeoff).
    fly_kwargs.setdefault("telemetry_rate_hz", 30.0)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    telemetry_log = Path(telemetry_log) if telemetry_log else out / "telemetry.jsonl"
    backlog = backlog or TRACKED_BACKLOG
    buffer = TelemetryBuffer(max_samples=_telemetry_samples(backlog, fly_kwargs["telemetry_rate_hz"]))
    source, paced = _open_capture(capture, buffer, capture_time_offset_s)
    on_autopilot_clock = capture.startswith("sim://") or paced is not None
    clock = ClockMap(fixed_offset_s=0.0) if on_autopilot_clock else ClockMap()
    # Frames on the autopilot clock get their Unix time from the telemetry's t_wall beside t_boot_s; live cameras
    # stamp with the companion's Unix clock already.
    capture_clock = TelemetryWallClock(clock) if on_autopilot_clock else UnixCaptureClock()
    tailer = TelemetryLogTailer(telemetry_log, buffer, None if on_autopilot_clock else clock,
                                wall_clock=capture_clock if on_autopilot_clock else None)
    try:
        tagger = FrameTagger(buffer, clock, wait_for_telemetry_s=TELEMETRY_WAIT_S)
        chain, camera_component = _build(out, tagger, plan, model=model, mask=mask,
                                         gcs_camera_url=gcs_camera_url, capture_clock=capture_clock, parallax=parallax)
    except BaseException:
        source.close()
        raise
    runner = LiveRunner(source, chain, backlog)
    # the standoff the chain measures from the images feeds the flight's standoff loop (issue 26)
    fly_kwargs.setdefault("camera_standoff", lambda: chain.standoff)
    flight = _fly_while_culling(plan, connect_url, telemetry_log, fly_kwargs, tailer=tailer, runner=runner,
                                source=source, paced=paced, camera_component=camera_component)
    return _report(flight, chain, runner, out, telemetry_log, capture, paced)


def _telemetry_samples(backlog: Backlog, rate_hz: float) -> int:
    """Telemetry samples to keep: the chain tags a frame when it reaches it, up to ``backlog.seconds`` after its
    capture, so the buffer reaches back that far and another two minutes (the default ring, 4000 samples, is the
    least)."""
    keep_s = (backlog.seconds or 0.0) + 120.0
    return max(4000, math.ceil(keep_s * max(rate_hz, 1.0) * 1.5))  # 1.5: samples may come faster than asked


def _open_capture(capture: str, buffer: TelemetryBuffer, offset_s: float):
    """The frame source, wrapped to be paced on the autopilot clock when it is a recording (then also returned
    as ``paced``); recorded times no flight can reach are refused here, before take-off."""
    source = open_source(capture)
    if not source.recorded:
        return source, None
    try:
        check_recorded_times(source, offset_s)
    except CompanionError:
        source.close()
        raise
    paced = AutopilotPacedSource(source, buffer, offset_s=offset_s)
    return paced, paced


# A frame newer than the newest telemetry sample waits this long (wall time) for the sample after its capture time,
# so its pose is interpolated rather than held (``FrameTagger``). Samples come every 33-80 ms of autopilot time; the
# recorder holds a position row until the next ATTITUDE and the tailer polls every 20 ms. The limit is the buffer's
# own gap limit: a sample later than that could not tag the frame anyway.
TELEMETRY_WAIT_S = 0.5

# What waits after the flight is at most a minute of camera time (``TRACKED_BACKLOG``); the chain crosses it in a few
# minutes even on a loaded companion. Past this, something hangs: the report is written with what was done.
_CATCH_UP_LIMIT_S = 600.0


def _fly_while_culling(plan, connect_url: str, telemetry_log: Path, fly_kwargs: dict, *, tailer, runner, source,
                       paced, camera_component):
    """Flies the plan with the telemetry tailer and the chain running; stops them in order whatever happens."""
    from companion.flight.fly import fly_mission_sync

    tailer.start()
    runner.start()
    try:
        return fly_mission_sync(plan, connect_url, telemetry_log=telemetry_log, **fly_kwargs)
    finally:
        tailer.stop()
        tailer.join(timeout=5.0)  # reads the log to its end: the buffer holds all the flight's telemetry
        if paced is not None:
            paced.finish()  # releases the frames the telemetry reached, then the recording ends
        else:
            runner.stop()
        if not runner.join(timeout=5.0):
            source.close()  # unblocks a capture thread waiting on a silent camera
            if not runner.wait_for_chain(limit_s=_CATCH_UP_LIMIT_S):
                log.error("the onboard chain did not finish within %.0f s of the flight's end; the report is what it "
                          "had done", _CATCH_UP_LIMIT_S)
        source.close()
        if camera_component is not None:
            camera_component.close()


def _report(flight, chain, runner: LiveRunner, out: Path, telemetry_log: Path, capture: str,
            paced: AutopilotPacedSource | None) -> LiveScanResult:
    """Writes cull_report.json; a run without a keyframe raises ``NoKeyframesError`` saying why."""
    stats = chain.stats
    write_atomic(out / CULL_REPORT, json.dumps(stats.as_dict(), indent=1), durable=True)
    error = str(runner.error) if runner.error else None
    result = LiveScanResult(flight, stats, out, telemetry_log, error)
    empty = explain_empty_cull(stats, chain.tagger)
    if empty is not None:
        raise NoKeyframesError(f"{_flight_summary(flight)}, but live culling of {capture} kept no keyframe: "
                               f"{_problem(empty, runner.error, paced)}", _live_fix(empty, paced is not None), result)
    return result


def _build(
    out: Path, tagger: FrameTagger, plan, *, model, mask: bool, gcs_camera_url: str | None, capture_clock: CaptureClock,
    parallax: bool = True,
):
    """The chain (and the MAVLink camera component that announces its keyframes, when asked for)."""
    camera_component = None
    if gcs_camera_url:
        from companion.onboard.camera_protocol import CameraDescription, MavlinkCamera

        cam = plan.mission.camera
        camera_component = MavlinkCamera(
            gcs_camera_url, CameraDescription(width_px=cam.width_px, height_px=cam.height_px, hfov_deg=cam.hfov_deg)
        ).start()

    def on_keyframe(kf, entry) -> None:
        est = kf.standoff  # the live status line: what a field engineer watches besides the overlap
        log.info("keyframe %d saved (overlap to previous %s); %s", kf.index, kf.overlap_to_previous,
                 standoff_line(None if est is None else est.distance_m, None if est is None else est.sigma_m,
                               float(plan.mission.standoff_m)))
        if camera_component is not None:
            camera_component.publish(kf.pose, entry.image)

    chain = build_chain(out, tagger, mission=plan.mission, model=model, mask=mask, capture_clock=capture_clock,
                        on_keyframe=on_keyframe, parallax=parallax)
    return chain, camera_component


def _flight_summary(flight) -> str:
    done = "the mission completed" if getattr(flight, "completed", False) else "the mission did NOT complete"
    reached, total = getattr(flight, "items_reached", None), getattr(flight, "items_total", None)
    return f"{done} ({reached}/{total} items)" if total else done


def _problem(empty: EmptyCull, capture_error: BaseException | None, paced: AutopilotPacedSource | None) -> str:
    problem = empty.problem
    if empty.cause is EmptyCause.NO_FRAMES and capture_error is not None:
        problem = f"the camera failed: {getattr(capture_error, 'problem', capture_error)}"
    elif empty.cause is EmptyCause.NO_FRAMES and paced is not None and paced.unreached:
        problem = f"no frame of the recording was reached: {'; '.join(paced.stats.notes)}"
    return problem


def _live_fix(empty: EmptyCull, recorded: bool) -> str:
    if recorded and (empty.shift_s is not None or empty.cause is EmptyCause.NO_FRAMES):
        return RECORDED_TIME_FIX
    if empty.shift_s is not None or empty.cause in (EmptyCause.NO_CLOCK, EmptyCause.NO_TELEMETRY):
        return ("the camera's frames must be stamped on a clock the telemetry can be matched to: check that the "
                "telemetry log gets rows (with t_wall) while the camera runs and that the companion's clock is "
                "steady (NTP steps during a flight break the mapping)")
    if empty.cause is EmptyCause.OFF_SCAN:
        return "check that the mission's facade ends and standoff are those of the wall this flight scanned"
    if empty.cause is EmptyCause.NO_USABLE_FRAME:
        return "check that the camera faces the facade at the standoff; try --no-mask or another --model"
    if empty.cause is EmptyCause.NO_FRAMES:
        return "check the camera (cable, device, stream URL): see the warnings above"
    return "see the warnings above"

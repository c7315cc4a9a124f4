"""Live culling during a flight: flight supervision and capture -> tag -> mask -> gate -> spool run concurrently.

The flight code writes every telemetry sample to its JSON-lines log as it arrives; a tailer thread feeds those
samples to the telemetry buffer that tags the frames. The same log therefore serves the live tagging, the
offline `companion cull` twin and the flight record, and the chain never touches the MAVLink connection.
"""

from __future__ import annotations

import json
import logging
import threading
import time
from dataclasses import dataclass
from pathlib import Path

from companion.capture.sources import open_source
from companion.capture.tagging import FrameTagger
from companion.capture.telemetry import ClockMap, TelemetryBuffer, pose_from_log_row
from companion.onboard.chain import ChainStats
from companion.onboard.runner import LiveRunner
from companion.onboard.setup import build_chain
from companion.spool.clock import TelemetryWallClock, UnixCaptureClock

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

    def stop(self) -> None:
        self._halt.set()

    def run(self) -> None:
        while not self.path.exists() and not self._halt.is_set():
            time.sleep(self.poll_s)
        if self._halt.is_set():
            return
        pending = ""
        with open(self.path) as fh:
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
                self.buffer.add(pose)
                if self.clock is not None and row.get("t_wall") is not None:
                    self.clock.observe(float(row["t_wall"]), pose.time_s)


@dataclass
class LiveScanResult:
    flight: object  # companion.flight.fly.FlightResult
    stats: ChainStats
    spool_dir: Path
    telemetry_log: Path
    capture_error: str | None = None


def run_live_scan(
    plan,
    connect_url: str,
    capture: str,
    out: Path,
    *,
    telemetry_log: Path | None = None,
    model: Path | None = None,
    mask: bool = True,
    gcs_camera_url: str | None = None,
    queue_size: int = 3,
    **fly_kwargs,
) -> LiveScanResult:
    """Fly ``plan`` and cull ``capture`` into the spool ``out`` at the same time.

    ``capture`` is a source spec (see ``open_source``). Frames from the simulator camera are stamped on the
    vehicle's clock; other sources on the companion's wall clock, mapped to the autopilot clock from telemetry.
    """
    from companion.flight.fly import fly_mission_sync

    # Tagging interpolates between telemetry samples: denser samples, smaller errors on fast legs (takeoff).
    fly_kwargs.setdefault("telemetry_rate_hz", 30.0)

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    telemetry_log = Path(telemetry_log) if telemetry_log else out / "telemetry.jsonl"
    sim_camera = capture.startswith("sim://")
    buffer = TelemetryBuffer()
    clock = ClockMap(fixed_offset_s=0.0) if sim_camera else ClockMap()
    # The simulator camera stamps frames on the autopilot clock: their Unix time comes from the telemetry's t_wall.
    # Other cameras stamp with the companion's Unix clock already.
    capture_clock = TelemetryWallClock(clock) if sim_camera else UnixCaptureClock()
    tailer = TelemetryLogTailer(
        telemetry_log, buffer, None if sim_camera else clock, wall_clock=capture_clock if sim_camera else None
    )

    camera_component = None
    if gcs_camera_url:
        from companion.onboard.camera_protocol import CameraDescription, MavlinkCamera

        cam = plan.mission.camera
        camera_component = MavlinkCamera(
            gcs_camera_url, CameraDescription(width_px=cam.width_px, height_px=cam.height_px, hfov_deg=cam.hfov_deg)
        ).start()

    def on_keyframe(kf, entry) -> None:
        log.debug("keyframe %d saved (overlap to previous %s)", kf.masked.tagged.frame.index, kf.overlap_to_previous)
        if camera_component is not None:
            camera_component.publish(kf.masked.tagged.pose, entry.image)

    chain = build_chain(
        out,
        FrameTagger(buffer, clock),
        mission=plan.mission,
        model=model,
        mask=mask,
        capture_clock=capture_clock,
        on_keyframe=on_keyframe,
    )
    source = open_source(capture)
    runner = LiveRunner(source, chain, queue_size=queue_size)
    tailer.start()
    runner.start()
    try:
        flight = fly_mission_sync(plan, connect_url, telemetry_log=telemetry_log, **fly_kwargs)
    finally:
        runner.stop()
        if not runner.join(timeout=5.0):
            source.close()  # unblocks a capture thread waiting on a silent camera
            runner.join(timeout=120.0)
        source.close()
        tailer.stop()
        tailer.join(timeout=5.0)
        if camera_component is not None:
            camera_component.close()
    stats = chain.stats
    (out / "cull_report.json").write_text(json.dumps(stats.as_dict(), indent=1))
    error = str(runner.error) if runner.error else None
    return LiveScanResult(flight, stats, out, telemetry_log, error)

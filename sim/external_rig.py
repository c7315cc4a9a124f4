"""The simulated camera flown with an EXTERNAL autopilot SITL (real ArduPilot): camera process + pose bridge.

Why: ``SitlRig`` (sim/rig.py) pairs the camera with our simulated vehicle, which publishes its true pose itself.
A real firmware's SITL does not; the bridge (sim/pose_bridge.py) reads its truth from SIM_STATE on a MAVLink port
the companion does not use and feeds the camera's pose channel, so a GPS error the SITL applies shows in the
images as it would in flight::

    with ExternalSitlRig("missions/demo-facade.yaml", "tcp:127.0.0.1:5762", log_dir="out/logs") as rig:
        # companion fly missions/demo-facade.yaml --connect tcp:127.0.0.1:5760 --capture <rig.capture>
        ...

or from a shell, until Ctrl-C: ``python -m sim external MISSION --connect tcp:127.0.0.1:5762``, which prints the
``companion fly`` line to run beside it.
"""

from __future__ import annotations

import argparse
import contextlib
import signal
import socket
import subprocess
import sys
import threading
from pathlib import Path

from companion.errors import CompanionError
from sim.process import child_environment, free_port, terminate
from sim.rig import camera_arguments, wait_for_line


class ExternalSitlRig:
    def __init__(
        self,
        mission_path: str | Path,
        autopilot_url: str,
        *,
        log_dir: str | Path,
        seed: int = 0,
        width_px: int = 640,
        fps: float = 5.0,
        stream_port: int | None = None,
        gimbal_pitch_deg: float = 0.0,
        record_dir: str | Path | None = None,
        record_max_out_m: float | None = None,
        renderer: str = "warp",
        bridge_timeout_s: float = 60.0,
        truth_log: str | Path | None = None,
    ):
        self.mission_path = Path(mission_path).resolve()
        self.autopilot_url = autopilot_url  # the bridge's MAVLink URL: a port the companion does not use
        self.log_dir = Path(log_dir)
        self.seed, self.width_px, self.fps = seed, width_px, fps
        self.gimbal_pitch_deg = gimbal_pitch_deg
        self.record_dir = Path(record_dir).resolve() if record_dir else None
        self.record_max_out_m = record_max_out_m
        self.renderer = renderer
        self.bridge_timeout_s = bridge_timeout_s
        self.truth_log = Path(truth_log).resolve() if truth_log else None  # the bridge's poses: the SITL's truth
        self.pose_port = free_port(socket.SOCK_DGRAM)
        self.stream_port = stream_port or free_port(socket.SOCK_STREAM)
        self.camera: subprocess.Popen | None = None
        self.bridge: subprocess.Popen | None = None
        self._logs: list = []

    @property
    def capture(self) -> str:
        """``companion fly --capture`` for this rig's camera."""
        return f"sim://127.0.0.1:{self.stream_port}"

    def _spawn(self, args: list[str], name: str) -> tuple[subprocess.Popen, Path]:
        path = self.log_dir / f"{name}.log"
        log = open(path, "w")  # noqa: SIM115 (lives as long as the process)
        self._logs.append(log)
        return subprocess.Popen(args, stdout=log, stderr=subprocess.STDOUT, env=child_environment()), path

    def start(self) -> ExternalSitlRig:
        """Camera first (it must hear every pose), then the bridge; returns once SIM_STATE flows to the camera."""
        self.log_dir.mkdir(parents=True, exist_ok=True)
        self.camera, cam_log = self._spawn(camera_arguments(
            self.mission_path, pose_port=self.pose_port, stream_port=self.stream_port, width_px=self.width_px,
            fps=self.fps, seed=self.seed, renderer=self.renderer, record_dir=self.record_dir,
            record_max_out_m=self.record_max_out_m), "camera")
        if not wait_for_line(self.camera, cam_log, "frames on tcp", 60.0):
            self.stop()
            raise CompanionError("the simulated camera did not start", f"see {cam_log}")
        self.bridge, bridge_log = self._spawn(
            [sys.executable, "-m", "sim", "posebridge", "--connect", self.autopilot_url, "--pose-port",
             str(self.pose_port), "--gimbal-pitch", str(self.gimbal_pitch_deg), "--timeout",
             str(self.bridge_timeout_s / 2),
             *(["--truth-log", str(self.truth_log)] if self.truth_log else [])], "posebridge")
        if not wait_for_line(self.bridge, bridge_log, "SIM_STATE flowing", self.bridge_timeout_s + 5.0):
            said = bridge_log.read_text().strip().splitlines()
            self.stop()
            raise CompanionError(f"the pose bridge to {self.autopilot_url} did not start: "
                                 f"{said[-1] if said else 'no output'}", f"see {bridge_log}")
        return self

    def stop(self) -> None:
        if self.bridge is not None:
            terminate(self.bridge, timeout_s=5.0)
        if self.camera is not None:
            terminate(self.camera, timeout_s=30.0)  # the camera finishes writing its recording on SIGTERM
        for log in self._logs:
            with contextlib.suppress(OSError):
                log.close()
        self._logs.clear()

    def __enter__(self) -> ExternalSitlRig:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m sim external", description=__doc__.split("\n\n")[0])
    p.add_argument("mission", type=Path, help="mission YAML (the facade and camera model)")
    p.add_argument("--connect", required=True,
                   help="the SITL's MAVLink URL for the bridge, one the companion does not use "
                        "(ArduPilot SITL: tcp:127.0.0.1:5762 while the companion flies on 5760)")
    p.add_argument("--log-dir", type=Path, default=Path("out/external-sitl"), help="camera and bridge logs")
    p.add_argument("--stream-port", type=int, help="the camera's TCP frame port (default: a free one)")
    p.add_argument("--width", type=int, default=640)
    p.add_argument("--fps", type=float, default=5.0)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--gimbal-pitch", type=float, default=0.0, metavar="DEG",
                   help="until the vehicle reports its gimbal (default level, as our missions command it)")
    p.add_argument("--record", type=Path, help="also write a recording with ground truth to this directory")
    p.add_argument("--truth-log", type=Path,
                   help="the bridge also appends every pose it publishes here (JSON lines): where the vehicle was")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    rig = ExternalSitlRig(args.mission, args.connect, log_dir=args.log_dir, seed=args.seed, width_px=args.width,
                          fps=args.fps, stream_port=args.stream_port, gimbal_pitch_deg=args.gimbal_pitch,
                          record_dir=args.record, truth_log=args.truth_log)
    done = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: done.set())
    try:
        rig.start()
    except CompanionError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"camera on {rig.capture}, rendering from {args.connect}'s SIM_STATE (logs in {args.log_dir}); fly with\n"
          f"  companion fly {args.mission} --connect <the SITL's other port> --capture {rig.capture}", flush=True)
    try:
        while not done.wait(0.5):
            if rig.camera.poll() is not None or rig.bridge.poll() is not None:
                print(f"error: the camera or the bridge stopped; see {args.log_dir}", file=sys.stderr)
                return 1
    finally:
        rig.stop()
    return 0

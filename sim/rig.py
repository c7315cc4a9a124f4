"""A whole SITL rig in one object: the simulated camera and vehicle processes, wired by the true-pose channel.

    with SitlRig("missions/demo-facade.yaml", speedup=2, fps=5) as rig:
        fly_mission_sync(plan, rig.url)                 # MAVLink, as with a real vehicle
        SimCameraSource(port=rig.stream_port)           # frames, as from a real camera

The camera starts first (so it sees every pose), then the vehicle. Logs go to ``log_dir``.
"""

from __future__ import annotations

import contextlib
import re
import socket
import subprocess
import sys
import time
from pathlib import Path

from companion.errors import CompanionError
from companion.flight.sitl_profile import SitlProfile, load_sitl_profile
from sim.process import SimulatorProcess, child_environment, free_port, terminate, with_mission_wall
from sim.vehicle.flavours import FLAVOURS

# The simulator told to keep home where the vehicle armed (by default its PX4 flavour moves home for 120 s after
# take-off, as real PX4 SIH does: sim/vehicle/home_drift.py).
STILL_HOME = {"home_shift_m": 0}


def sitl_profile_for(autopilot: str) -> SitlProfile | None:
    """What a flight on the simulator's ``autopilot`` flavour asks ``companion fly`` for (``--sitl-profile``): the
    PX4 flavour boots as PX4 SIH does, so its flights ask what real SIH needs; None for a flavour that needs none."""
    path = FLAVOURS[str(autopilot)].sitl_profile
    return load_sitl_profile(path) if path is not None else None


def fly_at_once_with_still_home(mission, sim_options: dict | None = None):
    """``(mission, sim_options)`` for a run about frames, not home (a recording, a test of something else): the
    simulator keeps home still, so the mission starts its scan at once (``margins.home_settle_s`` 0, no 2-minute
    hold). Both together, never one alone: the mission's hold is what keeps a PX4 whose home moves off the ground.
    Options that already say how home moves are kept, and then the mission keeps its hold."""
    options = dict(sim_options or {})
    if "home_shift_m" in options or "home_shift_after_takeoff" in options:
        return mission, options
    margins = mission.margins.model_copy(update={"home_settle_s": 0.0})
    return mission.model_copy(update={"margins": margins}), {**options, **STILL_HOME}


def camera_arguments(mission_path: Path, *, pose_port: int, stream_port: int, width_px: int, fps: float, seed: int,
                     renderer: str, record_dir: Path | None = None, record_max_out_m: float | None = None
                     ) -> list[str]:
    """The ``python -m sim camera`` command line of a rig's camera process (this rig's and sim/external_rig.py's)."""
    args = [sys.executable, "-m", "sim", "camera", str(mission_path), "--pose-port", str(pose_port),
            "--stream-port", str(stream_port), "--width", str(width_px), "--fps", str(fps), "--seed", str(seed),
            "--renderer", renderer]
    if record_dir is not None:
        args += ["--record", str(record_dir)]
        if record_max_out_m is not None:
            args += ["--record-max-out", str(record_max_out_m)]
    return args


def wait_for_line(proc: subprocess.Popen, log_path: Path, text: str, timeout_s: float) -> bool:
    """Wait until the child ``proc`` has written ``text`` to its log; False when it exits or time runs out first."""
    deadline = time.monotonic() + timeout_s
    while text not in log_path.read_text():
        if proc.poll() is not None or time.monotonic() > deadline:
            return False
        time.sleep(0.1)
    return True


class SitlRig:
    def __init__(
        self,
        mission_path: str | Path,
        *,
        log_dir: str | Path,
        seed: int = 0,
        width_px: int = 640,
        fps: float = 5.0,
        speedup: float = 2.0,
        autopilot: str = "px4",
        record_dir: str | Path | None = None,
        record_max_out_m: float | None = None,
        truth_log: str | Path | None = None,
        sim_options: dict | None = None,
        renderer: str = "warp",
    ):
        from companion.mission import load_mission, plan_scan

        self.mission_path = Path(mission_path).resolve()
        self.plan = plan_scan(load_mission(self.mission_path))
        self.log_dir = Path(log_dir)
        self.seed, self.width_px, self.fps, self.speedup = seed, width_px, fps, speedup
        self.autopilot = autopilot
        self.record_dir = Path(record_dir).resolve() if record_dir else None
        self.record_max_out_m = record_max_out_m
        self.truth_log = Path(truth_log).resolve() if truth_log else None
        self.sim_options = dict(sim_options or {})
        self.renderer = renderer
        self.pose_port = free_port(socket.SOCK_DGRAM)
        self.stream_port = free_port(socket.SOCK_STREAM)
        self.camera: subprocess.Popen | None = None
        self.vehicle = None
        self._cam_log = None

    @property
    def url(self) -> str:
        return self.vehicle.url

    @property
    def capture(self) -> str:
        return f"sim://127.0.0.1:{self.stream_port}"

    def start(self) -> SitlRig:

        self.log_dir.mkdir(parents=True, exist_ok=True)
        args = camera_arguments(self.mission_path, pose_port=self.pose_port, stream_port=self.stream_port,
                                width_px=self.width_px, fps=self.fps, seed=self.seed, renderer=self.renderer,
                                record_dir=self.record_dir, record_max_out_m=self.record_max_out_m)
        cam_log_path = self.log_dir / "camera.log"
        self._cam_log = open(cam_log_path, "w")  # noqa: SIM115 (lives as long as the process)
        self.camera = subprocess.Popen(args, stdout=self._cam_log, stderr=subprocess.STDOUT,
                                       env=child_environment())
        if not wait_for_line(self.camera, cam_log_path, "frames on tcp", 60.0):
            self.stop()
            raise CompanionError("the simulated camera did not start", f"see {cam_log_path}")
        home = self.plan.home
        options = with_mission_wall(self.sim_options, self.plan.mission)  # a rangefinder sees this mission's wall
        if self.truth_log is not None:
            options["truth_log"] = str(self.truth_log)
        self.vehicle = SimulatorProcess(
            speedup=self.speedup,
            seed=self.seed,
            pose_port=self.pose_port,
            autopilot=self.autopilot,
            home=f"{home.lat},{home.lon},{home.alt_amsl_m}",
            log_path=self.log_dir / "vehicle.log",
            **options,
        ).start()
        return self

    def stop(self) -> None:
        if self.vehicle is not None:
            with contextlib.suppress(Exception):
                self.vehicle.stop()
        if self.camera is not None:
            terminate(self.camera, timeout_s=30.0)  # the camera finishes writing its recording on SIGTERM
        if self._cam_log is not None:
            self._cam_log.close()
            self._cam_log = None

    def camera_counts(self) -> dict | None:
        """What the camera process reported when it stopped: frames sent, and frames dropped because rendering
        fell behind simulated time (None while it runs, or if it printed no summary)."""
        path = self.log_dir / "camera.log"
        m = re.search(r"camera: (\d+) frames sent, (\d+) dropped", path.read_text()) if path.exists() else None
        return {"frames_sent": int(m.group(1)), "frames_dropped": int(m.group(2))} if m else None

    def __enter__(self) -> SitlRig:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

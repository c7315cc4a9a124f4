"""A real PX4 SITL binary (SIH quadx, headless), started at a mission's take-off point in a fresh working directory.

Why: the project's simulator follows real firmware, but where the two disagree the firmware is right, so the
checks that matter on PX4 (its lost-link failsafe, its position controller on the scan legs, the flight's length)
are run against PX4's own SITL with its built-in SIH physics (no Gazebo). This module only *runs* a binary the user
built (``build/px4_sitl_default/bin/px4`` of a PX4-Autopilot tree); nothing here builds
or fetches one.

What it sets, and why each:

* ``PX4_SIM_MODEL=sihsim_quadx``: the SIH quadrotor, simulated inside the px4 process (lockstep, no simulator to
  start beside it).
* ``PX4_HOME_LAT/LON/ALT`` the mission's take-off point at its ground altitude: SIH puts the vehicle there
  (SIH_LOC_LAT0/LON0/H0), so the wall is where the mission says it is.
* A fresh working directory per run (``-w DIR``, the build's ``etc`` linked into it): PX4 keeps its parameters
  (``parameters.bson``), its mission storage (``dataman``) and its logs in the working directory, and a run started
  in a directory an earlier run used inherits that run's parameters and mission. Every run starts from the same
  vehicle. (Without ``-w`` every run of instance N shares the build's ``rootfs/N``.)
* ``PX4_SIM_SPEED_FACTOR``: SIH is lockstep, so a speed factor runs the autopilot's clock faster than the wall's;
  figures in autopilot time (the telemetry log's ``time_boot_ms``) do not depend on it, a loaded machine only
  slows the run down.

PX4 SITL instance N (``-i N``, system id N + 1) serves MAVLink over UDP: its onboard link sends to
``14540 + N`` (the companion listens there: ``udp://:14541`` for instance 1), its GCS link sends from ``18570 + N``
to ``14550`` (a watcher binds 14550 and listens there, sending nothing).
"""

from __future__ import annotations

import os
import shutil
import socket
import subprocess
import time
from dataclasses import dataclass
from pathlib import Path

from pymavlink.dialects.v20 import common as mavlink

from companion.errors import CompanionError
from sim.process import LoggedProcess

BINARY_IN_TREE = Path("build/px4_sitl_default/bin/px4")
ETC_IN_TREE = Path("build/px4_sitl_default/etc")  # the startup scripts (rcS, airframes) the build generated
GCS_PORT = 14550  # where PX4 SITL's GCS link sends (MAV_0, "remote port 14550"), whatever the instance


@dataclass(frozen=True)
class Px4Home:
    """Where SIH puts the vehicle: the mission's take-off point, ground altitude AMSL."""

    lat_deg: float
    lon_deg: float
    alt_amsl_m: float

    def environment(self) -> dict[str, str]:
        return {"PX4_HOME_LAT": f"{self.lat_deg:.8f}", "PX4_HOME_LON": f"{self.lon_deg:.8f}",
                "PX4_HOME_ALT": f"{self.alt_amsl_m:.2f}"}


@dataclass(frozen=True)
class Px4Ports:
    """The UDP ports of PX4 SITL instance ``instance``."""

    instance: int

    @property
    def system_id(self) -> int:
        return self.instance + 1  # PX4's rcS: MAV_SYS_ID = 1 + instance

    @property
    def onboard_port(self) -> int:
        return 14540 + self.instance  # PX4 sends the onboard link here; the companion binds it

    @property
    def companion_url(self) -> str:
        return f"udp://:{self.onboard_port}"

    @property
    def watch_url(self) -> str:
        """pymavlink: bind the GCS link's remote port (PX4 sends there from the start)."""
        return f"udpin:127.0.0.1:{GCS_PORT}"


def find_binary(px4: Path) -> tuple[Path, Path]:
    """The ``px4`` binary and its ``etc`` of a PX4 tree built for SITL, or a clear error."""
    px4 = Path(px4).expanduser().resolve()
    binary, etc = px4 / BINARY_IN_TREE, px4 / ETC_IN_TREE
    if not binary.is_file():
        raise CompanionError(f"no PX4 SITL binary at {binary}",
                             "give --px4 the top of a PX4-Autopilot source tree built for SITL "
                             "(PX4's own build documentation says how)")
    if not (etc / "init.d-posix" / "rcS").is_file():
        raise CompanionError(f"no {ETC_IN_TREE / 'init.d-posix/rcS'} in {px4}",
                             "give the PX4 tree the binary was built in")
    return binary, etc


def sitl_environment(home: Px4Home, speed_factor: float) -> dict[str, str]:
    """What PX4's rcS reads to start SIH quadx at ``home`` (pure: the tests check it)."""
    env = {"PX4_SIM_MODEL": "sihsim_quadx", **home.environment()}
    if speed_factor != 1.0:
        env["PX4_SIM_SPEED_FACTOR"] = f"{speed_factor:g}"
    return env


def prepare_run_dir(run_dir: Path) -> Path:
    """A clean working directory: no parameters, dataman or logs of an earlier run (px4 links ``etc`` into it)."""
    run_dir = Path(run_dir).resolve()
    if run_dir.exists():
        shutil.rmtree(run_dir)
    run_dir.mkdir(parents=True)
    return run_dir


def px4_arguments(binary: Path, etc: Path, run_dir: Path, instance: int) -> list[str]:
    """``-d``: no interactive shell (stdin is no terminal). ``-w RUN_DIR ETC``: run in the run's own directory, with
    the build's ``etc`` linked into it. Without them px4 -i N runs in the build's ``rootfs/N``, shared by every run
    of that instance: its parameters.bson keeps what the last run set (a save PX4 had not flushed when it was
    stopped is lost too, so a restore can look undone), and the next run starts from that."""
    return [str(binary), "-d", "-i", str(instance), "-w", str(run_dir), str(etc)]


class Px4Sitl(LoggedProcess):
    """``with Px4Sitl(tree, home=Px4Home(...), run_dir=..., instance=1) as sitl:`` ``sitl.ports.companion_url``,
    ``sitl.ports.watch_url``; the process is stopped on exit."""

    def __init__(self, px4: Path, *, home: Px4Home, run_dir: Path, instance: int = 1, speed_factor: float = 1.0,
                 start_timeout_s: float = 60.0):
        self.binary, self.etc = find_binary(px4)
        self.home, self.run_dir, self.speed_factor = home, Path(run_dir), speed_factor
        self.ports, self.start_timeout_s = Px4Ports(instance), start_timeout_s
        super().__init__()

    def start(self) -> Px4Sitl:
        if _udp_bound(18570 + self.ports.instance):
            raise CompanionError(f"PX4 SITL instance {self.ports.instance} seems to run already "
                                 f"(UDP {18570 + self.ports.instance} is bound)", "stop it, or give another instance")
        self.run_dir = prepare_run_dir(self.run_dir)
        env = dict(os.environ, **sitl_environment(self.home, self.speed_factor))
        self._spawn(px4_arguments(self.binary, self.etc, self.run_dir, self.ports.instance), self.run_dir / "px4.log",
                    cwd=self.run_dir, env=env, stdin=subprocess.DEVNULL)
        try:
            self._wait_heartbeat()
        except BaseException:
            self.stop()
            raise
        return self

    def _wait_heartbeat(self) -> None:
        """The first HEARTBEAT of this instance on the GCS link's port, listened to without sending anything."""
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            try:
                s.bind(("127.0.0.1", GCS_PORT))
            except OSError as e:
                raise CompanionError(f"cannot listen on UDP {GCS_PORT} for PX4's heartbeat: {e}",
                                     "stop what holds it (a ground station?)") from e
            s.settimeout(0.5)
            deadline = time.monotonic() + self.start_timeout_s
            while time.monotonic() < deadline:
                if self.process.poll() is not None:
                    raise CompanionError(f"PX4 SITL exited at start (code {self.process.returncode})",
                                         f"see {self.run_dir / 'px4.log'}")
                try:
                    data = s.recv(2048)
                except TimeoutError:
                    continue
                if self.ports.system_id in heartbeat_systems(data):
                    return
        raise CompanionError(f"no HEARTBEAT from PX4 SITL (system {self.ports.system_id}) on UDP {GCS_PORT} in "
                             f"{self.start_timeout_s:g} s", f"see {self.run_dir / 'px4.log'}")

    stop_timeout_s = 10.0


def heartbeat_systems(data: bytes) -> list[int]:
    """The system ids of the HEARTBEATs in one UDP datagram (pymavlink's parser: MAVLink 1 or 2 framing)."""
    parser = mavlink.MAVLink(None)
    parser.robust_parsing = True
    msgs = parser.parse_buffer(data) or []
    return [m.get_srcSystem() for m in msgs if m.get_type() == "HEARTBEAT"]


def _udp_bound(port: int) -> bool:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        try:
            s.bind(("0.0.0.0", port))
        except OSError:
            return True
    return False

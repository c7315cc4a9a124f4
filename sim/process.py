"""Start the SITL vehicle (``python -m sim vehicle``) as a child process on free ports, and stop it again.

Used by ``companion fly --sitl``, the demo and the tests: each run gets its own MAVLink port, so it never
collides with a simulator or autopilot already using 14540. The child runs in the caller's working directory and
finds ``sim`` where this process found it (a checkout or an installed wheel), never through the checkout's path.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import sysconfig
import time
from pathlib import Path

from companion.errors import CompanionError

# The directory holding the ``sim`` package, so the child's ``python -m sim`` imports this same copy of it.
PACKAGE_PARENT = Path(__file__).resolve().parents[1]


def child_environment() -> dict[str, str]:
    """This process's environment, with ``sim``'s parent directory first on PYTHONPATH when sim runs from a source
    tree (an installed sim is on the child interpreter's own path already, and its site-packages must not move
    ahead of the standard library)."""
    installed = {Path(sysconfig.get_paths()[key]).resolve() for key in ("purelib", "platlib")}
    if PACKAGE_PARENT in installed:
        return dict(os.environ)
    path = os.environ.get("PYTHONPATH", "")
    return dict(os.environ, PYTHONPATH=str(PACKAGE_PARENT) + (os.pathsep + path if path else ""))


def free_port(kind: int = socket.SOCK_DGRAM) -> int:
    """A localhost port free right now for ``kind`` (UDP by default, ``socket.SOCK_STREAM`` for TCP): the one
    helper the simulator, the rig, the benches and the tests take their ports from."""
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def terminate(proc: subprocess.Popen, timeout_s: float) -> None:
    """SIGTERM (a clean shutdown), then SIGKILL if the process has not exited within ``timeout_s``."""
    if proc.poll() is not None:
        return
    proc.send_signal(signal.SIGTERM)
    try:
        proc.wait(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


class LoggedProcess:
    """A firmware SITL process the user built, its output in a log file: started by a subclass's ``start()``
    (``_spawn``), stopped with SIGTERM then SIGKILL; a context manager."""

    stop_timeout_s = 5.0

    def __init__(self) -> None:
        self.process: subprocess.Popen | None = None
        self._log = None

    def _spawn(self, args: list[str], log_path: Path, **popen) -> subprocess.Popen:
        self._log = open(log_path, "w")  # noqa: SIM115 (lives as long as the process)
        self.process = subprocess.Popen(args, stdout=self._log, stderr=subprocess.STDOUT, **popen)
        return self.process

    def start(self):
        raise NotImplementedError

    def stop(self) -> None:
        if self.process is not None:
            terminate(self.process, timeout_s=self.stop_timeout_s)
        if self._log is not None:
            self._log.close()
            self._log = None

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()


def switch_value(value) -> bool | None:
    """True / False for an on-off option's value, None for any other value. ``--sim-arg rangefinder=true`` arrives
    as the text 'true', so the words count as well as Python's booleans."""
    if isinstance(value, bool):
        return value
    if isinstance(value, str) and value.strip().lower() in ("true", "yes", "on"):
        return True
    if isinstance(value, str) and value.strip().lower() in ("false", "no", "off"):
        return False
    return None


def with_mission_wall(options: dict, mission) -> dict:
    """The vehicle options with the mission's wall added for a rangefinder that has none: the vehicle process
    knows no facade otherwise (sim/vehicle/rangefinder.py)."""
    if not switch_value(options.get("rangefinder")) or options.get("rangefinder_wall"):
        return dict(options)
    from sim.vehicle.rangefinder import WallSpec

    return {**options, "rangefinder_wall": WallSpec.of_mission(mission).option()}


class SimulatorProcess:
    """``with SimulatorProcess(speedup=20, packet_loss=20) as sim: fly_mission(plan, sim.url)``.

    Keyword options become ``python -m sim vehicle`` options (``packet_loss=20`` -> ``--packet-loss 20``,
    ``gnss_bias=(1.5, 0, 0)`` -> ``--gnss-bias 1.5,0,0``, ``rangefinder=True`` -> ``--rangefinder``).
    ``pose_port`` defaults to a free port so a test run does not feed a camera simulator listening on 14660.
    """

    def __init__(self, *, speedup: float = 20.0, seed: int = 0, log_path: Path | None = None,
                 mavlink_port: int | None = None, pose_port: int | None = None, **options):
        self.port = mavlink_port or free_port()
        self.pose_port = pose_port if pose_port is not None else free_port()
        self.url = f"udpin://127.0.0.1:{self.port}"
        self.args = [sys.executable, "-m", "sim", "vehicle", "--mavlink-port", str(self.port), "--pose-port",
                     str(self.pose_port), "--speedup", str(speedup), "--seed", str(seed)]
        for key, value in options.items():
            flag = "--" + key.replace("_", "-")
            switch = switch_value(value)
            if switch is True:
                self.args.append(flag)
            elif value is not None and switch is None:
                # a tuple is the option's comma form (gnss_bias=(1.5, 0, 0) -> 1.5,0,0); a value starting with '-'
                # (--gnss-bias=-1.5,0,0) is glued to its flag, or argparse takes it for an option
                text = ",".join(str(v) for v in value) if isinstance(value, (tuple, list)) else str(value)
                self.args += [f"{flag}={text}"] if text.startswith("-") else [flag, text]
        self.log_path = log_path
        self.proc: subprocess.Popen | None = None
        self._log = None

    def start(self) -> SimulatorProcess:
        self._log = open(self.log_path, "w") if self.log_path else subprocess.DEVNULL  # noqa: SIM115
        self.proc = subprocess.Popen(self.args, stdout=self._log, stderr=self._log, env=child_environment())
        time.sleep(0.3)
        if self.proc.poll() is not None:
            raise CompanionError(f"the simulator exited at start (code {self.proc.returncode})",
                                 f"run it by hand to see why: {' '.join(self.args[1:])}")
        return self

    def stop(self) -> int | None:
        if self.proc is None:
            return None
        terminate(self.proc, timeout_s=5.0)
        if self._log not in (None, subprocess.DEVNULL):
            self._log.close()
        return self.proc.returncode

    def __enter__(self) -> SimulatorProcess:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

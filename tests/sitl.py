"""Test helper: start the simulated vehicle as its own process on free ports, and stop it again.

Each vehicle gets its own MAVLink port (connect with ``vehicle.url``) and pose port, so SITL tests can run
side by side without clashing with a simulator someone already runs on 14540.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class SitlVehicle:
    """``with SitlVehicle(speedup=20, packet_loss=20) as v: fly_mission(plan, v.url)``.

    Extra keyword arguments become command-line options (``packet_loss=20`` -> ``--packet-loss 20``).
    """

    def __init__(self, *, speedup: float = 20.0, seed: int = 0, log_path: Path | None = None, **options):
        self.port = free_udp_port()
        self.pose_port = free_udp_port()
        self.url = f"udpin://127.0.0.1:{self.port}"
        self.args = [sys.executable, "-m", "sim", "vehicle", "--mavlink-port", str(self.port), "--pose-port",
                     str(self.pose_port), "--speedup", str(speedup), "--seed", str(seed)]
        for key, value in options.items():
            flag = "--" + key.replace("_", "-")
            if value is True:
                self.args.append(flag)
            elif value is not None and value is not False:
                self.args += [flag, str(value)]
        self.log_path = log_path
        self.proc: subprocess.Popen | None = None
        self._log = None

    def start(self) -> SitlVehicle:
        self._log = open(self.log_path, "w") if self.log_path else subprocess.DEVNULL  # noqa: SIM115
        env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
        self.proc = subprocess.Popen(self.args, cwd=ROOT, stdout=self._log, stderr=self._log, env=env)
        time.sleep(0.3)
        if self.proc.poll() is not None:
            raise RuntimeError(f"simulator exited at start with code {self.proc.returncode}: {self.args}")
        return self

    def stop(self) -> int | None:
        if self.proc is None:
            return None
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        if self._log not in (None, subprocess.DEVNULL):
            self._log.close()
        return self.proc.returncode

    def __enter__(self) -> SitlVehicle:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

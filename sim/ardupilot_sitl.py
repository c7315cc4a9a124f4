"""A real ArduCopter SITL binary, started at a mission's take-off point with the simulator parameters a check asks for.

Why: the project's simulator follows real firmware, but where the two disagree the firmware is right, so the
checks that matter (a GNSS offset flown by the real EKF and position controller, the real GCS failsafe) are run
against ArduPilot's own SITL. This module only *runs* a binary the user built (``build/sitl/bin/arducopter`` of an
ArduPilot tree, configured for the ``sitl`` board); nothing here builds or fetches one.

What it sets, and why each:

* ``--home`` the mission's take-off point facing the wall: the simulated camera renders the wall where the mission
  says it is, from where the SITL's vehicle truly is (``sim/pose_bridge.py`` reads SIM_STATE).
* ``-w`` wiped parameters and ``--defaults`` the tree's ``copter.parm`` plus the check's own: every run starts
  from the same vehicle.
* ``--serial0 tcp:0``: ArduPilot SITL's first port otherwise waits for a client before the vehicle runs
  (``tcp:0:wait``), and the pose bridge on the second port would see no SIM_STATE until the companion connects.
* A GNSS offset as ArduPilot simulates one: ``SIM_GPS1_GLTCH`` is added to the receiver's *latitude and
  longitude in degrees* and its altitude in metres (libraries/SITL/SIM_GPS.cpp), so metres along and out from the
  wall are turned into degrees at the take-off point.
* A rangefinder: ``RNGFND1_TYPE 100`` (SITL) facing forward. ArduPilot's SITL knows no wall: its simulated
  rangefinder measures the distance to the ground along the beam (libraries/SITL/SIM_Aircraft.cpp,
  ``rangefinder_range``), so facing forward in level flight it reports nothing in range. A check with it on shows
  what the companion does with a forward sensor that never sees the facade, not a measured standoff.

ArduPilot SITL serves MAVLink on TCP ``5760 + 10 x instance`` (the companion's), ``+2`` and ``+3`` (one client
each: the pose bridge takes ``+2``, a watcher ``+3``).
"""

from __future__ import annotations

import math
import socket
import time
from dataclasses import dataclass
from pathlib import Path

from companion.errors import CompanionError
from sim.process import LoggedProcess

BINARY_IN_TREE = Path("build/sitl/bin/arducopter")
DEFAULTS_IN_TREE = Path("Tools/autotest/default_params/copter.parm")
M_PER_DEG_LAT = 111_320.0  # at the scale of a GNSS offset (metres), the sphere is exact enough


@dataclass(frozen=True)
class SitlParameters:
    """What a check changes on the SITL vehicle before it boots."""

    gnss_offset_enu_m: tuple[float, float, float] = (0.0, 0.0, 0.0)  # the receiver's error, east / north / up
    forward_rangefinder: bool = False
    extra: tuple[tuple[str, float], ...] = ()

    def lines(self, lat_deg: float) -> list[str]:
        """The parameter-file lines (``NAME VALUE``) at latitude ``lat_deg``."""
        east, north, up = self.gnss_offset_enu_m
        out = []
        if any(self.gnss_offset_enu_m):
            out += [f"SIM_GPS1_GLTCH_X {north / M_PER_DEG_LAT:.10f}",
                    f"SIM_GPS1_GLTCH_Y {east / (M_PER_DEG_LAT * math.cos(math.radians(lat_deg))):.10f}",
                    f"SIM_GPS1_GLTCH_Z {up:.3f}"]
        if self.forward_rangefinder:
            out += ["RNGFND1_TYPE 100", "RNGFND1_ORIENT 0", "RNGFND1_MIN 0.2", "RNGFND1_MAX 20"]
        out += [f"{name} {value:g}" for name, value in self.extra]
        return out


def find_binary(ardupilot: Path) -> tuple[Path, Path]:
    """The ``arducopter`` binary and ``copter.parm`` of an ArduPilot tree built for SITL, or a clear error."""
    ardupilot = Path(ardupilot).expanduser().resolve()
    binary, defaults = ardupilot / BINARY_IN_TREE, ardupilot / DEFAULTS_IN_TREE
    if not binary.is_file():
        raise CompanionError(f"no ArduCopter SITL binary at {binary}",
                             "give --ardupilot the top of an ArduPilot source tree built for its sitl board "
                             "(ArduPilot's own build documentation says how)")
    if not defaults.is_file():
        raise CompanionError(f"no {DEFAULTS_IN_TREE} in {ardupilot}", "give the ArduPilot tree the binary was built in")
    return binary, defaults


class ArduCopterSitl(LoggedProcess):
    """``with ArduCopterSitl(tree, home=(lat, lon, alt, heading), run_dir=...) as sitl:`` ``sitl.companion_url``,
    ``sitl.bridge_url``, ``sitl.watch_url``; the process is stopped on exit."""

    def __init__(self, ardupilot: Path, *, home: tuple[float, float, float, float], run_dir: Path,
                 parameters: SitlParameters = SitlParameters(), instance: int = 0, speedup: float = 1.0,
                 start_timeout_s: float = 30.0):
        self.binary, self.defaults = find_binary(ardupilot)
        self.home, self.run_dir, self.parameters = home, Path(run_dir), parameters
        self.instance, self.speedup, self.start_timeout_s = instance, speedup, start_timeout_s
        self.base_port = 5760 + 10 * instance
        super().__init__()

    @property
    def companion_url(self) -> str:
        return f"tcpout://127.0.0.1:{self.base_port}"

    @property
    def bridge_url(self) -> str:
        return f"tcp:127.0.0.1:{self.base_port + 2}"

    @property
    def watch_url(self) -> str:
        return f"tcp:127.0.0.1:{self.base_port + 3}"

    def start(self) -> ArduCopterSitl:
        self.run_dir.mkdir(parents=True, exist_ok=True)
        for port in (self.base_port, self.base_port + 2, self.base_port + 3):
            if _listening(port):
                raise CompanionError(f"TCP port {port} is already in use (another SITL?)",
                                     "stop it, or give another instance")
        check = self.run_dir / "check.parm"
        check.write_text("".join(line + "\n" for line in self.parameters.lines(self.home[0])))
        lat, lon, alt, heading = self.home
        args = [str(self.binary), "--model", "+", "--speedup", f"{self.speedup:g}", "-I", str(self.instance),
                "--home", f"{lat:.8f},{lon:.8f},{alt:.2f},{heading:.1f}", "-w",
                "--defaults", f"{self.defaults},{check}", "--serial0", "tcp:0"]
        # the SITL writes eeprom.bin, logs/ and terrain/ into its working directory: the run's own
        self._spawn(args, self.run_dir / "arducopter.log", cwd=self.run_dir)
        deadline = time.monotonic() + self.start_timeout_s
        while time.monotonic() < deadline:
            if self.process.poll() is not None:
                self.stop()
                raise CompanionError(f"ArduCopter SITL exited at start (code {self.process.returncode})",
                                     f"see {self.run_dir / 'arducopter.log'}")
            if _listening(self.base_port) and _listening(self.base_port + 3):
                return self
            time.sleep(0.2)
        self.stop()
        raise CompanionError(f"ArduCopter SITL did not open TCP {self.base_port} in {self.start_timeout_s:g} s",
                             f"see {self.run_dir / 'arducopter.log'}")


def _listening(port: int) -> bool:
    """Whether a TCP socket listens on ``port``, read from /proc/net/tcp: connecting to find out would take the
    SITL port's one client slot."""
    try:
        rows = Path("/proc/net/tcp").read_text().splitlines()[1:]
    except OSError:
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:  # no procfs: a connection says it listens
            return s.connect_ex(("127.0.0.1", port)) == 0
    for row in rows:
        fields = row.split()
        if len(fields) > 3 and fields[3] == "0A" and int(fields[1].rsplit(":", 1)[1], 16) == port:
            return True
    return False

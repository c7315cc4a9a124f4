"""``python -m sim posebridge``: feeds the simulated camera's pose channel from a SITL autopilot's own truth.

Why: the camera (sim/camera/live.py) renders from the vehicle's TRUE pose. Our simulated vehicle publishes it
itself; a real firmware's SITL (ArduPilot) does not, but reports it over MAVLink in SIM_STATE. The bridge connects
to the autopilot (ArduPilot SITL: ``tcp:127.0.0.1:5762``, a port the companion does not use), asks for SIM_STATE
and for ATTITUDE (its ``time_boot_ms`` is the clock: SIM_STATE carries none), HOME_POSITION and the gimbal's
report with SET_MESSAGE_INTERVAL, and sends each SIM_STATE to the pose channel as the JSON line the camera reads
(sim/sim_state.py converts). So the images follow where the SITL's vehicle really is, whatever its GPS says.

The bridge sends no HEARTBEAT: it is not a ground station, and must not keep the autopilot's lost-link failsafe
from firing when the companion goes quiet.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import signal
import socket
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mavlink  # common + ArduPilot messages, MAVLink 2

from companion.errors import CompanionError
from sim.sim_state import (
    Gimbal,
    Home,
    gimbal_from_device_status,
    gimbal_from_mount_status,
    home_from_position,
    pose_from_sim_state,
)

log = logging.getLogger(__name__)

# messages whose time_boot_ms is the clock SIM_STATE lacks
CLOCK_MESSAGES = ("ATTITUDE", "SYSTEM_TIME")
REQUEST_AGAIN_S = 1.0  # until SIM_STATE flows (an ArduPilot starting up answers nothing but HEARTBEAT)
NOT_AUTOPILOTS = (mavlink.MAV_TYPE_GCS, mavlink.MAV_TYPE_GIMBAL, mavlink.MAV_TYPE_CAMERA,
                  mavlink.MAV_TYPE_ONBOARD_CONTROLLER, mavlink.MAV_TYPE_ADSB)
NO_SIM_STATE_FIX = ("connect the bridge to a SITL's MAVLink port: ArduPilot SITL (tcp:127.0.0.1:5762 or :5763 "
                    "while the companion uses 5760; its SIM_STATE stops only with a simulated ELRS receiver "
                    "attached), or our simulator with --autopilot ardupilot. A real vehicle or PX4 SIH sends no "
                    "SIM_STATE: fly them with the simulator's own pose channel (sim/rig.py) instead")


@dataclass(frozen=True)
class BridgeConfig:
    connect: str  # pymavlink URL of the autopilot: tcp:HOST:PORT, udpin:HOST:PORT, ...
    pose_port: int = 14660
    pose_host: str = "127.0.0.1"
    rate_hz: float = 50.0
    gimbal: Gimbal = field(default_factory=Gimbal)  # until the vehicle reports its gimbal
    timeout_s: float = 20.0  # for the first HEARTBEAT, then again for the first SIM_STATE
    duration_s: float | None = None  # wall seconds, for tests and scripted runs
    truth_log: Path | None = None  # also append every published pose here (JSON lines): the flight's truth
    source_system: int = 253
    source_component: int = mavlink.MAV_COMP_ID_ONBOARD_COMPUTER


def requested_intervals_us(rate_hz: float) -> dict[int, float]:
    """The messages the bridge asks for and their intervals (µs): the clock and SIM_STATE at the pose rate, home
    and the gimbal slower. ATTITUDE is asked before SIM_STATE: a vehicle that sends both on one tick in the order
    they were asked for (ours does) then stamps each SIM_STATE with that tick's clock."""
    pose_us = 1e6 / rate_hz
    return {
        mavlink.MAVLINK_MSG_ID_ATTITUDE: pose_us,
        mavlink.MAVLINK_MSG_ID_SYSTEM_TIME: 1e6,
        mavlink.MAVLINK_MSG_ID_SIM_STATE: pose_us,
        mavlink.MAVLINK_MSG_ID_HOME_POSITION: 1e6,
        mavlink.MAVLINK_MSG_ID_GIMBAL_DEVICE_ATTITUDE_STATUS: 1e5,
    }


class PoseBridge:
    """One autopilot connection -> one pose channel. ``run()`` blocks until ``stop()`` or ``duration_s``."""

    def __init__(self, cfg: BridgeConfig):
        if cfg.rate_hz <= 0:
            raise CompanionError(f"--rate {cfg.rate_hz:g} Hz is not a rate", "give a positive rate, e.g. 50")
        self.cfg = cfg
        self.conn = None
        self.target: tuple[int, int] | None = None
        self.t_s: float | None = None  # the autopilot clock: latest time_boot_ms / 1000 seen
        self.gimbal = cfg.gimbal
        self.home: Home | None = None
        self.yaw_deg: float | None = None
        self.published = 0
        self.same_clock = 0  # SIM_STATEs left out: the clock had not moved since the last pose
        self._stamped: float | None = None  # the time of the last pose made
        self.unstamped = 0  # SIM_STATEs dropped: no clock message seen yet
        self._stop = False
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._truth = None  # the truth log's file, opened by run()

    def stop(self) -> None:
        self._stop = True

    def open(self) -> None:
        url = self.cfg.connect
        try:
            conn = mavutil.mavlink_connection(url, source_system=self.cfg.source_system,
                                              source_component=self.cfg.source_component, retries=2)
        except (OSError, ValueError) as exc:
            raise CompanionError(f"cannot connect to the autopilot at {url} ({exc})",
                                 "start the SITL first and give its MAVLink URL, e.g. --connect tcp:127.0.0.1:5762 "
                                 "(ArduPilot SITL serves one client per TCP port: 5760, 5762, 5763)") from exc
        # the ArduPilot dialect in MAVLink 2 for this link alone (SIM_STATE's lat_int/lon_int are extensions), not
        # through mavutil's process-wide dialect, which other modules set
        conn.mav = mavlink.MAVLink(conn, srcSystem=self.cfg.source_system, srcComponent=self.cfg.source_component)
        conn.mav.robust_parsing = True
        self.conn = conn

    def _wait_heartbeat(self) -> None:
        deadline = time.monotonic() + self.cfg.timeout_s
        while not self._stop and time.monotonic() < deadline:
            msg = self.conn.recv_match(type="HEARTBEAT", blocking=True, timeout=0.2)
            if msg is not None and msg.type not in NOT_AUTOPILOTS:
                self.target = (msg.get_srcSystem(), msg.get_srcComponent())
                log.info("autopilot: system %d component %d", *self.target)
                return
        if not self._stop:
            raise CompanionError(f"no autopilot HEARTBEAT from {self.cfg.connect} in {self.cfg.timeout_s:g} s",
                                 "is the SITL running, and is this its MAVLink port? (ArduPilot SITL: "
                                 "tcp:127.0.0.1:5762; our simulator: udpin:127.0.0.1:<its --mavlink-port>)")

    def _request(self) -> None:
        system, component = self.target
        for msg_id, interval_us in requested_intervals_us(self.cfg.rate_hz).items():
            self.conn.mav.command_long_send(system, component, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 0,
                                            msg_id, interval_us, 0, 0, 0, 0, 0)

    def handle(self, msg) -> dict | None:
        """Take one message from the autopilot; the pose line to publish, if it was a SIM_STATE."""
        kind = msg.get_type()
        if self.target is not None and msg.get_srcSystem() != self.target[0]:
            return None
        boot_ms = getattr(msg, "time_boot_ms", None)
        if kind in CLOCK_MESSAGES and boot_ms is not None:
            self.t_s = boot_ms / 1000.0
        if kind == "SIM_STATE":
            if self.t_s is None:
                self.unstamped += 1
                return None
            if self.t_s == self._stamped:
                # no clock message since the last pose (a loaded autopilot sent two SIM_STATEs in a row): a second
                # pose at the same time would give the camera's interpolation a zero interval
                self.same_clock += 1
                return None
            pose = pose_from_sim_state(msg.to_dict(), t_s=self.t_s, gimbal=self.gimbal, home=self.home)
            if pose is not None:
                self.yaw_deg = pose["yaw_deg"]
                self._stamped = self.t_s
            return pose
        if kind == "GIMBAL_DEVICE_ATTITUDE_STATUS":
            self.gimbal = gimbal_from_device_status(msg.to_dict(), self.yaw_deg) or self.gimbal
        elif kind == "MOUNT_STATUS":
            self.gimbal = gimbal_from_mount_status(msg.to_dict())
        elif kind == "HOME_POSITION":
            self.home = home_from_position(msg.to_dict())
        return None

    def publish(self, pose: dict) -> None:
        line = json.dumps(pose)
        with contextlib.suppress(OSError):  # no camera listening yet: the pose is lost, as the vehicle's would be
            self.sock.sendto(line.encode(), (self.cfg.pose_host, self.cfg.pose_port))
        if self._truth is not None:
            self._truth.write(line + "\n")
            self._truth.flush()  # a killed bridge keeps what it saw
        self.published += 1

    def run(self) -> int:
        """Bridge until stopped; the number of poses published."""
        if self.conn is None:
            self.open()
        if self.cfg.truth_log is not None and self._truth is None:
            self.cfg.truth_log.parent.mkdir(parents=True, exist_ok=True)
            self._truth = open(self.cfg.truth_log, "a")  # noqa: SIM115 (closed by close())
        start = time.monotonic()
        self._wait_heartbeat()
        asked = first_ask = time.monotonic()
        self._request()
        while not self._stop:
            now = time.monotonic()
            if self.cfg.duration_s is not None and now - start >= self.cfg.duration_s:
                break
            if self.published == 0:
                if now - first_ask > self.cfg.timeout_s and self.unstamped:
                    raise CompanionError(
                        f"{self.cfg.connect} sent {self.unstamped} SIM_STATE but no ATTITUDE or SYSTEM_TIME in "
                        f"{self.cfg.timeout_s:g} s: no autopilot clock to time the poses by",
                        "let the bridge's SET_MESSAGE_INTERVAL for ATTITUDE through (or stream ATTITUDE on this "
                        "port, ArduPilot: SRn_EXTRA1)")
                if now - first_ask > self.cfg.timeout_s:
                    raise CompanionError(
                        f"{self.cfg.connect} sent no SIM_STATE in {self.cfg.timeout_s:g} s: not a SITL, or its "
                        "sim-state messages are off", NO_SIM_STATE_FIX)
                if now - asked > REQUEST_AGAIN_S:
                    self._request()
                    asked = now
            msg = self.conn.recv_match(blocking=True, timeout=0.2)
            if msg is None:
                continue
            pose = self.handle(msg)
            if pose is not None:
                if self.published == 0:
                    log.info("SIM_STATE flowing: poses to udp://%s:%d", self.cfg.pose_host, self.cfg.pose_port)
                self.publish(pose)
        return self.published

    def close(self) -> None:
        if self.conn is not None:
            with contextlib.suppress(OSError):
                self.conn.close()
            self.conn = None
        if self._truth is not None:
            self._truth.close()
            self._truth = None
        self.sock.close()


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m sim posebridge", description=__doc__.split("\n\n")[0])
    p.add_argument("--connect", required=True,
                   help="the autopilot's MAVLink URL (ArduPilot SITL: tcp:127.0.0.1:5762; our simulator: "
                        "udpin:127.0.0.1:PORT)")
    p.add_argument("--pose-port", type=int, default=14660, help="UDP port of the camera's pose channel")
    p.add_argument("--pose-host", default="127.0.0.1")
    p.add_argument("--rate", type=float, default=50.0, help="SIM_STATE rate asked for, Hz (autopilot clock)")
    p.add_argument("--gimbal-pitch", type=float, default=0.0, metavar="DEG",
                   help="gimbal pitch (down negative) until the vehicle reports its gimbal (default level)")
    p.add_argument("--gimbal-yaw", type=float, default=0.0, metavar="DEG",
                   help="gimbal yaw from the vehicle's heading until the vehicle reports its gimbal")
    p.add_argument("--timeout", type=float, default=20.0,
                   help="seconds to wait for the first HEARTBEAT, then for the first SIM_STATE")
    p.add_argument("--duration", type=float, help="stop after this many wall seconds")
    p.add_argument("--truth-log", type=Path,
                   help="also append every pose published to this file (JSON lines): where the SITL's vehicle "
                        "truly was, for judging a flight against the wall")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    cfg = BridgeConfig(connect=args.connect, pose_port=args.pose_port, pose_host=args.pose_host, rate_hz=args.rate,
                       gimbal=Gimbal(args.gimbal_pitch, args.gimbal_yaw), timeout_s=args.timeout,
                       duration_s=args.duration, truth_log=args.truth_log)
    bridge = None
    try:
        bridge = PoseBridge(cfg)
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, lambda *_: bridge.stop())
        print(f"posebridge: SIM_STATE from {cfg.connect} -> poses on udp://{cfg.pose_host}:{cfg.pose_port}",
              flush=True)
        published = bridge.run()
    except CompanionError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    finally:
        if bridge is not None:
            bridge.close()
    print(f"posebridge: {published} poses published", flush=True)
    return 0

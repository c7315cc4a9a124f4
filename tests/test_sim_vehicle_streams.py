"""The simulator's telemetry time stamps disagree between streams as real SITL's did at speed-up (``--stream-stall``).

Real PX4 SIH at speed-up 4 (a pymavlink listener on the link, paper-edge mission, 250 s): 509 of 59473 ATTITUDE /
GLOBAL_POSITION_INT messages came more than 0.3 s of autopilot time behind the other stream's latest, 17 more than
1 s, 5 more than 2 s, in both directions; each stream stayed in order within itself. Real ArduCopter at speed-up 5
handed the companion an ATTITUDE 1.2 s older than a GLOBAL_POSITION_INT it had already handled. A restart check that
compared the streams with each other ended good flights as "restarted"; the simulator must produce such skews so the
per-stream check is what its flights exercise."""

from __future__ import annotations

import socket
import time

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from tests.sitl import SitlVehicle

pytestmark = pytest.mark.sitl


def _skews(sim_s: float, **options) -> tuple[float, float]:
    """Listen to a PX4-flavoured simulator until its clock passed ``sim_s``; returns (the most one stream's message
    was behind the other stream's latest stamp, the most a stream's own stamp went back), both in seconds."""
    latest: dict[str, float] = {}
    behind = back = 0.0
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        sock.settimeout(0.2)
        with SitlVehicle(speedup=20, mavlink_port=sock.getsockname()[1], **options):
            parser = mavlink.MAVLink(None)
            deadline = time.monotonic() + 120.0  # wall: a loaded machine slows the simulator down
            while time.monotonic() < deadline and max(latest.values(), default=0.0) < sim_s:
                try:
                    data = sock.recv(65535)
                except TimeoutError:
                    continue
                for m in parser.parse_buffer(data) or []:
                    name = m.get_type()
                    if name not in ("ATTITUDE", "GLOBAL_POSITION_INT"):
                        continue
                    t = m.time_boot_ms / 1000.0
                    back = max(back, latest.get(name, t) - t)
                    latest[name] = max(latest.get(name, t), t)
                    other = latest.get("ATTITUDE" if name == "GLOBAL_POSITION_INT" else "GLOBAL_POSITION_INT")
                    if other is not None:
                        behind = max(behind, other - t)
    assert max(latest.values(), default=0.0) >= sim_s, "the simulator did not get that far"
    return behind, back


def test_streams_stall_behind_each_other_but_stay_in_order():
    behind, back = _skews(80.0, stream_stall=2.5, stream_stall_every=5)
    assert 1.0 < behind < 2.5 + 2.0  # more than the 1 s a cross-stream restart check allows, bounded by the stall
    assert back == 0.0  # within a stream, never backwards: that stays the sign of a restart
    calm, calm_back = _skews(30.0)
    assert calm < 1.0 and calm_back == 0.0  # without the option the streams agree (the old simulator, always)

"""What a pilot reads in the log (issue 31 item 5): mavsdk's own lines as whole records of ours (they came spliced
into our lines, a stray "390)"), and a stop request that names its signal (it read "signal 1", like SIGHUP, when it
was the first SIGINT). The waypoint progress line per change is in tests/test_flight_parameters.py."""

from __future__ import annotations

import logging
import os
import re
import signal
import subprocess
import sys

import mavsdk

from companion.flight.fly import stop_request_text
from companion.flight.mavsdk_log import mavsdk_line
from sim.process import free_port
from tests.sitl import ROOT


def test_stop_requests_name_their_signal_and_what_follows():
    first = stop_request_text(signal.SIGINT, 1)
    assert first == "stop requested by SIGINT (Ctrl-C): pausing, then returning to launch"
    again = stop_request_text(signal.SIGTERM, 2)
    assert "SIGTERM" in again and "no longer waiting for the landing" in again
    assert "signal 1" not in first + again
    assert "SIGHUP" in stop_request_text(1, 1)  # a real signal 1 is called by its name too


def test_a_mavsdk_line_is_one_record_of_the_mavsdk_logger(caplog):
    caplog.set_level(logging.DEBUG, logger="mavsdk")
    assert mavsdk_line(mavsdk.LogLevel.WARN, "Lost heartbeat\n", "/src/core/mavsdk_impl.cpp", 390) is True
    (record,) = caplog.records
    assert record.name == "mavsdk" and record.levelno == logging.WARNING
    assert record.getMessage() == "Lost heartbeat (mavsdk_impl.cpp:390)"


def test_mavsdk_lines_reach_the_log_as_whole_lines_without_colour_escapes():
    """A command that starts mavsdk and finds no vehicle: every line on stderr is one of ours."""
    port = free_port()
    proc = subprocess.run([sys.executable, "-m", "companion.cli", "restore", "--connect", f"udpin://127.0.0.1:{port}",
                           "--connect-timeout", "1"], cwd=ROOT, capture_output=True, text=True, timeout=60,
                          env=dict(os.environ, PYTHONPATH=str(ROOT)))
    assert proc.returncode == 2, proc.stderr
    assert "\x1b[" not in proc.stderr
    assert "INFO mavsdk: MAVSDK version" in proc.stderr
    ours = re.compile(r"^(DEBUG|INFO|WARNING|ERROR|CRITICAL) [\w.]+: |^error: |^  fix: ")
    assert all(ours.match(line) for line in proc.stderr.splitlines()), proc.stderr

"""Crash test: kill -9 the companion mid-flight, restart it on the same spool, finish the mission.

The simulated vehicle and camera keep running (as a real autopilot and camera would); only the companion dies.
Afterwards the spool is consistent and every keyframe the first run had reported is still there.

Kept short for the suite's time: tests/data/small-wall.yaml without PX4's 121 s home-settle hold, on a simulated
vehicle told to keep home still (tests/small_wall.py), a 320 px camera at 3 fps and a speed-up of 2 (what is checked
is the spool across a kill, not the gate's accuracy: tests/test_onboard_sitl.py judges that at 640 px).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from companion.spool.layout import MANIFEST
from sim.rig import SitlRig
from tests.small_wall import small_wall_scan_at_once

pytestmark = pytest.mark.sitl
ROOT = Path(__file__).resolve().parents[1]


def _companion(mission, rig, out, telemetry, log):
    cmd = [sys.executable, "-m", "companion.cli", "-v", "fly", str(mission), "--connect", rig.url, "--capture",
           rig.capture, "--out", str(out), "--telemetry-log", str(telemetry), "--no-mask", "--no-progress",
           "--end-action", "rtl"]  # fmt: skip
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    return subprocess.Popen(cmd, cwd=ROOT, stdout=log, stderr=subprocess.STDOUT, env=env)


def test_kill_9_mid_flight_then_restart_loses_nothing(tmp_path):
    mission, still_home = small_wall_scan_at_once(tmp_path)
    out, telemetry = tmp_path / "spool", tmp_path / "telemetry.jsonl"
    with SitlRig(mission, log_dir=tmp_path / "logs", speedup=2, fps=3, width_px=320,
                 sim_options=still_home) as rig:
        with open(tmp_path / "run1.log", "w") as log:
            first = _companion(mission, rig, out, telemetry, log)
            deadline = time.monotonic() + 120
            manifest = out / MANIFEST
            while time.monotonic() < deadline:  # kill once a few keyframes are reported
                if manifest.exists() and len(manifest.read_text().splitlines()) >= 4:
                    break
                assert first.poll() is None, (tmp_path / "run1.log").read_text()[-3000:]
                time.sleep(0.1)
            os.kill(first.pid, signal.SIGKILL)
            first.wait()
        last_seen = json.loads([x for x in telemetry.read_text().splitlines() if x.endswith("}")][-1])
        assert last_seen["in_air"] and last_seen["armed"], f"killed after the flight, not during it: {last_seen}"
        reported = [json.loads(x)["index"] for x in manifest.read_text().splitlines() if x.endswith("}")]
        assert len(reported) >= 4
        with open(tmp_path / "run2.log", "w") as log:
            second = _companion(mission, rig, out, telemetry, log)
            assert second.wait(timeout=300) == 0, (tmp_path / "run2.log").read_text()[-3000:]
    lines = [json.loads(x) for x in manifest.read_text().splitlines()]
    indices = [x["index"] for x in lines]
    assert indices == sorted(set(indices)), "duplicates or out-of-order entries after the restart"
    assert set(reported) <= set(indices), "a keyframe reported before the crash is gone"
    assert len(indices) > len(reported), "the restarted companion added nothing"
    for x in lines:
        assert (out / x["image"]).stat().st_size > 0 and (out / x["mask"]).exists() and (out / x["sidecar"]).exists()
    assert not list(out.glob(".*.tmp"))

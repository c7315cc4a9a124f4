"""Crash test: kill -9 the companion mid-flight, restart it on the same spool, finish the mission.

The simulated vehicle and camera keep running (as a real autopilot and camera would); only the companion dies.
Afterwards the spool is consistent and every keyframe the first run had reported is still there.
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

from sim.rig import SitlRig

pytestmark = pytest.mark.sitl
ROOT = Path(__file__).resolve().parents[1]
SMALL_WALL = Path(__file__).parent / "data" / "small-wall.yaml"


def _companion(mission, rig, out, log):
    cmd = [sys.executable, "-m", "companion.cli", "-v", "fly", str(mission), "--connect", rig.url, "--capture",
           rig.capture, "--out", str(out), "--no-mask", "--no-progress", "--end-action", "rtl"]  # fmt: skip
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    return subprocess.Popen(cmd, cwd=ROOT, stdout=log, stderr=subprocess.STDOUT, env=env)


def test_kill_9_mid_flight_then_restart_loses_nothing(tmp_path):
    mission = SMALL_WALL
    out = tmp_path / "spool"
    with SitlRig(mission, log_dir=tmp_path / "logs", speedup=1.5, fps=3) as rig:
        with open(tmp_path / "run1.log", "w") as log:
            first = _companion(mission, rig, out, log)
            deadline = time.monotonic() + 120
            manifest = out / "manifest.jsonl"
            while time.monotonic() < deadline:  # kill once a few keyframes are reported
                if manifest.exists() and len(manifest.read_text().splitlines()) >= 4:
                    break
                assert first.poll() is None, (tmp_path / "run1.log").read_text()[-3000:]
                time.sleep(0.1)
            os.kill(first.pid, signal.SIGKILL)
            first.wait()
        reported = [json.loads(x)["index"] for x in manifest.read_text().splitlines() if x.endswith("}")]
        assert len(reported) >= 4
        with open(tmp_path / "run2.log", "w") as log:
            second = _companion(mission, rig, out, log)
            assert second.wait(timeout=300) == 0, (tmp_path / "run2.log").read_text()[-3000:]
    lines = [json.loads(x) for x in manifest.read_text().splitlines()]
    indices = [x["index"] for x in lines]
    assert indices == sorted(set(indices)), "duplicates or out-of-order entries after the restart"
    assert set(reported) <= set(indices), "a keyframe reported before the crash is gone"
    assert len(indices) > len(reported), "the restarted companion added nothing"
    for x in lines:
        assert (out / x["image"]).stat().st_size > 0 and (out / x["mask"]).exists() and (out / x["sidecar"]).exists()
    assert not list(out.glob(".*.tmp"))

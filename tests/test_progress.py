"""Progress output a companion computer can keep: redraws on a terminal, a line every few seconds in a log."""

from __future__ import annotations

import io
import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import cv2

from companion.progress import progress_bar
from evaluation.keyframes.synthetic import render, sweep, textured_wall

ROOT = Path(__file__).resolve().parents[1]


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_log_output_has_no_redraws_and_few_lines():
    out = io.StringIO()
    with progress_bar(total=5000, desc="culling", unit="frame", file=out) as bar:
        for _ in range(5000):
            bar.update(1)
    text = out.getvalue()
    assert "\r" not in text and "\x1b" not in text
    lines = text.splitlines()
    assert 1 <= len(lines) <= 3, lines  # the first count and the final one: under a second, no line in between
    assert lines[-1].startswith("culling: 100%") and "5000/5000" in lines[-1]


def test_log_output_prints_a_line_every_interval():
    out = io.StringIO()
    interval = 0.1
    t0 = time.monotonic()
    with progress_bar(total=60, desc="matching", file=out, log_interval_s=interval, leave=False) as bar:
        for _ in range(60):
            time.sleep(0.01)
            bar.update(1)
    elapsed = time.monotonic() - t0
    lines = out.getvalue().splitlines()
    assert "\r" not in out.getvalue()
    assert 3 <= len(lines) <= elapsed / interval + 3, (len(lines), elapsed)
    assert "60/60" in lines[-1]  # leave=False is for terminals: a log keeps the final count


def test_terminal_output_still_redraws_in_place():
    out = _Terminal()
    with progress_bar(total=50, desc="render", file=out, mininterval=0) as bar:
        for _ in range(50):
            bar.update(1)
    assert out.getvalue().count("\r") >= 10


def test_no_module_makes_its_own_tqdm():
    """Every progress bar goes through companion.progress (the flight's waypoint bar on a terminal too)."""
    offenders = []
    for path in [*ROOT.glob("companion/**/*.py"), *ROOT.glob("sim/**/*.py"), *ROOT.glob("bench/*.py")]:
        rel = path.relative_to(ROOT).as_posix()
        if rel == "companion/progress.py":
            continue
        if re.search(r"^\s*(from tqdm|import tqdm)", path.read_text(), re.M):
            offenders.append(rel)
    assert offenders == []


def test_cull_log_to_a_file_has_no_carriage_returns(tmp_path):
    tex = textured_wall(1400, 400, seed=3)
    frames = tmp_path / "frames"
    frames.mkdir()
    for i, view in enumerate(sweep(tex, 30, 14, 240, 180, y=200)):
        cv2.imwrite(str(frames / f"{i:04d}.jpg"), render(tex, view))
    log = tmp_path / "telemetry.jsonl"
    log.write_text("".join(json.dumps({"t_boot_s": i / 10.0, "lat": 37.0, "lon": 127.0 + i * 1e-6, "alt_amsl_m": 40.0,
                                       "roll_deg": 0.0, "pitch_deg": 0.0, "yaw_deg": 0.0}) + "\n" for i in range(40)))
    cmd = [sys.executable, "-m", "companion.cli", "cull", str(frames), "--telemetry", str(log),
           "--out", str(tmp_path / "spool"), "--no-mask", "--no-mission", "--fps", "10"]
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    t0 = time.monotonic()
    with open(tmp_path / "cull.log", "w") as fh:
        rc = subprocess.run(cmd, stdout=fh, stderr=subprocess.STDOUT, env=env, cwd=ROOT, timeout=300).returncode
    elapsed = time.monotonic() - t0
    text = (tmp_path / "cull.log").read_text()
    assert rc == 0, text
    assert "\r" not in text
    bar_lines = [x for x in text.splitlines() if x.startswith("culling:")]
    assert 1 <= len(bar_lines) <= elapsed / 5.0 + 2, text
    assert "30/30" in bar_lines[-1] and "30 frames ->" in text

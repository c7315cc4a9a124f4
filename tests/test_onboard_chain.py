"""The onboard chain on a synthetic scan: keyframes meet the overlap target, backlog skipping, offline cull CLI."""

from __future__ import annotations

import json
import time

import cv2
import numpy as np

from companion.capture.sources import FrameSource
from companion.capture.tagging import FrameTagger
from companion.capture.telemetry import ClockMap, TelemetryBuffer
from companion.cli import main
from companion.keyframes.synthetic import render, sweep, textured_wall, true_overlap
from companion.onboard.runner import LiveRunner
from companion.onboard.setup import build_chain
from companion.records import Frame, Pose


def _scan(n=40, step=14):
    tex = textured_wall(1400, 400, seed=3)
    views = sweep(tex, n, step, 240, 180, y=200)
    return views, [render(tex, v) for v in views]


def _buffer(n, fps=10.0):
    buf = TelemetryBuffer()
    for i in range(n + 2):
        buf.add(Pose(i / fps, 37.0 + i * 1e-6, 127.0, 40.0, 10.0, 0.0, 0.0, 0.0))
    return buf


class ListSource(FrameSource):
    def __init__(self, images, fps=10.0, delay_s=0.0):
        super().__init__()
        self.images, self.fps, self.delay_s = images, fps, delay_s

    def __iter__(self):
        for i, img in enumerate(self.images):
            time.sleep(self.delay_s)
            self.stats.delivered += 1
            yield Frame(i, i / self.fps, img)


def test_chain_keyframes_meet_overlap_target(tmp_path):
    views, images = _scan()
    chain = build_chain(tmp_path, FrameTagger(_buffer(len(images)), ClockMap(0.0)), mask=False)
    for i, img in enumerate(images):
        chain.process(Frame(i, i / 10.0, img))
    chain.finish()
    lines = [json.loads(x) for x in (tmp_path / "manifest.jsonl").read_text().splitlines()]
    idx = [x["index"] for x in lines]
    assert idx[0] == 0 and idx[-1] == len(images) - 1 and len(idx) >= 4
    for a, b in zip(idx, idx[1:], strict=False):
        assert true_overlap(views[a], views[b]) >= 0.80 - 0.03
        if b + 1 < len(views):  # the next frame would have been below the target: the gate kept the last one above
            assert true_overlap(views[a], views[b + 1]) < 0.80 + 0.03
    assert all(x["pose"] is not None for x in lines)
    assert chain.stats.keyframes == len(idx) and chain.stats.stale_pose == 0
    assert (tmp_path / "CLOSED").exists()  # a following stitcher makes its final map


def test_live_runner_skips_backlog_but_never_a_keyframe(tmp_path):
    views, images = _scan(n=30, step=6)
    chain = build_chain(tmp_path, FrameTagger(_buffer(len(images)), ClockMap(0.0)), mask=False)
    slow = chain.process

    def slow_process(frame):  # a CPU that cannot keep up with the camera
        time.sleep(0.05)
        return slow(frame)

    chain.process = slow_process
    runner = LiveRunner(ListSource(images, delay_s=0.005), chain, queue_size=2)
    runner.run_until_done()
    assert runner.error is None
    st = chain.stats
    assert st.skipped_backlog > 0 and st.frames_in == len(images)
    idx = [json.loads(x)["index"] for x in (tmp_path / "manifest.jsonl").read_text().splitlines()]
    assert idx == sorted(set(idx)) and idx[-1] <= len(images) - 1 and len(idx) == st.keyframes


def test_cull_cli_on_image_folder(tmp_path):
    views, images = _scan(n=25)
    frames = tmp_path / "frames"
    frames.mkdir()
    for i, img in enumerate(images):
        cv2.imwrite(str(frames / f"{i:04d}.jpg"), img)
    (frames / "0007.jpg").write_bytes(b"corrupt")
    log = tmp_path / "telemetry.jsonl"
    with open(log, "w") as fh:
        for i in range(30):
            row = {
                "t_boot_s": 50.0 + i / 10.0,
                "lat": 37.0,
                "lon": 127.0 + i * 1e-6,
                "alt_amsl_m": 40.0,
                "rel_alt_m": 10.0,
                "roll_deg": 0.0,
                "pitch_deg": 0.0,
                "yaw_deg": 0.0,
                "mission_item": 3,
            }
            fh.write(json.dumps(row) + "\n")
    out = tmp_path / "spool"
    args = [
        "cull",
        str(frames),
        "--telemetry",
        str(log),
        "--out",
        str(out),
        "--no-mask",
        "--fps",
        "10",
        "--time-offset",
        "50",
    ]
    assert main(args) == 0
    report = json.loads((out / "cull_report.json").read_text())
    assert report["corrupt"] == 1 and report["keyframes"] >= 3 and report["stale_pose"] == 0
    side = json.loads(next(out.glob("kf_*.json")).read_text())
    assert side["pose"]["mission_item"] == 3 and side["settings"]["rth"] == 0.8
    # Resuming on the same directory adds no duplicates.
    assert main(args) == 0
    idx = [json.loads(x)["index"] for x in (out / "manifest.jsonl").read_text().splitlines()]
    assert len(idx) == len(set(idx)) == report["keyframes"]
    assert np.all(np.diff(idx) > 0)


def test_a_thinning_buffer_keeps_waiting_frames_spread_over_the_busy_time():
    from companion.onboard.runner import FrameBuffer

    image = np.zeros((2, 2, 3), np.uint8)
    thin, oldest = FrameBuffer(10, "thin"), FrameBuffer(10, "oldest")
    dropped_thin = [thin.put(Frame(i, i / 30.0, image)) for i in range(100)]  # a worker busy for 100 frames
    dropped_old = [oldest.put(Frame(i, i / 30.0, image)) for i in range(100)]
    assert sum(d is not None for d in dropped_thin) == sum(d is not None for d in dropped_old) == 90
    kept_thin = [thin.get().index for _ in range(10)]
    kept_old = [oldest.get().index for _ in range(10)]
    assert kept_old == list(range(90, 100))  # a 90-frame hole: the stretch of wall flown meanwhile is lost
    assert kept_thin[0] == 0 and kept_thin[-1] == 99 and kept_thin == sorted(kept_thin)
    assert max(b - a for a, b in zip(kept_thin, kept_thin[1:], strict=False)) <= 16  # 11 on average

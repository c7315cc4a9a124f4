"""The onboard chain on a synthetic scan: keyframes meet the overlap target, backlog skipping, offline cull CLI."""

from __future__ import annotations

import json
import time

import cv2
import numpy as np
import pytest

from companion.capture.sources import FrameSource
from companion.capture.tagging import FrameTagger
from companion.capture.telemetry import ClockMap, TelemetryBuffer
from companion.cli import main
from companion.onboard.runner import Backlog, LiveRunner
from companion.onboard.setup import build_chain
from companion.records import EncodedFrame, Frame, Pose
from companion.spool.layout import CLOSED, CULL_REPORT, MANIFEST
from evaluation.keyframes.synthetic import render, sweep, textured_wall, true_overlap


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
    lines = [json.loads(x) for x in (tmp_path / MANIFEST).read_text().splitlines()]
    idx = [x["index"] for x in lines]
    assert idx[0] == 0 and idx[-1] == len(images) - 1 and len(idx) >= 4
    for a, b in zip(idx, idx[1:], strict=False):
        assert true_overlap(views[a], views[b]) >= 0.80 - 0.03
        if b + 1 < len(views):  # the next frame would have been below the target: the gate kept the last one above
            assert true_overlap(views[a], views[b + 1]) < 0.80 + 0.03
    assert all(x["pose"] is not None for x in lines)
    assert chain.stats.keyframes == len(idx) and chain.stats.stale_pose == 0
    assert (tmp_path / CLOSED).exists()  # a following stitcher makes its final map


def test_live_runner_skips_backlog_but_never_a_keyframe(tmp_path):
    views, images = _scan(n=30, step=6)
    chain = build_chain(tmp_path, FrameTagger(_buffer(len(images)), ClockMap(0.0)), mask=False)
    slow = chain.process

    def slow_process(frame):  # a CPU that cannot keep up with the camera
        time.sleep(0.05)
        return slow(frame)

    chain.process = slow_process
    runner = LiveRunner(ListSource(images, delay_s=0.005), chain, Backlog(frames=2))
    runner.run_until_done()
    assert runner.error is None
    st = chain.stats
    assert st.skipped_backlog > 0 and st.frames_in == len(images)
    idx = [json.loads(x)["index"] for x in (tmp_path / MANIFEST).read_text().splitlines()]
    assert idx == sorted(set(idx)) and idx[-1] <= len(images) - 1 and len(idx) == st.keyframes


def test_after_the_flight_the_runner_waits_for_the_chain_to_finish_what_waits(tmp_path, caplog):
    """The chain fell behind the camera (slow CPU); the capture stops (the flight ended) and every frame that was
    waiting is still culled before the report: none skipped, the lag recorded."""
    views, images = _scan(n=30, step=6)
    chain = build_chain(tmp_path, FrameTagger(_buffer(len(images)), ClockMap(0.0)), mask=False)
    fast = chain.process

    def slow_process(frame):
        time.sleep(0.08)
        return fast(frame)

    chain.process = slow_process
    runner = LiveRunner(ListSource(images), chain, Backlog(frames=100, drop="thin", seconds=60.0)).start()
    while chain.stats.frames_processed < 2:
        time.sleep(0.01)
    runner.stop()
    caplog.set_level("INFO", logger="companion.onboard.runner")
    assert runner.wait_for_chain(limit_s=30.0, log_every_s=0.5)
    st = chain.stats
    assert runner.error is None and st.skipped_backlog == 0 and st.frames_processed == len(images)
    assert st.backlog_max_s >= 1.0  # the last frames waited while the first were culled (2.9 s of recording)
    assert "onboard chain catching up" in caplog.text
    assert (tmp_path / CLOSED).exists()


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
        "--no-mission",
        "--fps",
        "10",
        "--time-offset",
        "50",
    ]
    assert main(args) == 0
    report = json.loads((out / CULL_REPORT).read_text())
    assert report["corrupt"] == 1 and report["keyframes"] >= 3 and report["stale_pose"] == 0
    side = json.loads(next(out.glob("kf_*.json")).read_text())
    assert side["pose"]["mission_item"] == 3 and side["settings"]["rth"] == 0.8
    # Resuming on the same directory adds no duplicates.
    assert main(args) == 0
    idx = [json.loads(x)["index"] for x in (out / MANIFEST).read_text().splitlines()]
    assert len(idx) == len(set(idx)) == report["keyframes"]
    assert np.all(np.diff(idx) > 0)


def test_a_thinning_buffer_keeps_waiting_frames_spread_over_the_busy_time():
    from companion.onboard.runner import Backlog, FrameBuffer

    image = np.zeros((2, 2, 3), np.uint8)
    thin, oldest = FrameBuffer(Backlog(10, "thin")), FrameBuffer(Backlog(10, "oldest"))
    dropped_thin = [thin.put(Frame(i, i / 30.0, image)) for i in range(100)]  # a worker busy for 100 frames
    dropped_old = [oldest.put(Frame(i, i / 30.0, image)) for i in range(100)]
    assert sum(map(len, dropped_thin)) == sum(map(len, dropped_old)) == 90
    kept_thin = [thin.get()[0].index for _ in range(10)]
    kept_old = [oldest.get()[0].index for _ in range(10)]
    assert kept_old == list(range(90, 100))  # a 90-frame hole: the stretch of wall flown meanwhile is lost
    assert kept_thin[0] == 0 and kept_thin[-1] == 99 and kept_thin == sorted(kept_thin)
    assert max(b - a for a, b in zip(kept_thin, kept_thin[1:], strict=False)) <= 16  # 11 on average


def test_the_tracker_backlog_rides_out_a_long_busy_stretch_without_dropping_a_frame():
    """One core busy: the chain fell behind for most of the scan and a one-second buffer thinned the frames to six a
    second, leaving gaps around decisions (keyframes below the target). Twenty seconds behind now cost no frame."""
    from companion.onboard.runner import TRACKED_BACKLOG, FrameBuffer

    backlog = FrameBuffer(TRACKED_BACKLOG)
    jpeg = b"\xff" * 150_000  # a 1280 px camera JPEG
    dropped = [backlog.put(EncodedFrame(i, i / 30.0, jpeg, 1280, 720)) for i in range(600)]
    assert sum(map(len, dropped)) == 0
    first, lag = backlog.get()
    assert first.index == 0 and lag == pytest.approx(599 / 30.0)
    assert backlog.waiting() == (599, pytest.approx(598 / 30.0))


def test_a_backlog_that_keeps_growing_is_thinned_evenly_within_its_span():
    """A chain that needs 1.5x the CPU it gets for a whole flight: the waiting frames stay within the span bound
    (the telemetry the chain keeps reaches back that far) and what is dropped is spread, never a stretch."""
    from companion.onboard.runner import Backlog, FrameBuffer

    backlog = FrameBuffer(Backlog(frames=1800, drop="thin", seconds=20.0))
    processed, dropped = [], 0
    for i in range(30 * 300):  # five minutes of a 30 fps camera; the chain takes two frames in three arriving
        dropped += len(backlog.put(EncodedFrame(i, i / 30.0, b"j", 1280, 720)))
        if i % 3:
            frame, lag = backlog.get()
            processed.append(frame.index)
            assert lag <= 21.0  # the bound is kept within a second: one frame dropped per arrival past it
    assert dropped > 0 and backlog.waiting()[1] <= 21.0
    rest = [backlog.get()[0].index for _ in range(backlog.waiting()[0])]
    kept = processed + rest
    assert kept == sorted(kept) and kept[0] == 0 and kept[-1] == 30 * 300 - 1
    assert max(b - a for a, b in zip(kept, kept[1:], strict=False)) <= 6  # 1.5 on average: no stretch lost


def test_decoded_frames_are_bounded_by_megabytes():
    from companion.onboard.runner import Backlog, FrameBuffer

    backlog = FrameBuffer(Backlog(frames=1800, drop="thin", megabytes=30.0))
    image = np.zeros((720, 1280, 3), np.uint8)  # 2.76 MB decoded
    dropped = sum(len(backlog.put(Frame(i, i / 30.0, image))) for i in range(40))
    assert backlog.waiting()[0] == 10 and dropped == 30


def test_the_culling_line_of_fly_and_demo_names_keyframes_below_the_target_and_the_lag():
    """`companion fly` and the demo print the same line; the fly line used to leave out the keyframes taken below
    the overlap target and the frames off the scan, the first figures a field engineer checks."""
    from pathlib import Path

    from companion.onboard.chain import ChainStats
    from companion.onboard.scan_flight import culling_summary

    st = ChainStats()
    st.frames_processed, st.keyframes, st.low_overlap_keyframes, st.off_scan = 900, 40, 2, 120
    st.backlog_max_s = 12.34
    line = culling_summary(st, Path("/spool"))
    assert line.startswith("culling: 900 frames -> 40 keyframes in /spool (")
    assert "2 below the overlap target" in line and "120 off the scan's standoff" in line
    assert "at most 12.3 s behind the camera" in line
    assert " in " not in culling_summary(st).split("(")[0]

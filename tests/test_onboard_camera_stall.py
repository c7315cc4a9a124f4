"""A camera that stops delivering gives a clear warning; `companion record --fast` writes a recording."""

from __future__ import annotations

import json
import socket
import threading
import time

import cv2
import numpy as np

from companion.capture.simcam import SimCameraSource, encode_message
from companion.capture.tagging import FrameTagger
from companion.capture.telemetry import ClockMap, TelemetryBuffer
from companion.cli import main
from companion.onboard.runner import LiveRunner
from companion.onboard.setup import build_chain
from companion.records import Pose


def _silent_camera(server: socket.socket, frames: int, hold_s: float, warm_up_s: float = 0.0) -> None:
    conn, _ = server.accept()
    time.sleep(warm_up_s)  # building its scene before the first frame
    img = np.random.default_rng(0).integers(0, 255, (90, 160, 3), dtype=np.uint8)
    for k in range(frames):
        ok, jpg = cv2.imencode(".jpg", img)
        header = {"index": k, "capture_time_s": 1.0 + k / 10, "time_boot_ms": 1000 + 100 * k, "width": 160,
                  "height": 90, "encoding": "jpeg"}  # fmt: skip
        conn.sendall(encode_message(header, jpg.tobytes()))
    time.sleep(hold_s)  # connected but silent: a camera that stopped delivering
    conn.close()


def test_camera_that_stops_delivering_is_reported(tmp_path):
    server = socket.create_server(("127.0.0.1", 0))
    port = server.getsockname()[1]
    threading.Thread(target=_silent_camera, args=(server, 3, 3.0), daemon=True).start()
    buf = TelemetryBuffer()
    for i in range(30):
        buf.add(Pose(i / 10, 37.0, 127.0, 40.0, 10.0, 0.0, 0.0, 0.0))
    chain = build_chain(tmp_path, FrameTagger(buf, ClockMap(0.0)), mask=False)
    source = SimCameraSource("127.0.0.1", port, idle_timeout_s=0.5)
    runner = LiveRunner(source, chain)
    runner.run_until_done()
    server.close()
    assert source.stats.delivered == 3 and source.stats.stalls == 1
    assert any("stopped delivering frames after 3" in w for w in chain.stats.warnings), chain.stats.warnings
    assert chain.stats.keyframes >= 1  # what arrived before the stall was still culled and spooled


def test_a_camera_slow_to_its_first_frame_is_not_a_stall():
    server = socket.create_server(("127.0.0.1", 0))
    threading.Thread(target=_silent_camera, args=(server, 2, 1.5, 1.2), daemon=True).start()
    with SimCameraSource("127.0.0.1", server.getsockname()[1], idle_timeout_s=0.5, first_frame_timeout_s=5.0) as src:
        frames = list(src)
    server.close()
    assert len(frames) == 2 and src.stats.stalls == 1  # the warm-up waited; the silence after frame 2 did not
    assert src.stats.notes == ["no frame for 0.5 s"]


def test_sim_record_fast_writes_a_recording(tmp_path, capsys):
    from pathlib import Path

    mission = Path(__file__).parent / "data" / "small-wall.yaml"
    out = tmp_path / "rec"
    assert main(["record", str(mission), "--out", str(out), "--fast", "--max-frames", "3", "--width", "96"]) == 0
    meta = json.loads((out / "meta.json").read_text())
    assert meta["frames"] == 3 and len(list((out / "frames").glob("*.jpg"))) == 3
    assert "recorded 3 frames" in capsys.readouterr().out

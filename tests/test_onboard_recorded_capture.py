"""Recorded sources as live captures are paced on the autopilot clock; a cull that places no frame is an error.

The flight is replaced by a stand-in that appends telemetry rows to the log over time, exactly as the flight code
does (one JSON line per sample, t_boot_s on the autopilot clock, t_wall on the companion's): everything else
(tailer, pacing, tagging, chain, report) is the real live-culling path of `companion fly --capture`.
"""

from __future__ import annotations

import json
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import pytest

from companion.capture.pacing import AutopilotPacedSource
from companion.capture.sources import ImageFolderSource, open_source
from companion.capture.telemetry import TelemetryBuffer
from companion.cli import main
from companion.errors import CompanionError
from companion.mission import load_mission, plan_scan
from companion.onboard.live import NoKeyframesError, TelemetryLogTailer, run_live_scan
from companion.records import Pose
from companion.spool.layout import CULL_REPORT, MANIFEST
from evaluation.keyframes.synthetic import render, sweep, textured_wall

SMALL_WALL = Path(__file__).parent / "data" / "small-wall.yaml"


def _frames(folder: Path, n: int = 30, times: list[float] | None = None) -> Path:
    folder.mkdir(parents=True)
    tex = textured_wall(1400, 400, seed=3)
    for i, view in enumerate(sweep(tex, n, 14, 240, 180, y=200)):
        cv2.imwrite(str(folder / f"{i:04d}.jpg"), render(tex, view))
    if times is not None:
        (folder / "times.csv").write_text("name,seconds\n" + "".join(f"{i:04d}.jpg,{t}\n" for i, t in enumerate(times)))
    return folder


def _row(t: float) -> dict:
    # On the small wall's scan: 4.4 m south of it (its standoff is 4 m), 3 m up, facing north; frames taken far off
    # the scan are not judged by the gate (companion.keyframes.gate_scope)
    return {"t_wall": round(time.time(), 4), "t_boot_s": round(t, 3), "lat": 37.56646, "lon": 126.978 + t * 1e-6,
            "alt_amsl_m": 33.0, "rel_alt_m": 3.0, "roll_deg": 0.0, "pitch_deg": 0.0, "yaw_deg": 0.0,
            "vn_m_s": 0.0, "ve_m_s": 0.1, "vd_m_s": 0.0, "mission_item": 3, "mission_total": 10,
            "flight_mode": "MISSION", "armed": True, "in_air": True}


@dataclass
class _Flight:
    completed: bool = True
    items_reached: int = 10
    items_total: int = 10


class _FakeFlight:
    """Stands in for fly_mission_sync: writes telemetry rows t0, t0 + dt, ... to the log, one per ``period_s``."""

    def __init__(self, t0: float, t1: float, dt: float = 0.05, period_s: float = 0.05):
        self.times = [t0 + k * dt for k in range(int(round((t1 - t0) / dt)) + 1)]
        self.period_s = period_s
        self.called = False

    def __call__(self, plan, url, *, telemetry_log, **kwargs):
        self.called = True
        with open(telemetry_log, "a") as fh:
            for t in self.times:
                fh.write(json.dumps(_row(t)) + "\n")
                fh.flush()
                time.sleep(self.period_s)
        return _Flight()


@pytest.fixture
def plan():
    return plan_scan(load_mission(SMALL_WALL))


def test_image_folder_capture_is_paced_on_the_autopilot_clock(tmp_path, plan, monkeypatch):
    # Frames taken at t = 5.0 .. 7.9 s after the autopilot booted; the flight's telemetry starts at 4 s.
    frames = _frames(tmp_path / "rec", times=[5.0 + i / 10 for i in range(30)])
    flight = _FakeFlight(4.0, 9.0)
    monkeypatch.setattr("companion.flight.fly.fly_mission_sync", flight)
    res = run_live_scan(plan, "udp://:0", str(frames), tmp_path / "spool", mask=False)
    st = res.stats
    assert st.before_telemetry == 0 and st.stale_pose == 0, st.as_dict()
    # The fake telemetry moves ~1 cm per frame while the images sweep 14 px: the gate (which trusts the wall motion
    # predicted from telemetry) keeps few keyframes; what matters here is that every frame was placed and tagged.
    assert st.frames_in == 30 and st.keyframes >= 2, st.as_dict()
    keyframes = [json.loads(x) for x in (tmp_path / "spool" / MANIFEST).read_text().splitlines()]
    for kf in keyframes:  # tagged at their own time: the pose interpolated from the rows around it
        assert Pose.from_json(kf["pose"]).time_s == pytest.approx(kf["capture_time_s"])
        assert kf["pose"]["lon"] == pytest.approx(126.978 + kf["capture_time_s"] * 1e-6, abs=1e-9)


def test_paced_source_releases_a_frame_only_once_telemetry_reached_it(tmp_path):
    times = [2.0 + i / 10 for i in range(20)]
    buffer = TelemetryBuffer()
    paced = AutopilotPacedSource(ImageFolderSource(_frames(tmp_path / "rec", n=20, times=times)), buffer)
    released: list[tuple[float, float]] = []

    def consume():
        for frame in paced:
            released.append((frame.capture_time_s, buffer.newest_time_s))

    consumer = threading.Thread(target=consume)
    consumer.start()
    for k in range(60):  # telemetry 1.0 .. 3.95 s, then the flight ends
        buffer.add(Pose(1.0 + k * 0.05, 37.0, 127.0, 40.0, 10.0, 0.0, 0.0, 0.0))
        time.sleep(0.01)
    paced.finish()
    consumer.join(timeout=10)
    assert not consumer.is_alive()
    assert [t for t, _ in released] == times  # every frame, the last (3.9 s) reached at 3.95 s
    assert all(newest >= t for t, newest in released)
    assert paced.unreached == 0

    buffer2 = TelemetryBuffer()
    paced2 = AutopilotPacedSource(ImageFolderSource(tmp_path / "rec"), buffer2)
    for k in range(12):  # the flight ends at 2.55 s
        buffer2.add(Pose(2.0 + k * 0.05, 37.0, 127.0, 40.0, 10.0, 0.0, 0.0, 0.0))
    paced2.finish()
    got = [f.capture_time_s for f in paced2]
    assert got == times[:6]  # 2.0 .. 2.5 s
    assert paced2.unreached == 14 and "14 frames" in paced2.stats.notes[0] and "2.60" in paced2.stats.notes[0]


def test_recording_older_than_the_flight_is_an_error_not_zero_keyframes(tmp_path, plan, monkeypatch):
    # No times.csv: index / 30 fps = 0 .. 1 s, while this autopilot has been up 20 s when telemetry starts.
    frames = _frames(tmp_path / "rec")
    monkeypatch.setattr("companion.flight.fly.fly_mission_sync", _FakeFlight(20.0, 21.0))
    with pytest.raises(NoKeyframesError) as err:
        run_live_scan(plan, "udp://:0", str(frames), tmp_path / "spool", mask=False)
    text = str(err.value)
    assert "kept no keyframe" in text and "older than the flight's first telemetry sample" in text, text
    assert "t = 0.00 .. 0.97 s" in text and "t = 20.00 s" in text and "fix:" in text
    assert err.value.result.flight.completed
    report = json.loads((tmp_path / "spool" / CULL_REPORT).read_text())
    assert any("older than the flight's first telemetry sample" in w and "; fix:" in w for w in report["warnings"])
    assert all("\n" not in w for w in report["warnings"])  # warnings stay one log line each
    assert len((tmp_path / "spool" / "telemetry.jsonl").read_text().splitlines()) == 21  # nothing lost


def test_recording_after_the_flight_is_an_error(tmp_path, plan, monkeypatch):
    frames = _frames(tmp_path / "rec", times=[100.0 + i / 10 for i in range(30)])
    monkeypatch.setattr("companion.flight.fly.fly_mission_sync", _FakeFlight(4.0, 5.0, period_s=0.01))
    with pytest.raises(NoKeyframesError, match=r"30 frames of recording .* from t = 100.00 to 102.90 s") as err:
        run_live_scan(plan, "udp://:0", str(frames), tmp_path / "spool", mask=False)
    assert "last telemetry sample is at t = 5.00 s" in str(err.value)


def test_wall_clock_times_are_refused_before_the_flight(tmp_path, plan, monkeypatch):
    frames = _frames(tmp_path / "rec", n=3, times=[1.7e9, 1.7e9 + 0.1, 1.7e9 + 0.2])
    flight = _FakeFlight(4.0, 5.0)
    monkeypatch.setattr("companion.flight.fly.fly_mission_sync", flight)
    with pytest.raises(CompanionError, match="beyond any autopilot boot time"):
        run_live_scan(plan, "udp://:0", str(frames), tmp_path / "spool", mask=False)
    assert not flight.called


def test_tailer_follows_this_flight_not_the_rows_already_in_the_log(tmp_path):
    log = tmp_path / "telemetry.jsonl"
    log.write_text("".join(json.dumps(_row(500.0 + k)) + "\n" for k in range(5)))  # an earlier flight
    buffer = TelemetryBuffer()
    tailer = TelemetryLogTailer(log, buffer)
    tailer.start()
    with open(log, "a") as fh:
        for k in range(10):
            fh.write(json.dumps(_row(3.0 + k / 10)) + "\n")
    time.sleep(0.2)
    tailer.stop()
    tailer.join(timeout=5)
    assert len(buffer) == 10 and buffer.first_time_s == 3.0 and buffer.newest_time_s == pytest.approx(3.9)


def test_cull_that_places_no_frame_is_an_error_with_the_offset_to_use(tmp_path, capsys):
    frames = _frames(tmp_path / "frames", n=25)  # no times.csv: 0 .. 2.4 s at --fps 10
    log = tmp_path / "telemetry.jsonl"
    log.write_text("".join(json.dumps(_row(50.0 + i / 10)) + "\n" for i in range(30)))
    args = ["cull", str(frames), "--telemetry", str(log), "--out", str(tmp_path / "spool"), "--no-mask", "--no-mission",
            "--fps", "10"]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "kept no keyframe" in err and "all 25 frames are older than the first telemetry sample" in err, err
    assert "t = 0.00 .. 2.40 s" in err and "t = 50.00 .. 52.90 s" in err and "--time-offset 50.00" in err
    assert not (tmp_path / "spool").exists()  # nothing kept: the spool folder this run made is removed
    assert main([*args, "--time-offset", "50"]) == 0  # the suggested fix works
    printed = capsys.readouterr()
    kept = int(printed.out.split(" keyframes in ")[0].split("-> ")[-1])
    assert kept > 0 and printed.err.strip().splitlines()[-1].endswith(f"keyframes={kept}]"), printed.err


def test_times_csv_must_cover_every_image(tmp_path):
    _frames(tmp_path / "rec", n=4)
    (tmp_path / "rec" / "times.csv").write_text("0000.jpg,1.0\n0001.jpg,1.1\n")
    with pytest.raises(CompanionError, match="no time for 2 of 4 images"):
        open_source(str(tmp_path / "rec"))
    (tmp_path / "rec" / "times.csv").write_text("0000.jpg,1.0\n0001.jpg,soon\n0002.jpg,1.2\n0003.jpg,1.3\n")
    with pytest.raises(CompanionError, match="line 2 is not 'name,seconds'"):
        open_source(str(tmp_path / "rec"))

"""Live camera: a fake vehicle sends true poses over UDP; the camera streams frames over TCP to SimCameraSource."""

from __future__ import annotations

import json
import socket
import threading
import time

import numpy as np
import pytest

from companion.capture.simcam import SimCameraSource
from companion.errors import CompanionError
from companion.mission import load_mission, plan_scan
from companion.onboard.working import decode_full
from companion.records import EncodedFrame
from sim.camera.live import LiveCamera, LiveConfig, camera_pose, interpolate_pose
from sim.camera.recording import load_recording
from sim.process import free_port

MISSION = "missions/demo-facade.yaml"


class FakeVehicle(threading.Thread):
    """Hovers 4 m in front of the wall's middle, drifting east at 0.5 m/s; 50 Hz of simulated time."""

    def __init__(self, port: int, speedup: float = 2.0):
        super().__init__(daemon=True)
        self.port, self.speedup = port, speedup
        self.stop = threading.Event()
        self.frame = plan_scan(load_mission(MISSION)).frame

    def msg(self, t: float) -> dict:
        lat, lon, alt = self.frame.facade_to_geodetic(10.0 + 0.5 * t, 4.0, 6.0)
        return {"t_s": round(t, 4), "time_boot_ms": int(t * 1000), "lat": float(lat), "lon": float(lon),
                "alt_amsl_m": float(alt), "north_m": 0.0, "east_m": 0.0, "down_m": -6.0, "vn_m_s": 0.0,
                "ve_m_s": 0.5, "vd_m_s": 0.0, "roll_deg": 2.0, "pitch_deg": -3.0,
                "yaw_deg": self.frame.yaw_facing_wall_deg, "gimbal_pitch_deg": 0.0, "gimbal_yaw_deg": 0.0,
                "armed": True, "in_air": True, "home": {"lat": 37.56638, "lon": 126.97815, "alt_amsl_m": 30.0}}

    def run(self):
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        t0 = time.monotonic()
        k = 0
        while not self.stop.is_set():
            t = k * 0.02
            wait = t0 + t / self.speedup - time.monotonic()
            if wait > 0:
                time.sleep(wait)
            s.sendto(json.dumps(self.msg(t)).encode(), ("127.0.0.1", self.port))
            k += 1
        s.close()


def test_interpolation_takes_the_short_way_round():
    a = {"t_s": 0.0, "lat": 1.0, "lon": 2.0, "alt_amsl_m": 10.0, "yaw_deg": 350.0}
    b = {"t_s": 1.0, "lat": 3.0, "lon": 2.0, "alt_amsl_m": 20.0, "yaw_deg": 10.0}
    m = interpolate_pose(a, b, 0.25)
    assert m["lat"] == pytest.approx(1.5) and m["alt_amsl_m"] == pytest.approx(12.5)
    assert m["yaw_deg"] == pytest.approx(355.0)


def test_stabilised_gimbal_ignores_body_tilt():
    frame = plan_scan(load_mission(MISSION)).frame
    msg = FakeVehicle(0).msg(1.0)
    pose = camera_pose(msg, frame)
    assert pose.roll_deg == 0.0 and pose.pitch_deg == 0.0
    _, out, up = frame.enu_to_facade(*pose.position_enu)
    assert float(out) == pytest.approx(4.0, abs=1e-3) and float(up) == pytest.approx(6.0, abs=1e-3)
    assert np.allclose(pose.velocity_enu_m_s, [0.5, 0.0, 0.0])


def test_stream_and_recording_from_fake_vehicle(tmp_path):
    pose_port, stream_port = free_port(), free_port(socket.SOCK_STREAM)
    cfg = LiveConfig(pose_port=pose_port, stream_port=stream_port, width_px=160, fps=10.0,
                     record_dir=tmp_path / "live", duration_s=20.0, max_lag_frames=50)
    cam = LiveCamera(MISSION, cfg)
    runner = threading.Thread(target=cam.run, daemon=True)
    runner.start()
    vehicle = FakeVehicle(pose_port)
    vehicle.start()
    frames = []
    try:
        with SimCameraSource(port=stream_port, idle_timeout_s=10.0) as src:
            for f in src:
                frames.append(f)
                if len(frames) == 6:
                    break
    finally:
        cam.stop.set()
        runner.join(timeout=10)
        vehicle.stop.set()
    assert len(frames) == 6
    times = np.array([f.capture_time_s for f in frames])
    assert np.all(np.diff(times) > 0)
    assert np.allclose(times * 10.0, np.round(times * 10.0), atol=1e-6)  # capture instants k / fps
    assert all(f.index == round(f.capture_time_s * 10) for f in frames)
    assert all(isinstance(f, EncodedFrame) and (f.width, f.height) == (160, 90) for f in frames)  # decoded by the chain
    assert decode_full(frames[0]).image.shape == (90, 160, 3)
    rec = load_recording(tmp_path / "live")
    assert len(rec) >= 6
    # the recorded truth is the fake vehicle's pose at the capture instant
    i = len(rec) - 1
    _, out, up = rec.frame.enu_to_facade(*rec.camera_pose(i).position_enu)
    along, _, _ = rec.frame.enu_to_facade(*rec.camera_pose(i).position_enu)
    assert float(along) == pytest.approx(10.0 + 0.5 * rec.capture_time(i), abs=0.01)
    assert float(out) == pytest.approx(4.0, abs=0.01)
    assert (rec.roi_mask(i) > 0).all()  # hovering mid-wall at 4 m: all facade


def test_missing_camera_is_a_companion_error():
    with pytest.raises(CompanionError, match="simulated camera"):
        SimCameraSource(port=free_port(socket.SOCK_STREAM), connect_timeout_s=0.3)


def test_a_recording_failure_stops_the_camera_with_that_error(tmp_path):
    """Encoding, streaming and recording run on a delivery thread; its failure must not be lost."""
    pose_port = free_port()
    cfg = LiveConfig(pose_port=pose_port, stream_port=free_port(socket.SOCK_STREAM), width_px=64, fps=10.0,
                     record_dir=tmp_path / "live", duration_s=20.0, max_lag_frames=50)
    cam = LiveCamera(MISSION, cfg)

    def full_disk(*_a, **_k):
        raise OSError(28, "No space left on device")

    cam.writer.add = full_disk
    vehicle = FakeVehicle(pose_port)
    vehicle.start()
    try:
        t0 = time.monotonic()
        with pytest.raises(OSError, match="No space left"):
            cam.run()
        assert time.monotonic() - t0 < 15.0  # stopped at the failure, not at the 20 s duration
    finally:
        vehicle.stop.set()


def test_a_camera_behind_drops_frames_spread_not_a_stretch():
    """With one core of the machine busy the camera stalled for up to 0.9 s and then jumped to the newest pose: 27
    frames in a row never sent, and the keyframe gate took a keyframe below its target across the gap. After a
    stall it now drops a quarter of its lag per frame rendered, so the frames it sends keep coming from inside the
    stall. The loop below is the camera's own timeline: a 0.9 s stall at frame 300, then 20 ms per frame."""
    from types import SimpleNamespace

    camera = SimpleNamespace(cfg=LiveConfig(), fps=30.0)
    behind = LiveCamera._next_when_behind
    sent, k, clock = [], 0, 0.0
    while k < 600:
        t = k / camera.fps
        clock = max(clock, t)  # the newest pose: the camera never renders ahead of simulated time
        lag = (clock - t) * camera.fps
        if lag > camera.cfg.max_lag_frames:
            k = behind(camera, k, lag, clock)
            t = k / camera.fps
        sent.append(k)
        clock += 0.9 if k == 300 else 0.020
        k += 1
    gaps = np.diff(sent)
    assert sent[-1] >= 590 and gaps.max() <= 8  # the old jump: a gap of 28 frames after the stall
    assert behind(camera, 0, 120.0, 4.0) == 120  # past catch_up_frames (3 s): the newest pose's frame

"""The true-pose channel (vehicle -> sim camera) and the truth log: the contract fields at 50 Hz simulated."""

from __future__ import annotations

import json
import socket
import time

import pytest

from tests.sitl import SitlVehicle

pytestmark = pytest.mark.sitl

FIELDS = {"t_s", "time_boot_ms", "lat", "lon", "alt_amsl_m", "north_m", "east_m", "down_m", "vn_m_s", "ve_m_s",
          "vd_m_s", "roll_deg", "pitch_deg", "yaw_deg", "gimbal_pitch_deg", "gimbal_yaw_deg", "armed", "in_air",
          "home",
          # the estimator's position beside the truth, and the GNSS bias between them (issue 26)
          "nav_lat", "nav_lon", "nav_alt_amsl_m", "nav_north_m", "nav_east_m", "nav_down_m", "gnss_bias_enu_m"}


def test_pose_channel_and_truth_log(tmp_path):
    truth = tmp_path / "truth.jsonl"
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        sock.settimeout(0.2)
        poses = []
        with SitlVehicle(speedup=5, pose_port=sock.getsockname()[1], truth_log=truth,
                         home="37.56638,126.97815,30.0", home_yaw=90):
            # the first pose may take seconds on a loaded machine (the process imports numpy, pymavlink, ...): wait
            # for it generously, then listen 1.5 s of wall time
            start, end = time.monotonic(), None
            while time.monotonic() < (end or start + 60.0):
                try:
                    poses.append(json.loads(sock.recv(65535)))
                except TimeoutError:
                    continue
                end = end or time.monotonic() + 1.5
    assert len(poses) > 50
    p = poses[-1]
    assert set(p) == FIELDS
    assert p["home"] == {"lat": 37.56638, "lon": 126.97815, "alt_amsl_m": 30.0}
    assert p["lat"] == pytest.approx(37.56638) and p["alt_amsl_m"] == pytest.approx(30.0)
    assert p["yaw_deg"] == pytest.approx(90.0) and p["armed"] is False and p["in_air"] is False
    steps = [round(b["t_s"] - a["t_s"], 4) for a, b in zip(poses, poses[1:], strict=False)]
    assert min(steps) > 0 and sorted(steps)[len(steps) // 2] == pytest.approx(0.02)  # 50 Hz simulated time
    assert poses[-1]["time_boot_ms"] == round(poses[-1]["t_s"] * 1000)
    rows = [json.loads(line) for line in truth.read_text().splitlines()]
    assert len(rows) >= len(poses) and set(rows[0]) == FIELDS

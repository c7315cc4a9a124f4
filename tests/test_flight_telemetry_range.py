"""The telemetry log's forward rangefinder distance (issue 26): ``range_forward_m`` in each row, the true standoff a
GNSS bias cannot move, carried by the pose JSON into tagged frames and spooled keyframes."""

from __future__ import annotations

import asyncio
import io
import json

import pytest

from companion.capture.telemetry import TelemetryBuffer
from companion.flight.connection import connect, request_rates
from companion.flight.telemetry_log import TelemetryRecorder, read_telemetry_log
from companion.records import Pose
from sim.vehicle.rangefinder import WallSpec
from tests.sitl import SitlVehicle
from tests.test_sim_vehicle_rangefinder import HOME, _wall_north


class _Msg:
    def __init__(self, **fields):
        self.fields_json = json.dumps(fields)


def _reading(t_s: float, cm: int, orientation: int = 0) -> _Msg:
    return _Msg(time_boot_ms=int(t_s * 1000), min_distance=20, max_distance=4000, current_distance=cm, type=0, id=0,
                orientation=orientation, covariance=4)


def _row(rec: TelemetryRecorder, t_boot: float = 12.345) -> dict:
    rec._file = io.StringIO()
    rec._write_row(t_boot, 37.5, 127.0, 40.0, 10.0, (0.1, 0.2, 0.0))
    return json.loads(rec._file.getvalue())


def test_a_row_carries_the_forward_reading_nearest_its_time_and_null_otherwise():
    rec = TelemetryRecorder(vehicle=None)
    assert _row(rec)["range_forward_m"] is None  # no rangefinder: null, the key still there
    rec._on_distance_sensor(_reading(12.0, 790))
    rec._on_distance_sensor(_reading(12.3, 812))
    rec._on_distance_sensor(_reading(12.6, 830))
    assert _row(rec)["range_forward_m"] == 8.12  # the reading nearest the row's autopilot time
    assert _row(rec, 13.05)["range_forward_m"] == 8.30  # 0.45 s after the last: still its distance
    assert _row(rec, 13.2)["range_forward_m"] is None  # stale: more than 0.5 s from every reading
    rec._on_distance_sensor(_reading(14.0, 4001))  # max + 1: MAVLink's "nothing in range"
    assert _row(rec, 14.0)["range_forward_m"] is None
    rec._on_distance_sensor(_reading(15.0, 10))  # below the sensor's minimum
    assert _row(rec, 15.0)["range_forward_m"] is None
    rec._on_distance_sensor(_reading(16.0, 500, orientation=25))  # a downward rangefinder is not the wall
    assert _row(rec, 16.0)["range_forward_m"] is None
    pose = Pose.from_json({**_row(rec, 12.3), "roll_deg": 0.0, "pitch_deg": 0.0, "yaw_deg": 10.0})
    assert pose.range_forward_m == 8.12


def test_pose_json_carries_the_range_and_tagging_interpolates_it():
    a = Pose(1.0, 37.5, 127.0, 40.0, 10.0, 0.0, 0.0, 0.0, range_forward_m=8.0)
    b = Pose(1.1, 37.5, 127.0, 40.0, 10.0, 0.0, 0.0, 0.0, range_forward_m=8.2)
    assert a.to_json()["range_forward_m"] == 8.0 and Pose.from_json(json.loads(json.dumps(a.to_json()))) == a
    old_row = {k: v for k, v in a.to_json().items() if k != "range_forward_m"}  # a log from before the key
    assert Pose.from_json(old_row).range_forward_m is None
    buf = TelemetryBuffer()
    buf.add(a)
    buf.add(b)
    assert buf.pose_at(1.05).pose.range_forward_m == pytest.approx(8.1)
    buf.add(Pose(1.2, 37.5, 127.0, 40.0, 10.0, 0.0, 0.0, 0.0))  # the wall lost: the nearer sample's unknown
    assert buf.pose_at(1.19).pose.range_forward_m is None
    assert buf.pose_at(1.11).pose.range_forward_m == pytest.approx(8.2)


def _log_rows(tmp_path, name: str, **options) -> list[dict]:
    path = tmp_path / f"{name}.jsonl"

    async def record(url: str) -> None:
        vehicle = await connect(url, timeout_s=60)
        try:
            await request_rates(vehicle, 5.0)
            async with TelemetryRecorder(vehicle, path):
                for _ in range(200):
                    await asyncio.sleep(0.1)
                    rows = read_telemetry_log(path) if path.exists() else []
                    if sum(r["range_forward_m"] is not None for r in rows) >= 5 or len(rows) >= 30:
                        break
        finally:
            vehicle.close()

    with SitlVehicle(speedup=5, home=f"{HOME.lat},{HOME.lon},{HOME.alt_amsl_m}", log_path=tmp_path / f"{name}.log",
                     **options) as sim:
        asyncio.run(record(sim.url))
    return read_telemetry_log(path)


@pytest.mark.sitl
def test_the_telemetry_log_records_the_simulated_rangefinder(tmp_path):
    """The vehicle on the ground facing a wall 12 m north, its GNSS estimate 2 m nearer: the log's rows say 12 m;
    without a rangefinder they say null."""
    wall: WallSpec = _wall_north(12.0)
    rows = _log_rows(tmp_path, "with", rangefinder=True, rangefinder_wall=wall.option(), gnss_bias=(0.0, 2.0, 0.0))
    ranges = [r["range_forward_m"] for r in rows if r["range_forward_m"] is not None]
    assert len(ranges) >= 5 and all(r == pytest.approx(12.0, abs=0.1) for r in ranges)
    rows = _log_rows(tmp_path, "without")
    assert len(rows) >= 5 and all(r["range_forward_m"] is None for r in rows)

"""A telemetry-log row's attitude is the ATTITUDE at the row's autopilot time, also when the ATTITUDE stream lags
the position stream (a loaded companion: 6 busy loops on 2 cores made rows 0.4 s long all carry one old roll, and a
keyframe was tagged 6 degrees off). A row that cannot wait any longer says its attitude is held, and the tagger
takes frames on it as stale."""

from __future__ import annotations

import asyncio
import io
import json
import math
import time

import pytest

from companion.capture.telemetry import buffer_from_log, row_attitude_held
from companion.flight.telemetry_log import TelemetryRecorder
from companion.records import Pose


class _Msg:
    def __init__(self, **fields):
        self.fields_json = json.dumps(fields)


def _roll(t: float) -> float:
    """The true roll, degrees: a vehicle rocking +-8 degrees at about 0.5 Hz (strip starts and ends)."""
    return 8.0 * math.sin(3.0 * t)


def _att(t: float) -> _Msg:
    return _Msg(time_boot_ms=round(t * 1000), roll=math.radians(_roll(t)), pitch=math.radians(-2.0),
                yaw=math.radians(90.0), rollspeed=0.0, pitchspeed=0.0, yawspeed=0.0)


def _pos(t: float) -> _Msg:
    return _Msg(time_boot_ms=round(t * 1000), lat=375000000 + round(t * 100), lon=1270000000, alt=40000,
                relative_alt=10000, vx=0, vy=100, vz=0, hdg=9000)


def _record(messages: list[tuple[str, _Msg]], end: bool = True) -> tuple[TelemetryRecorder, list[dict]]:
    """Feed (stream, message) pairs in arrival order, end the log (``end``); the rows written."""
    rec = TelemetryRecorder(vehicle=None)
    rec._file = log = _KeptOpen()
    for stream, msg in messages:
        (rec._on_raw_att if stream == "att" else rec._on_raw_pos)(msg)
    if end:
        asyncio.run(rec.__aexit__(None, None, None))
    return rec, [json.loads(line) for line in log.getvalue().splitlines()]


class _KeptOpen(io.StringIO):
    def close(self) -> None:  # the recorder closes its log at the end; its text is still wanted
        pass


def _lagging_stream(duration_s: float, lag_s: float, burst_s: float, pos_dt: float = 0.1, att_dt: float = 0.04):
    """Positions arrive at their time; ATTITUDEs ``lag_s`` late, released in bursts every ``burst_s`` (a queue
    drained by a starved task). Arrival order, ATTITUDEs first on a tie."""
    events = []
    for i in range(round(duration_s / pos_dt)):
        t = 10.0 + i * pos_dt
        events.append((t, 1, "pos", _pos(t)))
    for i in range(round(duration_s / att_dt)):
        t = 10.0 + i * att_dt
        arrival = math.ceil((t + lag_s) / burst_s) * burst_s
        events.append((arrival, 0, "att", _att(t)))
    events.sort(key=lambda e: (e[0], e[1]))
    return [(stream, msg) for _, _, stream, msg in events]


@pytest.mark.parametrize("lag_s", [0.3, 0.6])
def test_rows_wait_for_a_lagging_attitude_stream_and_carry_the_attitude_at_their_time(lag_s):
    rec, rows = _record(_lagging_stream(duration_s=6.0, lag_s=lag_s, burst_s=0.5))
    assert len(rows) == 60
    times = [r["t_boot_s"] for r in rows]
    assert times == sorted(times)
    # the last ATTITUDE is at 15.96 s: every row up to it is interpolated, the old code held the last one (0.5 s)
    # rows that came before the first ATTITUDE (at 10.5 or 11.0 s): no attitude, never a wrong one (checked below)
    first_att_arrival = math.ceil((10.0 + lag_s) / 0.5) * 0.5
    inner = [r for r in rows if first_att_arrival <= r["t_boot_s"] <= 15.96]
    for r in inner:
        assert r["roll_deg"] == pytest.approx(_roll(r["t_boot_s"]), abs=0.02), r["t_boot_s"]
        assert r["pitch_deg"] == pytest.approx(-2.0) and r["yaw_deg"] == pytest.approx(90.0)
        assert "attitude_held" not in r and not row_attitude_held(r)
    first = [r for r in rows if r["t_boot_s"] < first_att_arrival]
    assert first and all(r["roll_deg"] is None and Pose.from_json(r) is None for r in first)
    assert rec.attitude_held_rows == 0


def test_a_row_that_waited_past_the_limit_says_its_attitude_is_held_and_tags_no_frame():
    # the ATTITUDE stream stops at 12.0 s while positions run on: rows wait ATTITUDE_WAIT_S, then go out held
    messages = [(s, m) for s, m in _lagging_stream(duration_s=6.0, lag_s=0.0, burst_s=0.04)
                if s == "pos" or json.loads(m.fields_json)["time_boot_ms"] <= 12000]
    _, before_end = _record(messages, end=False)  # held rows go out once positions ran ATTITUDE_WAIT_S past them
    assert before_end[-1]["t_boot_s"] == pytest.approx(15.9 - TelemetryRecorder.ATTITUDE_WAIT_S)
    assert row_attitude_held(before_end[-1])
    rec, rows = _record(messages)
    assert len(rows) == 60
    good = [r for r in rows if r["t_boot_s"] <= 12.0]
    held = [r for r in rows if r["t_boot_s"] > 12.0]
    assert all(not row_attitude_held(r) for r in good)
    assert all(r["roll_deg"] == pytest.approx(_roll(r["t_boot_s"]), abs=0.02) for r in good)
    assert all(row_attitude_held(r) for r in held) and rec.attitude_held_rows == len(held)
    assert held[0]["attitude_age_s"] == pytest.approx(held[0]["t_boot_s"] - 12.0, abs=1e-3)
    assert held[0]["roll_deg"] == pytest.approx(_roll(12.0))  # the newest ATTITUDE, held, never passed as exact

    buf = buffer_from_log(rows)
    assert not buf.pose_at(11.05).stale
    assert buf.pose_at(11.05).pose.roll_deg == pytest.approx(_roll(11.05), abs=0.2)
    result = buf.pose_at(13.05)
    assert result.stale and result.pose is None and "held" in result.reason
    assert buf.pose_at(12.05).stale  # between the last measured row and the first held one

    # a log from before the keys: no row is held, frames are tagged as they were
    old = [{k: v for k, v in r.items() if k not in ("attitude_held", "attitude_age_s")} for r in rows]
    assert not buffer_from_log(old).pose_at(13.05).stale


def test_an_attitude_stream_ahead_of_the_positions_is_interpolated_too():
    # positions lag 1.2 s (real ArduCopter SITL at speed-up 5 saw such a gap between the streams)
    events = []
    for i in range(40):
        t = 10.0 + i * 0.1
        events.append((t + 1.2, "pos", _pos(t)))
    for i in range(100):
        t = 10.0 + i * 0.04
        events.append((t, "att", _att(t)))
    events.sort(key=lambda e: e[0])
    rec, rows = _record([(s, m) for _, s, m in events])
    assert len(rows) == 40
    assert all(r["roll_deg"] == pytest.approx(_roll(r["t_boot_s"]), abs=0.02) for r in rows)
    assert rec.attitude_held_rows == 0 and rec.reboot is None


def test_a_reboot_writes_the_waiting_rows_and_starts_the_attitude_history_afresh():
    rec = TelemetryRecorder(vehicle=None)
    rec._file = io.StringIO()
    rec._on_raw_att(_att(100.0))
    rec._on_raw_pos(_pos(100.1))  # waits for the ATTITUDE after it
    rec._on_raw_pos(_pos(1.0))  # the autopilot restarted: its clock went back
    assert rec.reboot is not None
    rec._on_raw_att(_att(0.96))
    rec._on_raw_att(_att(1.04))
    rows = [json.loads(line) for line in rec._file.getvalue().splitlines()]
    assert [r["t_boot_s"] for r in rows] == [100.1, 1.0]
    # the other order: the ATTITUDE clock goes back first
    rec2 = TelemetryRecorder(vehicle=None)
    rec2._file = io.StringIO()
    rec2._on_raw_att(_att(100.0))
    rec2._on_raw_pos(_pos(100.1))
    rec2._on_raw_att(_att(0.96))  # the old boot's row goes out, held
    rec2._on_raw_pos(_pos(1.0))
    rec2._on_raw_att(_att(1.04))
    assert [json.loads(line) for line in rec2._file.getvalue().splitlines()] == [
        {**rows[0], "t_wall": json.loads(rec2._file.getvalue().splitlines()[0])["t_wall"]},
        {**rows[1], "t_wall": json.loads(rec2._file.getvalue().splitlines()[1])["t_wall"]}]
    assert rows[0]["attitude_held"] is True
    assert rows[1]["roll_deg"] == pytest.approx((_roll(0.96) + _roll(1.04)) / 2, abs=1e-6)
    assert "attitude_held" not in rows[1]


def test_the_live_tailer_takes_a_held_rows_frames_as_stale(tmp_path):
    from companion.capture.telemetry import TelemetryBuffer
    from companion.onboard.live import TelemetryLogTailer

    messages = [(s, m) for s, m in _lagging_stream(duration_s=3.0, lag_s=0.0, burst_s=0.04)
                if s == "pos" or json.loads(m.fields_json)["time_boot_ms"] <= 10500]
    _, rows = _record(messages)
    assert any(row_attitude_held(r) for r in rows)
    log = tmp_path / "telemetry.jsonl"
    log.touch()
    buffer = TelemetryBuffer()
    tailer = TelemetryLogTailer(log, buffer)
    tailer.start()
    with open(log, "a") as fh:
        fh.write("".join(json.dumps(r) + "\n" for r in rows))
    deadline = time.monotonic() + 5.0
    while len(buffer) < len(rows) and time.monotonic() < deadline:
        time.sleep(0.02)
    tailer.stop()
    tailer.join(timeout=5)
    assert len(buffer) == len(rows)
    assert not buffer.pose_at(10.25).stale
    assert buffer.pose_at(11.25).stale and "held" in buffer.pose_at(11.25).reason

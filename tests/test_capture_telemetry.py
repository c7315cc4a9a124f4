"""Pose interpolation at capture time, stale detection and clock mapping."""

from __future__ import annotations

import threading
import time

import pytest

from companion.attitude import euler_to_quat, quat_to_euler
from companion.capture.tagging import FrameTagger
from companion.capture.telemetry import ClockMap, TelemetryBuffer
from companion.records import Frame, Pose


def _pose(t, lat=37.0, yaw=0.0, roll=0.0, pitch=0.0, alt=40.0):
    return Pose(t, lat, 127.0, alt, alt - 30.0, roll, pitch, yaw, (1.0, 0.0, 0.0), 0.0, 3)


def test_euler_quaternion_round_trip():
    for angles in ((10.0, -20.0, 350.0), (0.0, 0.0, 0.0), (-45.0, 30.0, 90.0)):
        r, p, y = quat_to_euler(euler_to_quat(roll_deg=angles[0], pitch_deg=angles[1], yaw_deg=angles[2]))
        assert (r, p, y % 360) == pytest.approx((angles[0], angles[1], angles[2] % 360), abs=1e-9)


def test_interpolation_linear_position_and_slerp_across_north():
    buf = TelemetryBuffer()
    buf.add(_pose(10.0, lat=37.0, yaw=350.0, alt=40.0))
    buf.add(_pose(10.2, lat=37.0001, yaw=10.0, alt=42.0))
    res = buf.pose_at(10.05)
    assert not res.stale
    assert res.pose.lat == pytest.approx(37.000025) and res.pose.alt_amsl_m == pytest.approx(40.5)
    assert min(res.pose.yaw_deg, 360 - res.pose.yaw_deg) == pytest.approx(5.0, abs=1e-6)  # 355 deg, not 180


def test_stale_when_gap_or_beyond_newest():
    buf = TelemetryBuffer(max_gap_s=0.5, max_extrapolation_s=0.1)
    assert buf.pose_at(1.0).stale  # empty
    buf.add(_pose(1.0))
    buf.add(_pose(3.0))  # a 2 s hole (link outage)
    assert buf.pose_at(2.0).stale and "gap" in buf.pose_at(2.0).reason
    assert not buf.pose_at(3.05).stale
    assert buf.pose_at(3.5).stale and "behind" in buf.pose_at(3.5).reason
    assert not buf.add(_pose(2.5))  # out of order ignored


def test_clock_map_uses_minimum_delay_and_tagger_flags_stale():
    clock = ClockMap()
    assert clock.to_autopilot(5.0) is None
    for delay in (0.03, 0.01, 0.05):
        clock.observe(1000.0 + 2.0 + delay, 2.0)
    assert clock.offset_s == pytest.approx(1000.01)
    buf = TelemetryBuffer()
    buf.add(_pose(2.0))
    buf.add(_pose(2.1, lat=37.001))
    tagger = FrameTagger(buf, clock)
    tagged = tagger.tag(Frame(0, 1002.06, None))
    assert not tagged.pose_stale and tagged.pose.lat == pytest.approx(37.0005)
    assert tagger.tag(Frame(1, 1010.0, None)).pose_stale and tagger.stale_count == 1


def _rolling_in(buf: TelemetryBuffer, after_s: float) -> threading.Thread:
    """The sample after a frame's capture time arriving ``after_s`` of wall time late: the vehicle has rolled 4 deg
    (a strip's start in SITL: 0.12 -> -3.98 deg in 80 ms)."""
    def late():
        time.sleep(after_s)
        buf.add(_pose(23.0, roll=-3.98))
    thread = threading.Thread(target=late)
    thread.start()
    return thread


def test_a_live_frame_newer_than_the_telemetry_waits_for_the_sample_after_it():
    """SITL on a loaded machine (CI): a keyframe captured at 23.0 s was tagged while the newest sample was 22.92 s,
    so it got that sample's attitude held (roll 0.12 deg against the true -3.98). Waiting for the sample after the
    capture time tags it by interpolation. Without a wait (a recorded flight) the old answer stands."""
    buf = TelemetryBuffer(max_extrapolation_s=0.1)
    buf.add(_pose(22.92, roll=0.12))
    clock = ClockMap(fixed_offset_s=0.0)
    thread = _rolling_in(buf, 0.05)
    tagged = FrameTagger(buf, clock, wait_for_telemetry_s=5.0).tag(Frame(69, 23.0, None))
    thread.join()
    assert not tagged.pose_stale and tagged.pose.roll_deg == pytest.approx(-3.98)

    buf = TelemetryBuffer(max_extrapolation_s=0.1)
    buf.add(_pose(22.92, roll=0.12))
    thread = _rolling_in(buf, 0.05)
    held = FrameTagger(buf, clock).tag(Frame(69, 23.0, None))
    thread.join()
    assert held.pose.roll_deg == pytest.approx(0.12)  # the old answer: tagged at once, the last sample held


def test_a_silent_link_costs_one_wait_not_one_per_frame():
    buf = TelemetryBuffer(max_extrapolation_s=0.1)
    buf.add(_pose(10.0))
    tagger = FrameTagger(buf, ClockMap(fixed_offset_s=0.0), wait_for_telemetry_s=0.3)
    t0 = time.monotonic()
    assert not tagger.tag(Frame(0, 10.05, None)).pose_stale  # waited 0.3 s in vain, then held as before
    first = time.monotonic() - t0
    t1 = time.monotonic()
    for k in range(1, 20):
        tagger.tag(Frame(k, 10.05 + k * 0.1, None))
    rest = time.monotonic() - t1
    assert first >= 0.3 and rest < 0.3, (first, rest)
    buf.add(_pose(12.0))  # the link is back: the next frame newer than it waits again
    thread = threading.Thread(target=lambda: (time.sleep(0.05), buf.add(_pose(12.2, roll=5.0))))
    thread.start()
    tagged = tagger.tag(Frame(30, 12.2, None))
    thread.join()
    assert tagged.pose.roll_deg == pytest.approx(5.0)


def test_a_frame_the_chain_reaches_a_minute_late_is_tagged_from_the_live_buffer():
    """The live buffer (``live._telemetry_samples``: the backlog's minute + 2 min at the asked rate x1.5) reaches
    back past the chain's whole backlog: a frame tagged 60 s after its capture, with 30 Hz telemetry flowing in the
    meantime, gets the interpolated pose, as it would have at once. (test_onboard_sitl's stale poses under load
    were telemetry gaps of up to 1 s in the autopilot's own stream, not the chain's lateness: tests/
    test_keyframes_gate_scope.py has what they did to the scan.)"""
    from companion.onboard.live import _telemetry_samples
    from companion.onboard.runner import TRACKED_BACKLOG

    buf = TelemetryBuffer(max_samples=_telemetry_samples(TRACKED_BACKLOG, 30.0))
    tagger = FrameTagger(buf, ClockMap(fixed_offset_s=0.0), wait_for_telemetry_s=0.5)
    rate = 30.0 * 1.5  # samples may come faster than asked
    for k in range(int(240 * rate)):
        buf.add(_pose(k / rate, lat=37.0 + 1e-6 * k / rate))
    for t in (60.0, 100.05, 179.99):  # the newest sample is at ~240 s: up to three minutes behind
        tagged = tagger.tag(Frame(int(t * 3), t, None))
        assert not tagged.pose_stale and tagged.pose.lat == pytest.approx(37.0 + 1e-6 * t, abs=1e-10)
    assert tagger.tag(Frame(1, 40.0, None)).pose_stale  # older than the ring: the limit is beyond the backlog

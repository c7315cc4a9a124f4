"""The standoff controller's decisions (issue 26: the flight closes the loop on the measured standoff)."""

from __future__ import annotations

import random

import pytest

from companion.errors import CompanionError
from companion.flight.standoff_control import (
    ABORT,
    CAPPED,
    CORRECT,
    MEASURING,
    NO_MEASUREMENT,
    NOT_JUDGED,
    ON_PLAN,
    RECOVERED,
    SETTLING,
    TOO_CLOSE,
    HeightTracker,
    Measurement,
    StandoffController,
    StandoffSettings,
    correction_line,
    rangefinder_measurement,
)

PLAN = 4.0


def _fly(ctl: StandoffController, distance, t0: float, t1: float, leg: int = 3, hz: float = 10.0, noise=0.02,
         seed=1, sigma=0.03, source="rangefinder") -> list:
    """Measurements at ``hz`` from t0 to t1 (``distance``: metres or a function of time), a decision after each."""
    rng = random.Random(seed)
    decisions = []
    n = int(round((t1 - t0) * hz))
    for k in range(n + 1):
        t = t0 + k / hz
        d = distance(t) if callable(distance) else distance
        ctl.observe(Measurement(t, d + rng.gauss(0.0, noise), sigma, source), leg)
        decisions.append(ctl.decide(t, leg))
    return decisions


def test_no_bias_changes_nothing():
    ctl = StandoffController(StandoffSettings(PLAN))
    decisions = _fly(ctl, PLAN, 0.0, 60.0)
    assert {d.action for d in decisions[5:]} == {ON_PLAN}
    assert ctl.corrections == [] and ctl.offset_m == 0.0


def test_noise_within_the_tolerance_changes_nothing():
    ctl = StandoffController(StandoffSettings(PLAN, tolerance_m=0.3))
    decisions = _fly(ctl, PLAN + 0.2, 0.0, 60.0, noise=0.08)
    assert CORRECT not in {d.action for d in decisions} and ctl.corrections == []


def test_too_close_by_1_5_m_for_3_s_gives_one_correction_of_1_5_m_out():
    ctl = StandoffController(StandoffSettings(PLAN))
    decisions = _fly(ctl, PLAN - 1.5, 0.0, 2.5)
    assert CORRECT not in {d.action for d in decisions}  # not for 2.5 s: the hold is 3 s
    decisions = _fly(ctl, PLAN - 1.5, 2.6, 3.5, seed=2)
    corrections = [d for d in decisions if d.action == CORRECT]
    assert corrections, [d.action for d in decisions]
    first = corrections[0]
    assert first.shift_out_m == pytest.approx(1.5, abs=0.05)
    assert first.measured.distance_m == pytest.approx(2.5, abs=0.05)
    assert correction_line(first, PLAN).startswith("standoff measured 2.5")
    assert "moving the scan 1.5" in correction_line(first, PLAN) and correction_line(first, PLAN).endswith("m out")
    ctl.applied(first, first.measured.time_s, leg=3)
    assert ctl.offset_m == pytest.approx(1.5, abs=0.05)
    # the vehicle now flies the moved path: on plan, nothing more
    after = _fly(ctl, PLAN, 4.0, 30.0, leg=4, seed=3)
    assert CORRECT not in {d.action for d in after} and len(ctl.corrections) == 1
    summary = ctl.summary()
    assert summary.corrections[0].shift_out_m == pytest.approx(1.5, abs=0.05)
    assert [g.leg for g in summary.legs] == [3, 4]
    assert summary.legs[1].median_m == pytest.approx(PLAN, abs=0.02)
    assert summary.as_json()["corrections"][0]["kind"] == "correct"


def test_one_correction_per_leg_and_a_cap_on_its_size():
    ctl = StandoffController(StandoffSettings(PLAN, max_correction_m=1.0))
    decisions = _fly(ctl, PLAN - 1.5, 0.0, 4.0)
    first = next(d for d in decisions if d.action == CORRECT)
    assert first.shift_out_m == pytest.approx(1.0)  # capped
    ctl.applied(first, first.measured.time_s, leg=3)
    decisions = _fly(ctl, PLAN - 0.5, 4.0, 20.0, seed=4)  # still 0.5 m close on the same leg: on its way out
    assert {d.action for d in decisions} == {SETTLING}
    decisions = _fly(ctl, PLAN + 0.5, 20.0, 27.0, leg=4, seed=5)  # the next leg may correct again (in, this time)
    assert any(d.action == CORRECT and d.shift_out_m == pytest.approx(-0.5, abs=0.05) for d in decisions)


def test_what_is_measured_on_the_way_to_the_moved_path_moves_nothing():
    """The scan moved 1.5 m out on leg 3; the vehicle flies a straight line to the moved waypoint at that leg's
    end, so on the rest of leg 3 it is between the two paths (3.3 m, say). Counted, that made a second correction
    of +0.5 m on the next leg (the camera's 5 s window still held it) and a third of -0.5 m after it, the demo
    flown 4.5 m from the wall for a strip. Nothing is judged until the vehicle is on the moved path; a camera
    estimate counts once its window is wholly past the arrival."""
    ctl = StandoffController(StandoffSettings(PLAN))
    d = next(d for d in _fly(ctl, PLAN - 1.5, 0.0, 4.0, source="camera") if d.action == CORRECT)
    ctl.applied(d, 4.0, leg=3)
    decisions = _fly(ctl, lambda t: 2.5 + 1.5 * (t - 4.0) / 20.0, 4.1, 24.0, source="camera")  # the diagonal
    assert {d.action for d in decisions} == {SETTLING}
    late = _fly(ctl, 3.3, 24.1, 26.0, leg=4, source="camera")  # the estimate still mixing in the diagonal's
    after = _fly(ctl, PLAN, 26.1, 40.0, leg=4, source="camera")
    assert CORRECT not in {d.action for d in late + after} and ON_PLAN in {d.action for d in after}
    assert len(ctl.corrections) == 1


def test_too_far_moves_in_but_never_past_the_floor():
    ctl = StandoffController(StandoffSettings(PLAN))
    d = next(d for d in _fly(ctl, PLAN + 1.0, 0.0, 4.0) if d.action == CORRECT)
    assert d.shift_out_m == pytest.approx(-1.0, abs=0.05)
    with pytest.raises(CompanionError):
        StandoffSettings(PLAN, floor_m=3.8).check()  # a floor above standoff - tolerance cannot be held


def test_below_the_floor_backs_off_at_once_and_aborts_unless_it_recovers():
    settings = StandoffSettings(PLAN, recover_s=5.0)
    assert settings.floor == pytest.approx(2.4)
    ctl = StandoffController(settings)
    decisions = _fly(ctl, 2.0, 0.0, 1.0)
    back_off = next(d for d in decisions if d.action == TOO_CLOSE)  # within a second, no 3 s hold
    assert back_off.measured.time_s <= 0.7
    assert back_off.shift_out_m == pytest.approx(2.0, abs=0.05)
    ctl.applied(back_off, 0.7, leg=3)
    # it stays too close (the move did not happen): ends the flight after settle + recover
    decisions = _fly(ctl, 2.0, 0.8, 9.0, seed=6)
    assert decisions[-1].action == ABORT or ABORT in {d.action for d in decisions}
    assert "safety floor" in next(d for d in decisions if d.action == ABORT).reason

    ctl = StandoffController(settings)
    back_off = next(d for d in _fly(ctl, 2.0, 0.0, 1.0) if d.action == TOO_CLOSE)
    ctl.applied(back_off, 0.7, leg=3)
    decisions = _fly(ctl, lambda t: min(PLAN, 2.0 + (t - 0.7)), 0.8, 9.0, seed=7)  # moves out: recovers
    assert RECOVERED in {d.action for d in decisions} and ABORT not in {d.action for d in decisions}
    assert ctl.summary().corrections[0].kind == "back off"


def test_no_measurement_is_said_never_on_plan():
    ctl = StandoffController(StandoffSettings(PLAN))
    assert ctl.decide(10.0, leg=3).action == NO_MEASUREMENT
    _fly(ctl, PLAN, 10.0, 12.0)
    assert ctl.decide(12.5, leg=3).action == ON_PLAN
    assert ctl.decide(14.0, leg=3).action == NO_MEASUREMENT  # the readings stopped
    assert ctl.decide(14.0, leg=None).action == NOT_JUDGED  # off the scan: not judged at all
    summary = StandoffController(StandoffSettings(PLAN))
    summary.decide(1.0, leg=2)
    assert not summary.summary().measured and summary.summary().unmeasured_legs == (2,)
    assert "NOT measured" in summary.summary().line()


def test_camera_and_rangefinder_combine_by_uncertainty():
    ctl = StandoffController(StandoffSettings(PLAN))
    for k in range(40):
        t = k / 10
        ctl.observe(Measurement(t, 2.5, 0.03, "rangefinder"), 3)
        ctl.observe(Measurement(t, 3.0, 0.3, "camera"), 3)  # the camera's sigma is 10x: it weighs 1 %
    d = ctl.decide(4.0, 3)
    assert d.action == CORRECT and d.measured.distance_m == pytest.approx(2.51, abs=0.01)
    assert d.measured.source == "camera+rangefinder"


def test_a_rangefinder_reading_the_height_never_pulls_the_scan_into_the_wall():
    """Real ArduCopter SITL's rangefinder, configured facing forward (RNGFND1_ORIENT 0), reported the height above
    the ground; with a GNSS bias putting the vehicle 2.45 m from the wall, the flight took the height for the wall
    distance and moved the scan 4 m in. Now: while it climbs a strip its readings spread, which moves nothing; when
    the camera measures too, the two disagree and the nearer (the camera's 2.45 m) steers: the scan moves out."""
    ctl = StandoffController(StandoffSettings(PLAN))
    height = lambda t: 1.5 + 0.72 * t  # noqa: E731 (a vertical strip climbed at the scan speed)
    alone = _fly(ctl, height, 0.0, 6.0, noise=0.01)
    assert CORRECT not in {d.action for d in alone}
    assert any(d.action == MEASURING and "spread" in d.reason for d in alone)
    decisions = []
    for k in range(60):
        t = 6.0 + k / 10
        ctl.observe(Measurement(t, height(t), 0.03, "rangefinder"), 3)
        ctl.observe(Measurement(t, 2.45, 0.03, "camera"), 3)
        decisions.append(ctl.decide(t, 3))
    d = next(d for d in decisions if d.action in (CORRECT, TOO_CLOSE))
    assert d.shift_out_m == pytest.approx(1.55, abs=0.05) and d.measured.source == "camera"
    assert ctl.disagreements and ctl.disagreements[0].camera_m == pytest.approx(2.45)


def test_a_rangefinder_whose_readings_follow_the_climb_is_found_and_ignored():
    """The height reading of real ArduCopter SITL's rangefinder, seen along a climbed strip: it rose 1:1 with the
    altitude, which a wall flown along never does. A real wall reading (constant, or with a step at a balcony) is
    kept."""
    tracker = HeightTracker()
    assert not any(tracker.follows_height(3, 31.5 + 0.07 * k, 1.5 + 0.07 * k) for k in range(20))  # 1.33 m climbed
    assert tracker.follows_height(3, 31.5 + 0.07 * 25, 1.5 + 0.07 * 25)  # 1.75 m: it followed the height
    wall = HeightTracker()
    assert not any(wall.follows_height(5, 31.5 + 0.07 * k, 4.0 if k < 40 else 3.2) for k in range(100))
    assert not any(wall.follows_height(6, 40.0 - 0.07 * k, 4.0 + 0.01 * (k % 3)) for k in range(100))
    ctl = StandoffController(StandoffSettings(PLAN))
    _fly(ctl, 11.0, 0.0, 2.0)
    _fly(ctl, 4.0, 0.0, 2.0, leg=4, source="camera")
    ctl.ignore_source("rangefinder")
    decisions = _fly(ctl, 11.0, 2.0, 8.0)  # ignored from now on: its history is gone with it
    assert {d.action for d in decisions} == {NO_MEASUREMENT}
    summary = ctl.summary()  # nor does the flight's summary report its readings as the wall's distance
    assert summary.sources == ("camera",) and [g.leg for g in summary.legs] == [4] and summary.unmeasured_legs == (3,)


def test_without_the_camera_a_reading_moves_the_scan_in_only_as_far_as_a_wrong_one_is_safe():
    """A downward sensor on a horizontal pass reads a steady height (11 m), which the rangefinder alone cannot tell
    from a wall: the scan moves in at most planned - floor - tolerance (1.3 m at 4 m), so were the reading wrong the
    vehicle would still be above the floor; the camera agreeing lifts the limit."""
    ctl = StandoffController(StandoffSettings(PLAN))
    d = next(d for d in _fly(ctl, 11.0, 0.0, 4.0) if d.action == CORRECT)
    assert d.shift_out_m == pytest.approx(-1.3, abs=0.01)
    ctl.applied(d, 4.0, leg=3)
    later = _fly(ctl, 9.7, 20.0, 30.0, leg=4)
    assert CORRECT not in {d.action for d in later}
    assert any(d.action == CAPPED and "confirm" in d.reason for d in later)
    confirmed = StandoffController(StandoffSettings(PLAN))
    for k in range(40):
        confirmed.observe(Measurement(k / 10, 6.0, 0.03, "rangefinder"), 3)
        confirmed.observe(Measurement(k / 10, 6.1, 0.05, "camera"), 3)
    d = confirmed.decide(4.0, 3)
    assert d.action == CORRECT and d.shift_out_m == pytest.approx(-2.0, abs=0.05)


def test_rangefinder_counts_only_facing_the_wall():
    assert rangefinder_measurement(1.0, 4.0, 10.0, 0.0, facing_deg=0.0).distance_m == pytest.approx(3.94, abs=0.01)
    assert rangefinder_measurement(1.0, 4.0, 350.0, 0.0, facing_deg=0.0) is not None
    assert rangefinder_measurement(1.0, 4.0, 20.0, 0.0, facing_deg=0.0) is None
    assert rangefinder_measurement(1.0, None, 0.0, 0.0, facing_deg=0.0) is None


def test_a_correction_moves_only_the_standoff_items_ahead_along_the_out_axis():
    from companion.flight.standoff_loop import ScanLegs
    from companion.flight.standoff_shift import resume_seq, shifted_items, speeds_in_force
    from companion.mission import items as mi
    from tests.sitl import small_demo_plan

    plan = small_demo_plan()
    for autopilot, first in (("px4", 0), ("ardupilot", 1)):
        items = plan.mavlink_items(autopilot)
        legs = ScanLegs.of(plan, items, first)
        scan = [it.seq for it in items if it.command == mi.MAV_CMD_NAV_WAYPOINT and it.seq in legs.movable]
        current = sorted(legs.leg_of)[1]  # flying the second scan leg
        moved = shifted_items(items, legs.movable, current, plan.frame.out_enu, 1.5)
        assert [(m.seq, m.command, m.z) for m in moved] == [(i.seq, i.command, i.z) for i in items]
        for old, new in zip(items, moved, strict=True):
            _, o_old, _ = plan.frame.geodetic_to_facade(old.lat, old.lon, 0.0)
            _, o_new, _ = plan.frame.geodetic_to_facade(new.lat, new.lon, 0.0)
            if old.seq in scan and old.seq >= current:
                assert float(o_new - o_old) == pytest.approx(1.5, abs=0.02)  # 1e-7 deg: about 1 cm
            else:
                assert new == old  # take-off, landing, home placeholder, items behind: untouched
        assert moved[0] == items[0]
        start = resume_seq(items, current, first)
        assert start <= current and all(items[s].command != mi.MAV_CMD_NAV_WAYPOINT for s in range(start, current))
        assert speeds_in_force(items, current)[0][1] == pytest.approx(plan.estimates.scan_speed_m_s)


def test_the_cameras_late_estimates_still_decide_and_show_the_recovery():
    """The chain's estimate arrives up to seconds after its frames (it runs behind the camera) and covers the
    pairs of its last 5 s: it is current for 5 s, and after a move only counts once its window is past it."""
    ctl = StandoffController(StandoffSettings(PLAN, recover_s=10.0))
    lag = 2.5
    decisions = []
    for k in range(30):  # estimates of frame times 0..2.9 s, each arriving 2.5 s later
        t = k / 10
        ctl.observe(Measurement(t, 2.0, 0.05, "camera"), 3)
        decisions.append(ctl.decide(t + lag, 3))
    back_off = next(d for d in decisions if d.action == TOO_CLOSE)
    assert back_off.measured.source == "camera"
    ctl.applied(back_off, 3.0 + lag, leg=3)
    # the move is done by ~7 s; the camera's window holds older pairs until 12.5 s: those do not end the flight
    outcome = []
    for k in range(60, 260):
        t = k / 10
        d = 2.0 if t < 7.0 else (3.0 if t < 12.5 else PLAN)
        ctl.observe(Measurement(t, d, 0.05, "camera"), 3)
        outcome.append(ctl.decide(t + lag, 3).action)
    assert RECOVERED in outcome and ABORT not in outcome[: outcome.index(RECOVERED)]


def test_the_total_move_is_capped_too():
    ctl = StandoffController(StandoffSettings(PLAN, max_correction_m=2.0))
    d = next(d for d in _fly(ctl, PLAN - 1.5, 0.0, 4.0) if d.action == CORRECT)
    ctl.applied(d, 4.0, leg=3)
    d = next(d for d in _fly(ctl, PLAN - 1.5, 10.0, 18.0, leg=4) if d.action == CORRECT)  # still near: 0.5 more
    assert d.shift_out_m == pytest.approx(0.5, abs=0.05)
    ctl.applied(d, 18.0, leg=4)
    decisions = _fly(ctl, PLAN - 1.0, 20.0, 32.0, leg=5)
    assert CORRECT not in {d.action for d in decisions} and CAPPED in {d.action for d in decisions}
    assert "per leg" in ctl.summary().line()


class _MissionCurrent:
    def __init__(self, seq: int):
        self.fields_json = f'{{"seq": {seq}}}'


class _FakeVehicle:
    """The plugins fly_moved_scan uses, keeping what they were asked; MISSION_CURRENT says ``reports(seq_set)``."""

    def __init__(self, autopilot: str, reports):
        from types import SimpleNamespace

        self.autopilot, self.calls, self.stored, self.current = autopilot, [], [], None

        async def pause_mission():
            self.calls.append("pause")

        async def upload_mission(raw):
            self.calls.append("upload")
            self.stored = list(raw)

        async def download_mission():  # in the firmware's stored form, as the simulator keeps it
            from companion.flight.upload import from_raw, to_raw
            from sim.vehicle.flavours import copter_stored_item

            got = from_raw(self.stored)
            return to_raw([got[0], *(copter_stored_item(it) for it in got[1:])])

        async def set_current_mission_item(seq):
            self.calls.append(f"current {seq}")
            self.current = seq

        async def start_mission():
            self.calls.append("start")

        async def statustexts():
            return
            yield

        async def messages(name):
            for _ in range(50):
                await asyncio.sleep(0.01)
                if self.current is not None:
                    yield _MissionCurrent(reports(self.current))

        self.mission = SimpleNamespace(pause_mission=pause_mission, upload_mission=upload_mission,
                                       download_mission=download_mission, start_mission=start_mission,
                                       set_current_mission_item=set_current_mission_item)
        self.telemetry = SimpleNamespace(subscribe_status_text=statustexts)
        self.direct = SimpleNamespace(subscribe_message=messages)

    async def command_long(self, command, *params):
        self.calls.append(f"command {command} {params}")
        return 0


import asyncio  # noqa: E402 (the fakes above need it only when run)


def test_moving_the_scan_pauses_uploads_sets_the_item_it_flew_to_and_resumes():
    from companion.flight.standoff_loop import ScanLegs
    from companion.flight.standoff_shift import fly_moved_scan, shifted_items
    from companion.mission import items as mi
    from tests.sitl import small_demo_plan

    plan = small_demo_plan()
    items = plan.mavlink_items("ardupilot")
    legs = ScanLegs.of(plan, items, 1)
    target = sorted(legs.leg_of)[1]
    moved = shifted_items(items, legs.movable, target, plan.frame.out_enu, 1.5)
    # ArduPilot: set to the CONDITION_YAW before the waypoint, MISSION_CURRENT reports the waypoint (its NAV command)
    vehicle = _FakeVehicle("ardupilot", lambda seq: seq + 1 if items[seq].command != mi.MAV_CMD_NAV_WAYPOINT else seq)
    asyncio.run(fly_moved_scan(vehicle, moved, target, 1))
    calls = [c for c in vehicle.calls if not c.startswith("command 512")]  # REQUEST_MESSAGE(MISSION_CURRENT)
    assert calls[:4] == ["pause", "upload", f"current {target - 1}", "start"], calls
    assert items[target - 1].command == mi.MAV_CMD_CONDITION_YAW
    assert any(c.startswith(f"command {mi.MAV_CMD_DO_CHANGE_SPEED}") for c in calls[4:])
    assert [it.x for it in vehicle.stored] == [it.x for it in moved]
    # a vehicle that says another item is not resumed
    stuck = _FakeVehicle("ardupilot", lambda seq: 1)
    with pytest.raises(CompanionError, match="did not confirm item"):
        asyncio.run(fly_moved_scan(stuck, moved, target, 1))
    assert "start" not in stuck.calls


def test_a_back_off_the_camera_cannot_confirm_in_time_ends_the_flight_and_says_why():
    ctl = StandoffController(StandoffSettings(PLAN, recover_s=5.0))
    back_off = next(d for d in _fly(ctl, 2.0, 0.0, 1.0, source="camera", sigma=0.05) if d.action == TOO_CLOSE)
    ctl.applied(back_off, 1.0, leg=3)
    outcome = [ctl.decide(t / 10, 3) for t in range(10, 200)]  # the chain stalled: no estimate after the move
    abort = next(d for d in outcome if d.action == ABORT)
    assert "no measurement since" in abort.reason and "s old (the camera chain running behind?)" in abort.reason


def test_a_camera_estimate_too_old_to_steer_by_is_said_as_such():
    """On a loaded companion the camera chain ran up to 85 s behind the camera (the drift bench): its estimates
    arrived, but too late to steer by. The flight must not act on them, and must say why instead of "no camera
    estimate" on a wall the chain is measuring."""
    ctl = StandoffController(StandoffSettings(4.0))
    for t in range(0, 30):
        ctl.observe(Measurement(t * 0.5, 5.3, 0.04, "camera"), leg=3)
    decision = ctl.decide(40.0, leg=3)  # the newest is 25.5 s old
    assert decision.action == NO_MEASUREMENT
    assert "26 s old" in decision.reason and "running behind" in decision.reason

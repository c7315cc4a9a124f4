"""Flight supervision without a simulator: how each ending is decided, bounded and said.

The recorder and vehicle are stand-ins holding exactly what the supervisor reads, so each case is one state of the
vehicle (already landed, refused on the ground, restarted, silent) and the test checks the ending and its wording.
"""

from __future__ import annotations

import asyncio
import time
from types import SimpleNamespace

from companion.flight.fly import FlightAbort, _Supervisor
from companion.flight.telemetry_log import TelemetryRecorder
from companion.mission import items as mi


def _items(n_waypoints: int = 4) -> list[mi.MissionItem]:
    out = [mi.MissionItem(0, 6, mi.MAV_CMD_NAV_TAKEOFF, 1, 1, 0, 0, 0, 0, 1, 1, 5.0),
           mi.MissionItem(1, 2, mi.MAV_CMD_DO_CHANGE_SPEED, 0, 1, 1, 2, -1, 0, 0, 0, 0.0)]
    for k in range(n_waypoints):
        out.append(mi.MissionItem(len(out), 6, mi.MAV_CMD_NAV_WAYPOINT, 0, 1, 0, 1, 0, 0, 1, 1 + k, 5.0))
    out.append(mi.MissionItem(len(out), 6, mi.MAV_CMD_NAV_LAND, 0, 1, 0, 0, 0, 0, 1, 1, 0.0))
    return out


class _Recorder:
    """What the supervisor reads of the telemetry recorder."""

    def __init__(self, *, item: int, armed: bool | None, in_air: bool | None, was_in_air: bool,
                 was_armed: bool = True, silent_for_s: float | None = None):
        self.state = {"mission_item": item, "armed": armed, "in_air": in_air}
        self.was_in_air = was_in_air
        self.was_armed = was_armed
        self.last_sample_wall = time.monotonic() - silent_for_s if silent_for_s is not None else time.monotonic()
        self.silent = silent_for_s is not None
        self.reboot: str | None = None
        self.status_texts: list[str] = []
        self.status_events: list[tuple[float, str, str]] = []
        self.home_before_air_m: float | None = None
        self.home_before_air_latlon: tuple[float, float] | None = None
        self.boot_time_s: float | None = None  # the autopilot's clock (the home watch's settle window)

    def say(self, severity: str, text: str) -> None:
        self.status_texts.append(f"{severity}: {text}")
        self.status_events.append((time.monotonic(), severity, text))


class _Vehicle:
    def __init__(self, rtl_fails: bool = False):
        self.rtl_commands = 0

        async def noop():
            return None

        async def rtl():
            self.rtl_commands += 1
            if rtl_fails:
                raise RuntimeError("COMMAND_DENIED")

        self.mission = SimpleNamespace(pause_mission=noop)
        self.action = SimpleNamespace(return_to_launch=rtl, land=noop)


def _supervisor(rec, vehicle=None, **kw) -> _Supervisor:
    kw.setdefault("link_loss_s", 3.0)
    kw.setdefault("flight_timeout_s", 1.0)
    kw.setdefault("end_action", "land")
    return _Supervisor(vehicle or _Vehicle(), _items(), rec, progress=False, **kw)


def _run(sup: _Supervisor, fresh_link: _Recorder | None = None) -> tuple[str | None, float]:
    async def go():
        if fresh_link is not None and not fresh_link.silent:
            async def keep_alive():
                while True:
                    fresh_link.last_sample_wall = time.monotonic()
                    await asyncio.sleep(0.05)
            task = asyncio.create_task(keep_alive())
            try:
                return await sup.run()
            finally:
                task.cancel()
        return await sup.run()

    t0 = time.monotonic()
    reason = asyncio.run(go())
    return reason, time.monotonic() - t0


def test_flight_that_ended_before_supervision_started_is_complete():
    rec = _Recorder(item=len(_items()), armed=False, in_air=False, was_in_air=True)
    sup = _supervisor(rec)
    reason, _ = _run(sup, rec)
    assert reason is None and sup.problem is None and sup.max_reached == len(_items())
    assert sup.progress.done == sup.progress.total == 6  # takeoff, 4 waypoints, land: the DO item is not counted


def test_vehicle_never_armed_waits_for_the_timeout():
    # never seen armed, never airborne: nothing says the start was refused, so the timeout decides
    rec = _Recorder(item=0, armed=False, in_air=False, was_in_air=False, was_armed=False)
    vehicle = _Vehicle()
    reason, _ = _run(_supervisor(rec, vehicle, stop_wait_s=1.0), rec)
    assert reason == FlightAbort.TIMEOUT and vehicle.rtl_commands == 1


def test_disarmed_without_take_off_is_a_refused_start_within_seconds():
    # PX4 with a mission outside its geofence: armed, takeoff refused, disarmed on the ground
    rec = _Recorder(item=0, armed=False, in_air=False, was_in_air=False)
    sup = _supervisor(rec, flight_timeout_s=600.0)
    rec.say("CRITICAL", "Geofence violation for waypoint 3")
    rec.say("INFO", "Disarmed by auto preflight disarming")
    reason, took = _run(sup, rec)
    assert reason == FlightAbort.REFUSED and took < 2.0
    assert "disarmed without taking off" in sup.problem and "Geofence violation for waypoint 3" in sup.problem


def test_critical_text_on_the_ground_ends_the_start_while_still_armed():
    rec = _Recorder(item=0, armed=True, in_air=False, was_in_air=False)
    rec.say("CRITICAL", "Geofence violation: an old text from before this flight is not its reason")
    time.sleep(0.01)
    sup = _supervisor(rec, flight_timeout_s=600.0)
    rec.say("CRITICAL", "Switching to Mission is currently not available")  # real PX4's words
    reason, took = _run(sup, rec)
    assert reason == FlightAbort.REFUSED and took < 3.0
    assert "did not take off" in sup.problem and "Switching to Mission is currently not available" in sup.problem
    assert "old text" not in sup.problem


def test_autopilot_restart_fails_the_flight_even_when_progress_says_done():
    rec = _Recorder(item=len(_items()), armed=False, in_air=False, was_in_air=True)
    rec.reboot = "the autopilot restarted: its time since boot went back from 95.0 s to 3.2 s"
    sup = _supervisor(rec, flight_timeout_s=600.0)
    reason, _ = _run(sup, rec)
    assert reason == FlightAbort.REBOOT
    assert "restarted" in sup.problem and "cannot be trusted" in sup.problem


def test_dead_link_ends_supervision_at_the_limit_and_counts_the_open_loss():
    rec = _Recorder(item=3, armed=True, in_air=True, was_in_air=True, silent_for_s=0.0)
    sup = _supervisor(rec, link_loss_s=0.3, link_dead_s=1.0, flight_timeout_s=600.0)
    reason, took = _run(sup)
    assert reason == FlightAbort.LINK and 0.9 <= took < 3.0
    assert "no telemetry for" in sup.problem and "limit 1 s" in sup.problem
    assert len(sup.link_losses) == 1 and sup.link_losses[0].closed is False


def test_failed_rtl_after_a_timeout_is_reported_not_swallowed():
    rec = _Recorder(item=3, armed=True, in_air=True, was_in_air=True)
    vehicle = _Vehicle(rtl_fails=True)
    sup = _supervisor(rec, vehicle, flight_timeout_s=0.2, stop_wait_s=0.5)
    reason, took = _run(sup, rec)
    assert reason == FlightAbort.TIMEOUT and vehicle.rtl_commands == 3  # tried, and said
    assert sup.problem.index("longer than") < sup.problem.index("NOT sent home")  # both said, in order ...
    assert took < 8.0  # ... and the wait for the landing is bounded by stop_wait_s


def test_recorder_notices_time_since_boot_going_backwards():
    rec = TelemetryRecorder(SimpleNamespace(), None)
    for t in (100.0, 100.05, 100.03, 100.1):  # small reordering between two streams is not a restart
        rec._on_boot_time(t)
    assert rec.reboot is None
    rec._on_boot_time(2.5)
    assert rec.reboot is not None and "100.1 s to 2.5 s" in rec.reboot


def test_recorder_compares_each_stream_only_with_itself():
    """Real ArduCopter SITL at speed-up 5 on a loaded machine: an ATTITUDE handled after a GLOBAL_POSITION_INT
    1.2 s newer (separate subscriptions, separate queues) was taken for a restart and ended a good flight."""
    rec = TelemetryRecorder(SimpleNamespace(), None)
    rec._on_boot_time(512.9, "GLOBAL_POSITION_INT")
    rec._on_boot_time(511.7, "ATTITUDE")  # lagging stream, not a restart
    rec._on_boot_time(513.0, "GLOBAL_POSITION_INT")
    rec._on_boot_time(512.0, "ATTITUDE")
    assert rec.reboot is None
    rec._on_boot_time(3.0, "ATTITUDE")  # the autopilot really restarted
    assert rec.reboot is not None and "512.0 s to 3.0 s" in rec.reboot


def test_home_moved_down_in_flight_ends_the_scan_with_rtl():
    """The recorder saw home at 30 m before take-off; in the air the autopilot moved it to 25.5 m: the waypoints
    ahead (5 m above home) would be flown 0.5 m above the take-off ground, under the 1 m minimum."""
    rec = _Recorder(item=3, armed=True, in_air=True, was_in_air=True)
    rec.home_before_air_m = 30.0
    rec.state["home_alt_m"] = 25.5  # waypoints 5 m above home now 0.5 m above the take-off ground
    vehicle = _Vehicle()
    sup = _supervisor(rec, vehicle, flight_timeout_s=600.0, stop_wait_s=0.5)
    reason, took = _run(sup, rec)
    assert reason == FlightAbort.HOME and vehicle.rtl_commands == 1 and took < 5.0
    assert "moved home's altitude by -4.50 m" in sup.problem and "0.50 m above the take-off ground" in sup.problem


def test_home_moving_within_the_clearance_lets_the_flight_go_on():
    rec = _Recorder(item=len(_items()), armed=False, in_air=False, was_in_air=True)
    rec.home_before_air_m = 30.0
    rec.state["home_alt_m"] = 28.0  # 5 m waypoints now 3 m above the ground: said, not ended
    sup = _supervisor(rec, flight_timeout_s=600.0)
    reason, _ = _run(sup, rec)
    assert reason is None and sup.problem is None and sup.home.moves == [-2.0]

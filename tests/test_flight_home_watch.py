"""The companion watches the autopilot's home altitude in flight (companion/flight/home_watch.py).

Real PX4 moves home's altitude for 120 s after take-off whenever its barometer and GPS altitude differ by more than
1 m; mission altitudes are relative to home, so a home moved down flies every later waypoint lower (PX4 SIH: home
1.51 m low, the demo's strip bottoms 0.04 m above the ground; docs/FLIGHT.md)."""

from __future__ import annotations

import json
import logging
import os
import subprocess
import sys

import numpy as np
import pytest

from companion.flight import read_telemetry_log
from companion.flight.home_watch import MIN_GROUND_CLEARANCE_M, HomeWatch, settle_item_seq
from companion.mission import items as mi
from companion.mission import load_mission, plan_scan
from sim.vehicle import flavours as fl
from sim.vehicle.autopilot import SimVehicle, VehicleConfig
from tests.sitl import ROOT

DEMO = ROOT / "missions/demo-facade.yaml"
PX4_SIH_PROFILE = ROOT / "sim/sitl/px4-sih.yaml"


@pytest.fixture(scope="module")
def demo_items():
    return plan_scan(load_mission(DEMO)).mavlink_items(flavour="px4")


def _flying(items, home_alt=30.0) -> HomeWatch:
    watch = HomeWatch(items)
    watch.on_home(home_alt)
    watch.on_airborne()
    return watch


def test_home_at_arming_is_the_last_one_before_the_vehicle_is_in_the_air(demo_items):
    watch = HomeWatch(demo_items)
    watch.on_home(30.4)
    watch.on_home(30.0)  # PX4 sets home again at arming
    watch.on_airborne()
    watch.on_home(29.5)
    assert watch.home_at_arming_m == 30.0 and watch.offset_m == pytest.approx(-0.5)


def test_each_move_over_the_threshold_is_said_once(demo_items, caplog):
    watch = _flying(demo_items)
    with caplog.at_level(logging.WARNING, logger="companion.flight.home_watch"):
        for alt in (30.1, 29.9, 29.6, 29.6, 29.55, 29.2, 30.0):
            watch.on_home(alt)
    assert watch.moves == pytest.approx([-0.4, -0.8, 0.0])
    said = [r.getMessage() for r in caplog.records]
    assert len(said) == 3 and "moved home's altitude by -0.40 m" in said[0]
    assert "every later mission altitude moved with it" in said[0]


def test_moves_inside_the_correction_window_are_debug_and_its_net_move_one_warning(demo_items, caplog):
    """Real PX4 SIH moved home 30+ times while the plan held above the wall: each was a warning in the log, so a real
    warning after them was lost in the noise. Inside the window they are DEBUG; its net move is said once after it."""
    watch = _settle_watch(demo_items, restore=False)
    with caplog.at_level(logging.DEBUG, logger="companion.flight.home_watch"):
        for step, alt in enumerate((30.4, 29.9, 30.5, 29.8, 30.6, 29.7)):
            watch.on_home(alt, in_window=watch.window_open(10.0 + step))
            watch.summarise_window(10.0 + step)
        watch.summarise_window(130.0)
        watch.summarise_window(131.0)
        watch.on_home(29.2, in_window=watch.window_open(131.0))  # after the window: a warning again
    warnings = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    debug = [r.getMessage() for r in caplog.records if r.levelno == logging.DEBUG]
    assert len(debug) == 6 and all("moved home's altitude" in m for m in debug)
    assert len(warnings) == 2
    assert "window is over: home moved 6 times in it (each at debug level, -v) and is now -0.30 m" in warnings[0]
    assert "by -0.80 m" in warnings[1]


def test_a_move_that_brings_a_strip_bottom_near_the_ground_ends_the_scan(demo_items):
    watch = _flying(demo_items)
    watch.on_home(29.8)  # -0.2 m: strip bottoms at 1.35 m, still clear
    assert watch.too_low(7) is None
    watch.on_home(28.49)  # -1.51 m, the real PX4 SIH re-fly: strip bottoms 0.04 m above the ground
    low = watch.too_low(7)
    assert low is not None and low.planned_m == pytest.approx(1.55, abs=0.01)
    assert low.clearance_m == pytest.approx(0.04, abs=0.01) and low.clearance_m < MIN_GROUND_CLEARANCE_M
    text = low.problem(MIN_GROUND_CLEARANCE_M)
    assert "-1.51 m" in text and "raise the strip bottoms" in text and "settle" in text


def test_only_waypoints_still_ahead_count(demo_items):
    watch = _flying(demo_items)
    watch.on_home(28.5)
    last_bottom = max(it.seq for it in demo_items if it.command == 16 and it.z < 2.0)
    assert watch.too_low(last_bottom) is not None
    assert watch.too_low(last_bottom + 1) is None  # only the exit climb, transit and the landing are left
    up = _flying(demo_items)
    up.on_home(31.5)  # home moved up: everything ahead is higher, nothing to end
    assert up.too_low(7) is None


def _fly_demo_with_home_moved(tmp_path, *extra: str, speedup: float = 20.0) -> tuple[subprocess.CompletedProcess, str]:
    """The demo mission on the simulator's PX4, which moves home 1.2 m down 30 s after take-off (inside PX4's 120 s
    window, while the vehicle flies the strips' upper parts, 3.5 m above home and up): the strips' bottoms (1.55 m
    above home, flown after the window) would be flown 0.35 m above the ground."""
    cmd = [sys.executable, "-m", "companion.cli", "fly", "--connect-timeout", "60", str(DEMO), "--sitl",
           "--speedup", f"{speedup:g}", "--no-progress", "--telemetry-log", str(tmp_path / "t.jsonl"),
           "--sim-arg", f"truth-log={tmp_path / 'truth.jsonl'}",
           "--sim-arg", "home-shift-after-takeoff=30", "--sim-arg", "home-shift-m=-1.2", *extra]
    # ~450 s simulated: 30-60 s of wall time at speed-up 20 on a quiet machine, but a
    # starved simulator (load average 39 on 2 cores) ran it at about 1x
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, env=dict(os.environ, PYTHONPATH=str(ROOT)),
                          timeout=1800)
    return proc, proc.stdout + proc.stderr


def _true_heights_by_item(tmp_path) -> dict[int, list[float]]:
    """SIH-like truth: the vehicle's true height above the take-off ground, grouped by the mission item the
    companion's log said it was flying at that autopilot time, in Mission mode (not the hold and RTL after a stop)."""
    rows = [r for r in read_telemetry_log(tmp_path / "t.jsonl") if r.get("t_boot_s") is not None]
    truth = [json.loads(line) for line in (tmp_path / "truth.jsonl").read_text().splitlines() if line.strip()]
    times = np.array([r["t_boot_s"] for r in rows])
    by_item: dict[int, list[float]] = {}
    for t in truth:
        k = int(np.searchsorted(times, t["time_boot_ms"] / 1000.0)) - 1
        if 0 <= k < len(rows) and t["in_air"] and rows[k]["flight_mode"] == "MISSION":
            by_item.setdefault(int(rows[k]["mission_item"]), []).append(-float(t["down_m"]))
    return by_item


def _settle_watch(items, *, restore: bool, **wall) -> HomeWatch:
    """Timed by the autopilot's clock alone unless ``wall`` gives a wall clock (``restore_wait_wall_s``,
    ``wall_clock``)."""
    wall = {"restore_wait_wall_s": 0.0, **wall}
    watch = HomeWatch(items, window_s=120.0, settle_seq=4, restore=restore, **wall)
    watch.on_home(30.0)
    watch.on_airborne()
    return watch


def test_a_move_while_holding_for_home_to_settle_ends_nothing_until_the_window_is_over(demo_items):
    watch = _settle_watch(demo_items, restore=False)
    watch.on_home(28.49)  # -1.51 m at 40 s, the vehicle holding at item 4 above the wall
    assert watch.settling(4, 40.0) and watch.too_low(4) is not None  # the supervisor asks settling() first
    assert not watch.settling(4, 124.0)  # window over (+3 s slack): now the move counts
    assert not watch.settling(6, 40.0)  # the vehicle left the hold early: it counts at once
    assert watch.restore_step(130.0) is None  # a real vehicle's home is never put back


def test_px4_sih_home_is_put_back_after_the_window_confirmed_by_home_position(demo_items, caplog):
    watch = _settle_watch(demo_items, restore=True)
    watch.on_home(31.69)  # +1.69 m, as real PX4 SIH moved it
    assert watch.restore_step(100.0) is None  # the window is still open
    assert watch.restore_step(123.5) == 30.0 and watch.restore_sends == 1
    assert watch.settling(4, 125.0)  # still at the hold until it is confirmed
    assert watch.restore_step(125.0) is None  # asked 1.5 s ago: wait for HOME_POSITION
    assert watch.restore_step(128.6) == 30.0 and watch.restore_sends == 2  # no answer: asked again
    with caplog.at_level(logging.WARNING, logger="companion.flight.home_watch"):
        watch.on_home(30.01)
        assert watch.restore_step(129.0) is None
    assert watch.put_back and watch.restore_done and not watch.settling(4, 129.0)
    said = [r.getMessage() for r in caplog.records]
    back = [m for m in said if "home is back" in m]
    assert len(back) == 1 and "at 30.00 m AMSL" in back[0] and "moved it by +1.69 m" in back[0]
    assert not any("by +0.01 m" in m for m in said)  # the put-back is not reported as another move
    assert watch.too_low(4) is None and watch.restore_step(200.0) is None


def test_a_put_back_asked_after_the_vehicle_left_the_hold_ends_nothing_until_it_is_confirmed(demo_items):
    """CI (speed-up 20, loaded machine): the companion saw the window's end one poll late, the vehicle had already
    left the hold for the first strip, and the flight ended with the put-back on its way (exit 1, no scan)."""
    watch = _settle_watch(demo_items, restore=True)
    watch.on_home(28.8)  # -1.2 m: the strip bottoms would be 0.35 m above the ground
    assert watch.restore_step(126.0) == 30.0  # first seen after the window, the vehicle at item 6, past the hold
    assert watch.settling(6, 126.0) and watch.too_low(6) is not None  # pending: the watch waits for HOME_POSITION
    watch.on_home(30.0)
    assert watch.restore_step(127.0) is None and watch.put_back
    assert not watch.settling(6, 127.0) and watch.too_low(6) is None  # back where it was: the strips fly as planned


def test_a_put_back_is_asked_again_only_after_wall_time_too(demo_items):
    """CI-like: a simulator at speed-up 20 on a loaded machine runs 5 s of autopilot time in 0.25 s of wall time,
    less than its HOME_POSITION confirming the put-back may take to reach the companion: a try waits for both clocks,
    so three tries are not spent (and the put-back given up, ending a good flight) before the answer can come."""
    wall = [0.0]
    watch = _settle_watch(demo_items, restore=True, restore_wait_wall_s=3.0, wall_clock=lambda: wall[0])
    watch.on_home(28.8)
    assert watch.restore_step(123.5) == 30.0
    wall[0] = 0.5  # 10 s of autopilot time later, half a second of wall time
    assert watch.restore_step(133.5) is None and watch.restore_sends == 1
    wall[0] = 3.1
    assert watch.restore_step(185.0) == 30.0 and watch.restore_sends == 2
    wall[0] = 3.6
    watch.on_home(30.0)  # the confirmation, late in autopilot time
    assert watch.restore_step(195.0) is None and watch.put_back and not watch.settling(6, 195.0)


def test_a_put_back_the_vehicle_ignores_is_given_up_and_the_watch_decides(demo_items):
    watch = _settle_watch(demo_items, restore=True)
    watch.on_home(28.8)  # -1.2 m
    sent = [t for t in (123.1, 124.0, 128.2, 133.3, 138.4, 150.0) if watch.restore_step(t) is not None]
    assert sent == [123.1, 128.2, 133.3] and watch.restore_done and not watch.put_back
    assert not watch.settling(4, 150.0) and watch.too_low(4) is not None  # ends the flight at the hold


@pytest.mark.sitl
def test_px4_sih_home_moved_while_holding_is_put_back_and_the_strips_fly_where_planned(demo_items, tmp_path):
    """Asked for (``--sitl-profile sim/sitl/px4-sih.yaml``, as for PX4 SIH): the vehicle flies the strips' upper parts
    until PX4's window is over, then home is put back where it was at arming, and the strips' bottoms are flown 1.55 m
    above the true ground. Without the profile the flight ends (exit 1) with RTL before them (the next test)."""
    proc, out = _fly_demo_with_home_moved(tmp_path, "--sitl-profile", str(PX4_SIH_PROFILE))
    assert proc.returncode == 0, out[-4000:]
    assert "window is over: home moved 1 time in it (each at debug level, -v) and is now -1.20 m" in out, out[-4000:]
    assert "SITL profile: home is back at 30.00 m AMSL" in out and "home handed back to the vehicle" in out, \
        out[-4000:]
    assert "mission complete" in out, out[-4000:]
    heights = _true_heights_by_item(tmp_path)
    bottoms = [it.seq for it in demo_items if it.command == mi.MAV_CMD_NAV_WAYPOINT and it.z < 2.0]
    lowest = [min(heights[seq]) for seq in bottoms if seq in heights]
    assert len(lowest) >= len(bottoms) - 1, sorted(heights)  # a strip end can pass between two log rows
    assert min(lowest) == pytest.approx(1.55, abs=0.2), lowest  # 0.35 m without the put-back


@pytest.mark.sitl
def test_a_real_px4_home_moved_too_low_ends_the_flight_before_the_strips_bottoms(demo_items, tmp_path):
    """PX4 without a SITL profile (a real vehicle, or the simulator flown as one: the companion detects no simulator
    and never puts home back) moves home 1.2 m down while the vehicle flies the strips' upper parts: the move ends
    nothing in the window (they stay 2.3 m above the ground or more); when the window is over the flight ends there,
    with RTL and a clear error, before any waypoint below 3.5 m above home.
    Before (a 116 s hold above the wall), it ended at the hold, 18 m up; before that (no hold) on the first strip.

    Speed-up 5, not 20: the companion polls every 0.1 s of wall time, as on a real vehicle; at 20x a poll is 2 s of
    autopilot time."""
    proc, out = _fly_demo_with_home_moved(tmp_path, speedup=5.0)
    assert proc.returncode == 1, out[-4000:]
    assert "window is over: home moved 1 time in it (each at debug level, -v) and is now -1.20 m" in out, out[-4000:]
    assert "0.35 m above the take-off ground" in out and "raise the strip bottoms" in out, out[-4000:]
    assert "stopped by home" in out and "mission NOT complete" in out, out[-4000:]
    assert "landed and disarmed after RTL" in out and "put home back" not in out, out[-4000:]
    assert "SITL profile" not in out and "EKF2" not in out, out[-4000:]  # nothing a simulator needs, unasked
    assert "parameter MPC_Z_V_AUTO_DN restored to 1.5" in out, out[-4000:]  # what it set for the flight is restored
    plan = plan_scan(load_mission(DEMO))
    settle = settle_item_seq(demo_items, plan.settle_waypoint_index)
    flown = [r["mission_item"] for r in read_telemetry_log(tmp_path / "t.jsonl") if r["in_air"]]
    assert max(flown) <= settle, sorted(set(flown))  # no waypoint below 3.5 m above home was flown to
    first_strip = next(it.seq for it in demo_items if it.command == mi.MAV_CMD_NAV_WAYPOINT and it.z < 12.6)
    heights = _true_heights_by_item(tmp_path)
    on_strips = [min(h) for seq, h in heights.items() if seq > first_strip]
    assert on_strips and min(on_strips) > 2.0, heights.keys()  # 3.5 m above a home 1.2 m low, never lower


def test_sim_px4_moves_home_and_later_items_fly_above_the_new_home():
    """In process: 5 s after take-off PX4 moves home 1.5 m down; HOME_POSITION and the relative altitude say so, and
    the next waypoint (6 m above home) is flown 4.5 m above the true ground."""
    nan = float("nan")
    x, y = 375663800, 1269781500
    mission = [mi.MissionItem(0, 6, mi.MAV_CMD_NAV_TAKEOFF, 1, 1, 0.0, 0.0, 0.0, nan, x, y, 6.0),
               mi.MissionItem(1, 6, mi.MAV_CMD_NAV_WAYPOINT, 0, 1, 5.0, 0.5, 0.0, 0.0, x + 900, y, 6.0),
               mi.MissionItem(2, 6, mi.MAV_CMD_NAV_WAYPOINT, 0, 1, 0.0, 0.5, 0.0, 0.0, x, y, 6.0),
               mi.MissionItem(3, 6, mi.MAV_CMD_NAV_LAND, 0, 1, 0.0, 0.0, 0.0, nan, 0, 0, 0.0)]
    v = SimVehicle(VehicleConfig(pose_port=None, target=("127.0.0.1", 9), home_shift_after_takeoff_s=5.0,
                                 home_shift_m=-1.5))
    try:
        v._on_new_mission(mission)
        assert v.arm() is None and v.set_mode(fl.MISSION) is None
        for _ in range(int(120 / 0.02)):
            v.step()
            if v.mission_seq >= 2 and v.home_alt_shift_m != 0.0:
                break
        assert v.home_alt_shift_m == -1.5
        assert v._home_position().altitude == pytest.approx((v.cfg.home.alt_amsl_m - 1.5) * 1000, abs=1)
        for _ in range(int(60 / 0.02)):
            v.step()
            if v.mission_seq >= 3:
                break
        true_height = -float(v.model.state.pos[2])
        assert true_height == pytest.approx(4.5, abs=0.3)  # item 2: 6 m above the moved home
        assert v._global_position().relative_alt / 1000.0 == pytest.approx(true_height + 1.5, abs=0.05)
    finally:
        v.close()


def test_px4_plan_flies_only_what_home_s_largest_move_leaves_clear_while_home_may_move(demo_items):
    """The PX4 plan flies the strips' upper parts in PX4's 120 s window, not a 116 s hover: the watch's settle item is
    the last waypoint of that part, every waypoint up to it is 3.5 m above home or more, the strips' bottoms come
    after it; ArduPilot, which keeps home where it armed, has no window and no settle item."""
    from companion.flight.fly import home_watch_for

    plan = plan_scan(load_mission(DEMO))
    watch = home_watch_for(plan, demo_items, "px4")
    wps = [it for it in demo_items if it.command == mi.MAV_CMD_NAV_WAYPOINT]
    assert watch.window_s == 120.0 and watch.settle_seq == settle_item_seq(demo_items, plan.settle_waypoint_index)
    assert min(it.z for it in wps if it.seq <= watch.settle_seq) == pytest.approx(3.5)
    assert min(it.z for it in wps if it.seq > watch.settle_seq) == pytest.approx(1.546, abs=1e-3)
    steady = plan.for_autopilot("ardupilot")
    cu = home_watch_for(steady, steady.mavlink_items("ardupilot"), "ardupilot")
    assert cu.window_s == 0.0 and cu.settle_seq == -1


def test_a_move_in_the_window_ends_the_scan_only_when_it_brings_what_is_flown_in_it_near_the_ground(demo_items):
    """In the window the vehicle flies the strips' upper parts (3.5 m above home and up): home 1.51 m low (as real
    PX4 SIH left it) would put the strips' bottoms, flown after the window, 0.04 m above the ground, but what is flown
    now 1.99 m above it: nothing ends until the window is over, when the settled home decides. A move beyond any seen
    (-2.8 m) puts the window's own waypoints 0.7 m above the ground: the scan ends at once."""
    plan = plan_scan(load_mission(DEMO))
    settle = settle_item_seq(demo_items, plan.settle_waypoint_index)
    first_strip = next(it.seq for it in demo_items if it.command == mi.MAV_CMD_NAV_WAYPOINT and it.z < 12.6)
    watch = HomeWatch(demo_items, window_s=120.0, settle_seq=settle)
    watch.on_home(30.0)
    watch.on_airborne()
    watch.on_home(28.49)  # -1.51 m at 40 s, the vehicle on its first strip
    assert watch.settling(first_strip, 40.0) and watch.check(first_strip, 40.0) is None
    low = watch.check(first_strip, 124.0)  # the window is over (+3 s slack): the settled home counts
    assert low is not None and low.planned_m == pytest.approx(1.546, abs=1e-3)
    assert low.clearance_m == pytest.approx(0.036, abs=1e-3) and low.seq > settle
    watch.on_home(27.2)  # -2.8 m, still in the window
    worst = watch.check(first_strip, 50.0)
    assert worst is not None and worst.planned_m == pytest.approx(3.5) and worst.seq <= settle
    assert worst.clearance_m == pytest.approx(0.7)
    assert watch.check(settle + 1, 50.0) is not None  # past the settle item early: everything ahead counts

"""The demo mission flown end to end (simulator process + mavsdk + companion.flight) on both autopilot flavours,
judged from the simulator's truth log the way real firmware is judged: on every scan leg the heading within 3 degrees
of wall-facing and the speed along the leg (vertical on these strips) within 15 % of the plan.

The simulator boots with the firmware's defaults (PX4 climbs at 3 m/s, Copter faces the next waypoint); the flight
code must set what ``flight_parameters`` (``companion.mission.autopilot``) lists for the flight and restore it
afterwards. Speed-up 25: about 300 simulated seconds per flight.

Each firmware's demo flight is flown once per module (``px4_flight``, ``ardupilot_flight``) and judged by every test
that needs that flight: the PX4 one also as the plain completed flight with its telemetry log (it was a flight of its
own in tests/test_flight_sitl.py), the ArduCopter one also for the warnings about its default failsafe (a flight of
its own in tests/test_flight_sitl_endings.py); 40-50 s of the suite's time.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass

import numpy as np
import pymap3d
import pytest

from companion.flight import fly_mission_sync
from companion.flight.telemetry_log import read_telemetry_log
from companion.mission import load_mission, plan_scan
from companion.mission.autopilot import flight_parameters
from sim.evaluate_scan import read_truth_log, scan_leg_reports, worst
from tests.sitl import ROOT, SitlVehicle

pytestmark = pytest.mark.sitl


@pytest.fixture(scope="module")
def plan():
    return plan_scan(load_mission(ROOT / "missions/demo-facade.yaml"))


def _until_the_scan_ends(plan, rows: list[dict]) -> list[dict]:
    """The truth rows up to the last scan waypoint: the exit climb goes back up the column the scan ended on (the last
    strip's; PX4's: the first strip's, where the bottom band ends), and its samples on that leg would be judged as the
    leg flown the other way."""
    h, end = plan.home, plan.waypoints[plan.scan_legs[-1][1]]
    n, e, d = pymap3d.geodetic2ned(end.lat, end.lon, h.alt_amsl_m + end.rel_alt_m, h.lat, h.lon, h.alt_amsl_m)
    near = [k for k, r in enumerate(rows) if r.get("in_air", True)
            and math.dist((r["north_m"], r["east_m"], r["down_m"]), (n, e, d)) < 0.5]
    return rows[: near[-1] + 1] if near else rows


@dataclass(frozen=True)
class DemoFlight:
    result: object  # the FlightResult
    truth: list[dict]  # the simulator's truth log
    telemetry: list[dict]  # the companion's telemetry log


def _fly_demo(plan, autopilot: str, folder) -> DemoFlight:
    """The demo mission flown with the flight's defaults (``fly_mission_sync`` as ``companion fly`` calls it)."""
    truth, telemetry = folder / "truth.jsonl", folder / "telemetry.jsonl"
    h = plan.home
    with SitlVehicle(speedup=25, autopilot=autopilot, truth_log=truth,
                     home=f"{h.lat},{h.lon},{h.alt_amsl_m}", log_path=folder / "sim.log") as v:
        # wall seconds, generous: on a loaded 2-core machine the simulator ran at ~3x instead of 25x
        result = fly_mission_sync(plan, v.url, telemetry_log=telemetry, progress=False, handle_signals=False,
                                  flight_timeout_s=600.0, connect_timeout_s=60.0)
    return DemoFlight(result, read_truth_log(truth), read_telemetry_log(telemetry))


@pytest.fixture(scope="module")
def px4_flight(plan, tmp_path_factory) -> DemoFlight:
    return _fly_demo(plan, "px4", tmp_path_factory.mktemp("px4"))


@pytest.fixture(scope="module")
def ardupilot_flight(plan, tmp_path_factory) -> DemoFlight:
    return _fly_demo(plan, "ardupilot", tmp_path_factory.mktemp("ardupilot"))


@pytest.mark.parametrize("autopilot", ["px4", "ardupilot"])
def test_demo_scan_faces_the_wall_at_the_planned_speed(plan, autopilot, request):
    flight = request.getfixturevalue(f"{autopilot}_flight")
    result = flight.result
    assert result.completed and result.landed and result.disarmed, result
    assert set(flight_parameters(plan, autopilot)) <= {c.name for c in result.parameter_changes}, result
    assert result.items_reached == result.items_total == len(plan.mavlink_items(autopilot))
    flown = plan.for_autopilot(autopilot)  # PX4: the strips' bottoms as a pass along the wall after its home window
    reports = scan_leg_reports(flown, _until_the_scan_ends(flown, flight.truth))
    assert len(reports) == len(flown.scan_legs) == plan.estimates.strips + (autopilot == "px4"), reports
    assert all(r.samples > 50 for r in reports), reports
    speed_error, yaw_error = worst(reports)
    if autopilot == "px4":
        _px4_scans_while_home_may_move(flown, flight.truth)
    assert yaw_error < 3.0, [round(r.max_yaw_error_deg, 2) for r in reports]
    assert speed_error < 0.15, [round(r.median_speed_m_s, 3) for r in reports]


def _px4_scans_while_home_may_move(plan, rows: list[dict]) -> None:
    """No idle hover (issue 31): PX4's demo took 450 s from take-off to landing with its 116 s hold above the wall
    (simulator, main cc0293a); flying the strips' upper parts in the window it takes about 340 s. Within 125 s of
    take-off nothing at the standoff is flown lower than the window's floor (3.5 m above home; this simulator keeps
    home still)."""
    air = [r for r in rows if r["in_air"]]
    t0, t1 = air[0]["t_s"], air[-1]["t_s"]
    assert t1 - t0 < 450.0 - 90.0, t1 - t0
    o = plan.frame.origin
    lat, lon = np.array([r["lat"] for r in air]), np.array([r["lon"] for r in air])
    _, out, _ = plan.frame.geodetic_to_facade(lat, lon, np.full_like(lat, o.alt_amsl_m))
    height = np.array([r["alt_amsl_m"] for r in air]) - plan.home.alt_amsl_m
    t = np.array([r["t_s"] for r in air]) - t0
    scan = np.abs(np.asarray(out) - plan.mission.standoff_m) < 0.5
    assert height[scan & (t < 125.0)].min() > plan.estimates.px4_window_floor_m - 0.15
    assert height[scan].min() == pytest.approx(plan.footprint.height_m / 2.0, abs=0.15)  # the band, after it


def test_demo_mission_flies_to_completion(plan, px4_flight):
    """The plain flight (PX4): every item reached, landed and disarmed, the telemetry log complete and facing the
    wall on the scan."""
    result = px4_flight.result
    assert result.completed, result
    assert result.landed and result.disarmed and result.aborted is None
    assert result.items_reached == result.items_total == len(plan.mavlink_items("px4"))
    rows = px4_flight.telemetry
    assert len(rows) == result.telemetry_samples > 100
    keys = {"t_wall", "lat", "lon", "alt_amsl_m", "rel_alt_m", "roll_deg", "pitch_deg", "yaw_deg", "vn_m_s",
            "ve_m_s", "vd_m_s", "mission_item"}
    assert keys <= rows[-1].keys()
    # it really flew the scan: reached the scan's height band and came down again
    assert max(r["rel_alt_m"] for r in rows) > 12.0
    assert rows[-1]["rel_alt_m"] < 0.3 and rows[-1]["armed"] is False
    # and heading faced the wall during the scan (demo wall runs west->east, drone looks north)
    scan = [r for r in rows if r["mission_item"] in range(6, 32) and r["yaw_deg"] is not None]
    assert scan and all(min(abs(r["yaw_deg"]), 360 - abs(r["yaw_deg"])) < 5.0 for r in scan)


def test_default_failsafe_is_reported_as_unsafe_for_the_scan(ardupilot_flight):
    """ArduCopter's defaults (no lost-link action asked for): the completed flight warns that the vehicle keeps
    flying on a lost link and returns below the transit altitude."""
    result = ardupilot_flight.result
    assert result.completed, result
    text = " | ".join(result.warnings)
    assert "FS_GCS_ENABLE=0" in text and "keeps flying" in text
    assert "RTL_ALT is 15 m, below the transit altitude" in text
    assert result.waypoints_total < result.items_total  # progress counts waypoints, not DO items
    assert result.waypoints_reached == result.waypoints_total
    json.dumps([w for w in result.warnings])  # plain strings, fit for a report

"""The TRUE standoff flown on each scan leg (sim/evaluate_scan.flown_standoff), which the demo and the GNSS-bias
bench print: a vehicle that flies its biased estimate along the planned legs is measured where it really was."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from companion.mission import load_mission, plan_scan
from sim.demo import true_standoff
from sim.evaluate_scan import flown_standoff

SMALL_WALL = Path(__file__).parent / "data" / "small-wall.yaml"


def _rows(plan, bias_along_m: float, bias_out_m: float, *, with_estimate: bool = True) -> list[dict]:
    """Truth-log lines of a vehicle flying every scan leg by its estimate (on the plan) while its true position
    is the estimate minus the bias (facade frame)."""
    frame, rows = plan.frame, []
    for i, j in plan.scan_legs:
        a, b = plan.waypoints[i], plan.waypoints[j]
        for s in np.linspace(0.0, 1.0, 40):
            along, up = a.along_m + s * (b.along_m - a.along_m), a.up_m + s * (b.up_m - a.up_m)
            lat, lon, alt = (float(v) for v in frame.facade_to_geodetic(along - bias_along_m, a.out_m - bias_out_m,
                                                                         up))
            row = {"lat": lat, "lon": lon, "alt_amsl_m": alt, "in_air": True}
            if with_estimate:
                nlat, nlon, nalt = (float(v) for v in frame.facade_to_geodetic(along, a.out_m, up))
                row |= {"nav_lat": nlat, "nav_lon": nlon, "nav_alt_amsl_m": nalt}
            rows.append(row)
    return rows


def test_a_biased_vehicle_is_measured_where_it_really_flew():
    # vertical strips only (ArduPilot's plain plan; PX4's ends with a pass along the wall, which an along bias does
    # not take off its leg)
    plan = plan_scan(load_mission(SMALL_WALL)).for_autopilot("ardupilot")
    legs = flown_standoff(plan, _rows(plan, bias_along_m=1.0, bias_out_m=1.5))
    assert len(legs) == len(plan.scan_legs) and all(leg.samples > 20 for leg in legs)
    assert all(leg.median_m == pytest.approx(2.5, abs=1e-3) for leg in legs)
    assert all(leg.worst_error_m == pytest.approx(1.5, abs=1e-3) for leg in legs)
    # matched by the true position alone (an old log), the 1 m along bias puts the vertical legs' samples off
    old = flown_standoff(plan, _rows(plan, bias_along_m=1.0, bias_out_m=1.5, with_estimate=False))
    assert sum(leg.samples for leg in old) == 0


def test_the_demo_summary_of_the_true_standoff(tmp_path):
    plan = plan_scan(load_mission(SMALL_WALL))
    log = tmp_path / "truth.jsonl"
    log.write_text("".join(json.dumps(r) + "\n" for r in _rows(plan, 0.0, -1.5)))
    summary = true_standoff(plan, log)
    assert summary["median_m"] == pytest.approx(5.5, abs=1e-3) and summary["planned_m"] == 4.0
    assert summary["after_first_strip_worst_error_m"] == pytest.approx(1.5, abs=1e-3)
    assert true_standoff(plan, tmp_path / "missing.jsonl") is None

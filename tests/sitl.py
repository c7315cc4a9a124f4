"""Test helper: start the simulated vehicle as its own process on free ports, and stop it again.

Each vehicle gets its own MAVLink port (connect with ``vehicle.url``) and pose port, so SITL tests can run
side by side without clashing with a simulator someone already runs on 14540.
"""

from __future__ import annotations

from pathlib import Path

from companion.mission import load_mission, plan_scan
from sim.process import SimulatorProcess as SitlVehicle
from sim.process import free_port

ROOT = Path(__file__).resolve().parents[1]

__all__ = ["ROOT", "SitlVehicle", "free_port", "small_demo_plan"]


def small_demo_plan():
    """The demo mission shrunk to an 8 m x 6 m wall (4 vertical strips, 18 items, ~80 s simulated): the flight
    tests' short mission, one definition for all of them. It starts its scan at once (``home_settle_s`` 0: no
    2-minute hold for PX4's home to settle, which tests/test_flight_home_watch.py flies with the full demo)."""
    m = load_mission(ROOT / "missions/demo-facade.yaml")
    facade = m.facade.model_copy(update={"end": m.facade.end.model_copy(update={"lon": 126.97809}), "height_m": 6.0})
    takeoff = m.takeoff.model_copy(update={"lon": 126.97805})
    margins = m.margins.model_copy(update={"home_settle_s": 0.0})
    return plan_scan(m.model_copy(update={"facade": facade, "transit_alt_m": 10.0, "takeoff": takeoff,
                                          "margins": margins}))

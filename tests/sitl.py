"""Test helper: start the simulated vehicle as its own process on free ports, and stop it again.

Each vehicle gets its own MAVLink port (connect with ``vehicle.url``) and pose port, so SITL tests can run
side by side without clashing with a simulator someone already runs on 14540.
"""

from __future__ import annotations

from pathlib import Path

from companion.mission import load_mission, plan_scan
from sim.process import SimulatorProcess, free_port
from sim.rig import STILL_HOME

ROOT = Path(__file__).resolve().parents[1]

__all__ = ["ROOT", "STILL_HOME_ARGS", "SitlVehicle", "free_port", "small_demo_plan", "still_home_demo"]

# `companion fly --sitl` arguments for the same still home
STILL_HOME_ARGS = [arg for key, value in STILL_HOME.items()
                   for arg in ("--sim-arg", f"{key.replace('_', '-')}={value}")]


class SitlVehicle(SimulatorProcess):
    """The simulated vehicle for flight tests that are not about home: it keeps home where it armed
    (``home_shift_m=0``), which the tests' missions rely on (``small_demo_plan``, ``still_home_demo``: no hold for
    home to settle). A test about PX4's home passes ``home_shift_m=None`` (the default: PX4 SIH's moves, as real
    SIH makes them) or its own move."""

    def __init__(self, **options):
        super().__init__(**{**STILL_HOME, **options})


def small_demo_plan():
    """The demo mission shrunk to an 8 m x 6 m wall (4 vertical strips, 18 items, ~80 s simulated): the flight
    tests' short mission, one definition for all of them. It starts its scan at once (``home_settle_s`` 0: no
    2-minute hold for PX4's home to settle, which tests/test_flight_home_watch.py flies with the full demo), so fly
    it on a vehicle that keeps home still (``SitlVehicle``'s default)."""
    m = load_mission(ROOT / "missions/demo-facade.yaml")
    facade = m.facade.model_copy(update={"end": m.facade.end.model_copy(update={"lon": 126.97809}), "height_m": 6.0})
    takeoff = m.takeoff.model_copy(update={"lon": 126.97805})
    margins = m.margins.model_copy(update={"home_settle_s": 0.0})
    return plan_scan(m.model_copy(update={"facade": facade, "transit_alt_m": 10.0, "takeoff": takeoff,
                                          "margins": margins}))


def still_home_demo(tmp_path: Path) -> Path:
    """The demo mission as a file that starts its scan at once (``home_settle_s`` 0), for ``companion fly --sitl``
    tests that are not about home: fly it with ``STILL_HOME_ARGS``."""
    m = load_mission(ROOT / "missions/demo-facade.yaml")
    text = (ROOT / "missions/demo-facade.yaml").read_text()
    assert "home_settle_s" not in text and m.margins.home_settle_s > 0
    path = tmp_path / "demo-facade-at-once.yaml"
    path.write_text(text.replace("margins: {", "margins: {home_settle_s: 0, ", 1))
    assert load_mission(path).margins.home_settle_s == 0
    return path

"""Test helper: start the simulated vehicle as its own process on free ports, and stop it again.

Each vehicle gets its own MAVLink port (connect with ``vehicle.url``) and pose port, so SITL tests can run
side by side without clashing with a simulator someone already runs on 14540.
"""

from __future__ import annotations

from companion.flight.simulator import ROOT, free_port
from companion.flight.simulator import SimulatorProcess as SitlVehicle

__all__ = ["ROOT", "SitlVehicle", "free_port"]

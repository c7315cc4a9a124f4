"""Test helper: start the simulated vehicle as its own process on free ports, and stop it again.

Each vehicle gets its own MAVLink port (connect with ``vehicle.url``) and pose port, so SITL tests can run
side by side without clashing with a simulator someone already runs on 14540.
"""

from __future__ import annotations

from pathlib import Path

from sim.process import SimulatorProcess as SitlVehicle
from sim.process import free_port

ROOT = Path(__file__).resolve().parents[1]

__all__ = ["ROOT", "SitlVehicle", "free_port"]

"""Flying a planned scan through mavsdk: connect, health, upload + verify, arm, start, supervise, land."""

from companion.flight.fly import FlightResult, LinkLoss, fly_mission, fly_mission_sync, mission_items_for
from companion.flight.telemetry_log import read_telemetry_log

__all__ = ["FlightResult", "LinkLoss", "fly_mission", "fly_mission_sync", "mission_items_for",
           "read_telemetry_log"]

"""The supervision limits of one flight, with their defaults in one place: ``fly_mission``'s keywords and
``companion fly``'s options both read them from here, so the library and the command cannot drift apart."""

from __future__ import annotations

from dataclasses import dataclass

from companion.flight.connection import DEFAULT_HEALTH_TIMEOUT_S


@dataclass(frozen=True)
class FlightLimits:
    connect_url: str = "udp://:14540"  # PX4 SITL; ArduPilot SITL: tcpout://127.0.0.1:5760
    connect_timeout_s: float = 10.0  # to the first heartbeat
    health_timeout_s: float = DEFAULT_HEALTH_TIMEOUT_S  # GPS / home / pre-arm (ArduCopter's EKF: 35-40 s)
    link_loss_s: float = 3.0  # without telemetry: a loss (counted)
    link_dead_s: float = 60.0  # without telemetry: supervision ends as failed (the vehicle's failsafe flies on)
    flight_timeout_s: float = 1800.0  # RTL when the flight takes longer
    telemetry_rate_hz: float = 10.0
    end_action: str = "rtl"  # when the mission ends in the air: "rtl" or "land"
    stop_wait_s: float = 180.0  # after a stop request (RTL): the longest wait for landed + disarmed


FLIGHT_DEFAULTS = FlightLimits()

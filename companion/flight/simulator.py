"""Recognise PX4's SIH simulator from its parameters, and tell its estimator the simulator's sensor noise.

Why: PX4 SIH (SITL) adds white noise to its IMU 3.5x (accelerometer) and 8x (gyro) what EKF2's defaults assume.
With those defaults EKF2's estimate wandered 0.3-0.6 m off its setpoint out from the wall and its vertical velocity
by up to 0.25 m/s off its own height track (docs/FLIGHT.md), which a real vehicle (whose EKF2 tuning matches its
IMU) does not share. So on SIH only, and only for the flight (restored after, logged both ways like every flight
parameter), EKF2 is told the noise SIH injects. A real vehicle's estimator is never touched: it is recognised by
its IMU's device type (companion.mission.firmware.px4_sih_verdict); a vehicle whose markers cannot be read is
treated as real.
"""

from __future__ import annotations

import logging

from companion.errors import CompanionError
from companion.flight.parameters import read_parameter
from companion.mission.firmware import PX4_SIH_MARKERS, px4_sih_verdict, simulator_estimator_parameters

log = logging.getLogger(__name__)


async def read_sih_markers(param_plugin) -> dict[str, float | None]:
    """PX4's SIH markers as the vehicle reports them; None for one it does not have (e.g. SYS_HITL off a board)."""
    markers: dict[str, float | None] = {}
    for name in PX4_SIH_MARKERS:
        try:
            markers[name] = (await read_parameter(param_plugin, name)).value
        except CompanionError:
            markers[name] = None
    return markers


async def simulator_parameters(vehicle) -> dict[str, float]:
    """The estimator parameters to set for this flight: SIH's sensor noise on PX4 SIH, nothing on anything else."""
    if vehicle.autopilot != "px4":
        return {}
    verdict = px4_sih_verdict(await read_sih_markers(vehicle.param))
    params = simulator_estimator_parameters(verdict)
    if params:
        log.warning("this vehicle is PX4's SIH simulator (%s): EKF2 is told SIH's sensor noise for this flight "
                    "only (%s; SITL only: a real vehicle's estimator is never changed)", verdict.reason,
                    ", ".join(f"{k} {v:g}" for k, v in params.items()))
    else:
        log.info("estimator left as it is: %s", verdict.reason)
    return params

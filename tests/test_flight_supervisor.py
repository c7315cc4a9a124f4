"""Flight supervision edge case without a simulator: a short mission that flew and landed while the companion was
still waiting for the start command's acknowledgement (seen on a 20 % lossy SITL link at speed-up 20)."""

from __future__ import annotations

import asyncio
import time
from types import SimpleNamespace

from companion.flight.fly import _Supervisor
from companion.mission import items as mi


class _Recorder:
    """What the supervisor reads of the telemetry recorder: the vehicle is already down, disarmed, at the end."""

    def __init__(self, total: int, was_in_air: bool):
        self.state = {"mission_item": total, "armed": False, "in_air": False}
        self.was_in_air = was_in_air
        self.last_sample_wall = time.monotonic()


class _Vehicle:
    def __init__(self):
        self.rtl_commands = 0

        async def noop():
            return None

        async def rtl():
            self.rtl_commands += 1

        self.mission = SimpleNamespace(pause_mission=noop)
        self.action = SimpleNamespace(return_to_launch=rtl, land=noop)


def _run(was_in_air: bool) -> tuple[str | None, _Vehicle]:
    items = [SimpleNamespace(command=mi.MAV_CMD_NAV_WAYPOINT)] * 5 + [SimpleNamespace(command=mi.MAV_CMD_NAV_LAND)]
    vehicle = _Vehicle()
    rec = _Recorder(len(items), was_in_air)
    sup = _Supervisor(vehicle, items, rec, link_loss_s=3.0, flight_timeout_s=1.0, end_action="land",
                      progress=False)

    return asyncio.run(sup.run()), vehicle


def test_flight_that_ended_before_supervision_started_is_complete():
    reason, vehicle = _run(was_in_air=True)
    assert reason is None and vehicle.rtl_commands == 0


def test_vehicle_never_seen_airborne_is_not_taken_for_a_finished_flight():
    # without any sign of flight, a disarmed vehicle on the ground is still waiting to go: the timeout decides
    reason, vehicle = _run(was_in_air=False)
    assert reason == "timeout" and vehicle.rtl_commands == 1

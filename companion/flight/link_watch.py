"""Make the firmware's lost-link failsafe watch the companion's own heartbeats, for a flight with
``--lost-link-action``.

Which heartbeats each firmware's lost-link failsafe counts (read from source):

* ArduCopter (``Copter::failsafe_gcs_check``, ``GCS_MAVLINK::handle_heartbeat``): only HEARTBEATs whose *source
  system id* is the GCS id, MAV_GCS_SYSID (SYSID_MYGCS before 4.7; default 255), or within MAV_GCS_SYSID ..
  MAV_GCS_SYSID_HI when that is not below it (HI defaults to 0: off). The failsafe starts only once such a
  heartbeat was seen, and fires FS_GCS_TIMEOUT seconds (default 5) after the last. mavsdk sends the companion's
  heartbeats from system 245 (its ground-station default), so with the shipped 255 the failsafe never armed: on
  real ArduCopter 4.7 SITL the vehicle flew on after ``kill -9`` of the companion; with MAV_GCS_SYSID=245 it
  switched to RTL 4.6 s after the kill (issue 31).
* PX4 (``MavlinkReceiver::handle_message_heartbeat``, ``Commander::dataLinkCheck``): HEARTBEATs of type
  MAV_TYPE_GCS from *any* system id (mavsdk sends the companion's as MAV_TYPE_GCS), alive for 2.5 s each
  (``HEARTBEAT_TIMEOUT_US``); the loss comes COM_DL_LOSS_T (default 10 s) after that, and is ignored in Mission mode
  when COM_DLL_EXCEPT has bit 0 set, in the other auto modes (Hold, Return...) with bit 1. So PX4 needs no id; the
  exceptions are cleared for the flight. A second ground station on PX4 keeps its link alive: there a dead
  companion is a lost link only when it was the one ground station.

Why the GCS id is set for the flight rather than mavsdk made to send as 255: a companion computer usually flies
beside a real ground station, which is 255 (QGroundControl, Mission Planner). Two systems with one id break
MAVLink routing and the mission and parameter protocols (each takes the other's replies), and the failsafe would
then count the ground station's heartbeats too, so a dead companion, the one that supervises a scan a few metres
from a wall, would never be a lost link. Set for the flight (journaled and restored like every other parameter),
the failsafe watches exactly the companion. The cost, said in docs/FLIGHT.md: while the flight lasts, ArduPilot
takes RC override and MANUAL_CONTROL (a joystick on the ground station) only from the companion's id; the
transmitter, mode changes and commands from the ground station are not affected.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Sequence

from companion.errors import CompanionError
from companion.flight.connection import Vehicle
from companion.flight.parameters import read_parameter
from companion.mission.autopilot import autopilot_for, homes
from companion.mission.autopilot.base import LinkWatch

log = logging.getLogger(__name__)

# every firmware's GCS id parameters: a change of one of them waits for a counted heartbeat before arming
GCS_ID_PARAMS = frozenset(name for home in homes() for name in home.link_watch.gcs_id_params)
HEARTBEAT_PERIOD_WAIT_S = 1.5  # mavsdk sends a heartbeat every second: one has been counted after this


def watched_by_gcs_id(companion_id: int, gcs_id: int, gcs_id_hi: int | None) -> bool:
    """True when a firmware that counts one GCS id (or a range) counts heartbeats from ``companion_id`` (ArduPilot:
    GCS::sysid_is_gcs)."""
    if gcs_id_hi is not None and gcs_id_hi >= gcs_id:
        return gcs_id <= companion_id <= gcs_id_hi
    return companion_id == gcs_id


async def _first_parameter(vehicle: Vehicle, names: tuple[str, ...]):
    problems = []
    for name in names:
        try:
            return await read_parameter(vehicle.param, name)
        except CompanionError as exc:
            problems.append(exc.problem)
    raise CompanionError("cannot read the GCS system id the lost-link failsafe watches: " + "; ".join(problems),
                         f"check the link; set {' or '.join(names)} (whichever the firmware has) to "
                         f"{vehicle.own_system_id} by hand, or fly without --lost-link-action")


async def _optional_parameter(vehicle: Vehicle, name: str):
    """``name``'s value, or None when the firmware has no such parameter. Asked once: real ArduCopter V4.7.0-dev
    has no MAV_GCS_SYSID_HI and leaves the read unanswered, which three link attempts made a 10 s wait and three
    warnings before every flight."""
    try:
        return await read_parameter(vehicle.param, name, attempts=1)
    except CompanionError:
        log.info("%s: no answer from the vehicle; taken as a parameter this firmware does not have", name)
        return None


async def link_watch_overrides(vehicle: Vehicle) -> dict[str, float]:
    """The parameters that make the lost-link failsafe count the companion's heartbeats (empty: it does already),
    by the firmware's rule (its home's ``link_watch``)."""
    rule = autopilot_for(vehicle.autopilot).link_watch
    out: dict[str, float] = {}
    if rule.gcs_id_params:
        out.update(await _gcs_id_override(vehicle, rule))
    if rule.exception_param is not None:
        out.update(await _exception_override(vehicle, rule))
    return out


async def _gcs_id_override(vehicle: Vehicle, rule: LinkWatch) -> dict[str, float]:
    gcs = await _first_parameter(vehicle, rule.gcs_id_params)
    hi = await _optional_parameter(vehicle, rule.gcs_id_hi_param) if rule.gcs_id_hi_param else None
    me = vehicle.own_system_id
    if watched_by_gcs_id(me, int(gcs.value), int(hi.value) if hi is not None else None):
        log.info("the lost-link failsafe already watches the companion's heartbeats (system %d)", me)
        return {}
    log.info("the lost-link failsafe watches heartbeats from system %s=%s only; the companion sends from %d: "
             "%s set to %d for this flight", gcs.name, gcs.text(), me, gcs.name, me)
    return {gcs.name: float(me)}


async def _exception_override(vehicle: Vehicle, rule: LinkWatch) -> dict[str, float]:
    exceptions = await _optional_parameter(vehicle, rule.exception_param)
    if exceptions is None or not int(exceptions.value) & rule.exception_bits:
        return {}
    cleared = int(exceptions.value) & ~rule.exception_bits
    log.info("%s=%s ignores a lost link in Mission/auto modes: %d for this flight", rule.exception_param,
             exceptions.text(), cleared)
    return {rule.exception_param: float(cleared)}


async def until_heartbeat_counted(applied: Sequence) -> None:
    """After the GCS id was changed for the flight, wait one heartbeat period before arming. Why: ArduCopter's GCS
    failsafe keeps one "last seen" time; when the companion's heartbeats were not counted for a while (the id put
    back to 255 by the restore of a killed run, then set again), the failsafe is on, without action while
    disarmed, until the next counted heartbeat clears it; Copter refuses to arm in it ("GCS failsafe on")."""
    if any(change.name in GCS_ID_PARAMS for change in applied):
        await asyncio.sleep(HEARTBEAT_PERIOD_WAIT_S)

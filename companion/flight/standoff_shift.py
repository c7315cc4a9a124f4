"""Move the rest of a scan across the wall in flight: the vehicle side of a standoff correction (issue 26).

Why this sequence, the same on PX4 and ArduCopter: what an upload in flight does to the running mission differs by
firmware (ArduCopter resets its current item on every upload; PX4 keeps it only for an identical mission) and is
not something to rely on while 2.5 m from a wall. So the companion does only what both firmwares document and the
flight code already does on the ground:

  1. pause: ``pause_mission`` (PX4 Hold, ArduCopter BRAKE through mavsdk), as a Ctrl-C does;
  2. upload the mission with every positional item at the standoff from the item the vehicle was flying to on
     moved by the correction along the wall's out axis (same count, seq, commands and altitudes: only lat/lon
     change; ArduPilot's seq-0 home placeholder is never moved) and verify it by download, as before take-off;
  3. set the current item to the one the vehicle was flying to (from the DO/CONDITION items just before it, so
     ArduCopter's CONDITION_YAW and a speed change there run again) and read it back from MISSION_CURRENT (that
     item, or the waypoint itself: ArduPilot reports its current NAV command);
  4. resume the mission (``start_mission``: PX4 Mission mode, ArduCopter AUTO, which resumes at the current
     command with MIS_RESTART 0, the default);
  5. send the scan's speeds again as commands (DO_CHANGE_SPEED of each type in force at that item): a mode change
     can drop a mission's speed (ArduCopter's AUTO starts from WPNAV_SPEED*), and the simulator drops the climb and
     descent overrides on an upload.

Any failure raises CompanionError: the supervisor then ends the flight (RTL) rather than resume an unverified path.
"""

from __future__ import annotations

import asyncio
import dataclasses
import logging
from collections.abc import Sequence

import pymap3d

from companion.errors import CompanionError
from companion.flight.start import set_current_item
from companion.flight.status_texts import StatusTexts
from companion.flight.upload import upload_and_verify
from companion.mission import items as mi

log = logging.getLogger(__name__)

NAV_COMMANDS = {mi.MAV_CMD_NAV_WAYPOINT, mi.MAV_CMD_NAV_TAKEOFF, mi.MAV_CMD_NAV_LAND, mi.MAV_CMD_NAV_RETURN_TO_LAUNCH}
PAUSE_SETTLE_S = 0.5  # let the vehicle brake before the upload (wall seconds)


def shift_item(item: mi.MissionItem, out_enu: tuple[float, float], shift_m: float) -> mi.MissionItem:
    """``item`` moved ``shift_m`` along the horizontal unit vector ``out_enu`` (east, north); altitude unchanged."""
    lat, lon, _ = pymap3d.enu2geodetic(shift_m * out_enu[0], shift_m * out_enu[1], 0.0, item.lat, item.lon, 0.0)
    return dataclasses.replace(item, x=int(round(float(lat) * 1e7)), y=int(round(float(lon) * 1e7)))


def shifted_items(items: Sequence[mi.MissionItem], movable: frozenset[int], from_seq: int,
                  out_enu: tuple[float, float], shift_m: float) -> list[mi.MissionItem]:
    """The mission with the movable items from ``from_seq`` on moved ``shift_m`` out (negative: towards the wall)."""
    return [shift_item(it, out_enu, shift_m) if it.seq in movable and it.seq >= from_seq else it for it in items]


def resume_seq(items: Sequence[mi.MissionItem], target_seq: int, first_seq: int) -> int:
    """Where to resume for the vehicle to fly to ``target_seq``: the first of the DO/CONDITION items directly
    before it (they belong to that waypoint: ArduCopter's CONDITION_YAW, a speed change)."""
    seq = target_seq
    while seq - 1 > first_seq and items[seq - 1].command not in NAV_COMMANDS:
        seq -= 1
    return seq


def speeds_in_force(items: Sequence[mi.MissionItem], seq: int) -> list[tuple[float, float]]:
    """(speed type, m/s) of the last DO_CHANGE_SPEED of each type before ``seq``."""
    last: dict[float, float] = {}
    for it in items[:seq]:
        if it.command == mi.MAV_CMD_DO_CHANGE_SPEED and it.param2 > 0:
            last[it.param1] = it.param2
    return sorted(last.items())


async def fly_moved_scan(vehicle, items: Sequence[mi.MissionItem], target_seq: int, first_seq: int) -> None:
    """Pause, upload + verify ``items`` (the moved mission), resume flying to ``target_seq``; raises on failure."""
    try:
        await vehicle.mission.pause_mission()
    except Exception as exc:
        raise CompanionError(f"could not pause the mission to move the scan ({exc})",
                             "check the link; the flight ends rather than fly on unmeasured") from exc
    await asyncio.sleep(PAUSE_SETTLE_S)
    async with StatusTexts(vehicle.telemetry) as texts:
        await upload_and_verify(vehicle.mission, items, vehicle.autopilot, texts=texts)
    resume = resume_seq(items, target_seq, first_seq)
    # ArduPilot reports its current NAV command in MISSION_CURRENT: set to a DO item, it says the waypoint after it
    seen = await set_current_item(vehicle, resume, also=(target_seq,))
    if seen not in (resume, target_seq):
        raise CompanionError(f"the vehicle did not confirm item {resume} as current after moving the scan "
                             f"(MISSION_CURRENT: {seen})", "the flight ends: check the link and the vehicle")
    try:
        await vehicle.mission.start_mission()
    except Exception as exc:
        raise CompanionError(f"the vehicle did not resume the moved scan ({exc})",
                             "the flight ends: take control from the ground station if it does not return") from exc
    for speed_type, speed in speeds_in_force(items, target_seq):
        try:
            await vehicle.command_long(mi.MAV_CMD_DO_CHANGE_SPEED, speed_type, speed, -1.0)
        except Exception as exc:  # said: the scan flies on at the firmware's own speed
            log.warning("could not set the scan speed again after moving the scan (%s)", exc)
    log.info("resumed the moved scan at item %d (flying to item %d)", resume, target_seq)

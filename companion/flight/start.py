"""Getting a verified mission started the way each firmware needs it: a mode that can arm, the first item as the
current one (read back), arming with the firmware's own refusal text.

Why each step (real firmware in SITL, shared/notes/real-firmware.md):
  * PX4 does not arm in Return mode, nor in Mission mode without a valid mission; ArduCopter refuses in BRAKE (what
    mavsdk's ``arm()`` switches to first). So the companion selects PX4 Hold (AUTO_LOITER) or Copter GUIDED itself.
  * PX4 keeps its current item when the uploaded mission equals the stored one, even across a restart, and the
    ``current`` flag on item 0 does not reset it: a re-fly after an interrupted flight would resume mid-scan,
    skipping takeoff, transit altitude, gimbal and speed items. So the first item is set explicitly and read back
    from MISSION_CURRENT before the start; a vehicle that does not confirm it is not started.
  * A refused arm is only useful with the firmware's reason ("PreArm: ..."), which arrives as STATUSTEXT.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
from collections.abc import Callable, Collection

from companion.errors import CompanionError
from companion.flight.stream_listener import StreamListener
from companion.mission.autopilot import Autopilot, autopilot_for

log = logging.getLogger(__name__)

MAV_CMD_DO_SET_MODE = 176
MAV_CMD_DO_SET_MISSION_CURRENT = 224
MAV_CMD_REQUEST_MESSAGE = 512
MSG_ID_MISSION_CURRENT = 42
MAV_MODE_FLAG_CUSTOM_MODE_ENABLED = 1
MAV_RESULT_ACCEPTED = 0


def first_item_seq(autopilot: str | Autopilot) -> int:
    """The first item of the mission proper (ArduPilot keeps home at seq 0: its first mission item is 1)."""
    return autopilot_for(autopilot).first_item_seq


async def select_arming_mode(vehicle) -> bool:
    """Switch to the firmware's mode from which arming works; True when the vehicle accepted it."""
    mode = autopilot_for(vehicle.autopilot).arming_mode
    try:
        result = await vehicle.command_long(MAV_CMD_DO_SET_MODE, MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, *mode.custom_mode)
    except Exception as exc:  # reported by the caller's health wait / arming if it matters
        log.debug("mode switch to %s failed: %s", mode.name, exc)
        return False
    if result != MAV_RESULT_ACCEPTED:
        log.debug("mode switch to %s refused (MAV_RESULT %d)", mode.name, result)
    return result == MAV_RESULT_ACCEPTED


async def read_mission_current(vehicle, timeout_s: float = 3.0,
                               want: int | Collection[int] | None = None) -> int | None:
    """The seq of the vehicle's next MISSION_CURRENT (or the first one equal to ``want``, or in it) within
    ``timeout_s``."""
    seen: list[int] = []
    wanted = None if want is None else ({want} if isinstance(want, int) else set(want))

    async def _watch():
        async for msg in vehicle.direct.subscribe_message("MISSION_CURRENT"):
            with contextlib.suppress(ValueError, TypeError, KeyError):
                seen.append(int(json.loads(msg.fields_json)["seq"]))
                if wanted is None or seen[-1] in wanted:
                    return

    async def _ask():  # MISSION_CURRENT may stream slowly (ArduPilot: only once requested): ask for one now
        with contextlib.suppress(Exception):
            await vehicle.command_long(MAV_CMD_REQUEST_MESSAGE, MSG_ID_MISSION_CURRENT)

    watcher = asyncio.create_task(_watch())
    asker = asyncio.create_task(_ask())
    try:
        await asyncio.wait_for(watcher, timeout_s)
    except TimeoutError:
        pass
    finally:
        asker.cancel()
        with contextlib.suppress(asyncio.CancelledError, Exception):
            await asker
    return seen[-1] if seen else None


async def start_from_first_item(vehicle, attempts: int = 3, timeout_s: float = 3.0) -> int:
    """Make the first mission item the current one and confirm it from MISSION_CURRENT; raises otherwise."""
    first = first_item_seq(vehicle.autopilot)
    seen = await set_current_item(vehicle, first, attempts, timeout_s)
    if seen == first:
        log.info("current mission item set to %d (the first) and confirmed by the vehicle", first)
        return first
    what = "no MISSION_CURRENT at all" if seen is None else f"MISSION_CURRENT still says item {seen}"
    raise CompanionError(
        f"the vehicle did not confirm the first mission item as current ({what}): it could resume mid-mission",
        "not starting; check the link and that the vehicle accepts MISSION_SET_CURRENT, then retry")


async def set_current_item(vehicle, seq: int, attempts: int = 3, timeout_s: float = 3.0,
                           also: Collection[int] = ()) -> int | None:
    """Ask for ``seq`` as the current mission item until MISSION_CURRENT says it (or one of ``also``); returns the
    last seq seen (None: no MISSION_CURRENT at all). Also used to resume a moved scan at the item it was flying to."""
    seen = None
    accept = {seq, *also}
    for _ in range(attempts):
        try:
            await vehicle.mission.set_current_mission_item(seq)
        except Exception as exc:  # older stacks: the command form
            log.debug("set_current_mission_item failed (%s); sending DO_SET_MISSION_CURRENT", exc)
            with contextlib.suppress(Exception):
                await vehicle.command_long(MAV_CMD_DO_SET_MISSION_CURRENT, seq)
        seen = await read_mission_current(vehicle, timeout_s, want=accept)
        if seen in accept:
            return seen
    return seen


async def arm_with_reason(vehicle, texts_since: Callable[[int], list[str]], text_count: Callable[[], int],
                          attempts: int = 3, reason_wait_s: float = 1.5) -> None:
    """Arm; a refusal raises with the firmware's own STATUSTEXTs (pre-arm failures) quoted. Only a timed-out
    command is tried again: a refusal will not change by repeating it."""
    for attempt in range(1, attempts + 1):
        mark = text_count()
        try:
            await vehicle.action.arm()
            return
        except Exception as exc:
            result = getattr(getattr(exc, "result", None), "name", str(exc))
            if result in ("TIMEOUT", "CONNECTION_ERROR") and attempt < attempts:
                log.warning("arming timed out (attempt %d of %d), retrying", attempt, attempts)
                continue
            await asyncio.sleep(reason_wait_s)  # the STATUSTEXT may trail the COMMAND_ACK
            said = texts_since(mark)
            reason = "; ".join(said) if said else "the vehicle gave no reason (no STATUSTEXT)"
            raise CompanionError(f"the vehicle refused to arm ({result}): {reason}",
                                 "fix what the vehicle reports (its pre-arm checks), then retry") from exc


_LINK_RESULTS = ("TIMEOUT", "CONNECTION_ERROR")
MAV_CMD_MISSION_START = 300
MAV_RESULT_NAMES = {0: "ACCEPTED", 1: "TEMPORARILY_REJECTED", 2: "DENIED", 3: "UNSUPPORTED", 4: "FAILED",
                    5: "IN_PROGRESS", 6: "CANCELLED"}


class _CommandAcks(StreamListener):
    """The COMMAND_ACKs of mode switches and mission starts, read beside mavsdk's own handling: mavsdk reports a
    refused start as DENIED or UNKNOWN (ArduCopter's MAV_RESULT_FAILED), the vehicle's own result says which."""

    def __init__(self, vehicle):
        self.direct = getattr(vehicle, "direct", None)
        self.results: list[str] = []

    def _can_listen(self) -> bool:
        return self.direct is not None

    async def _listen(self) -> None:
        async for msg in self.direct.subscribe_message("COMMAND_ACK"):
            with contextlib.suppress(ValueError, TypeError, KeyError):
                f = json.loads(msg.fields_json)
                if int(f["command"]) in (MAV_CMD_DO_SET_MODE, MAV_CMD_MISSION_START):
                    name = "DO_SET_MODE" if int(f["command"]) == MAV_CMD_DO_SET_MODE else "MISSION_START"
                    result = int(f["result"])
                    self.results.append(f"{name} {MAV_RESULT_NAMES.get(result, str(result))}")


async def start_with_reason(vehicle, texts_since: Callable[[int], list[str]], text_count: Callable[[], int],
                            attempts: int = 3, reason_wait_s: float = 1.5) -> None:
    """Start the mission (mavsdk: a mode switch to Mission/AUTO); a refusal raises with the command's result and
    the firmware's own STATUSTEXTs quoted (PX4: "Switching to Mission is currently not available"; ArduCopter: "Auto:
    Missing Takeoff Cmd", "Mode change to AUTO failed: init failed"). Only a timed-out command is tried again."""
    async with _CommandAcks(vehicle) as acks:
        for attempt in range(1, attempts + 1):
            mark, acked = text_count(), len(acks.results)
            try:
                await vehicle.mission.start_mission()
                return
            except Exception as exc:
                result = getattr(getattr(exc, "result", None), "name", str(exc))
                if result in _LINK_RESULTS and attempt < attempts:
                    log.warning("mission start timed out (attempt %d of %d), retrying", attempt, attempts)
                    await asyncio.sleep(0.5)
                    continue
                if result in _LINK_RESULTS:
                    raise CompanionError(f"the mission start got no answer ({result}, {attempts} attempts)",
                                         "check the link to the vehicle, then retry") from exc
                await asyncio.sleep(reason_wait_s)  # the STATUSTEXT may trail the COMMAND_ACK
                said = texts_since(mark)
                reason = "it said: " + "; ".join(said) if said else "it gave no reason (no STATUSTEXT)"
                answered = acks.results[acked:]
                how = f"{answered[-1]}; mavsdk: {result}" if answered else result
                raise CompanionError(f"the vehicle refused the mission start ({how}); {reason}",
                                     "fix what the vehicle reports (e.g. a mission that starts with a takeoff, "
                                     "inside its geofence; check its feasibility on the ground station), then "
                                     "retry") from exc

"""Mission upload through the raw mission protocol, then download and compare (verify).

MissionRaw, not the high-level Mission plugin: it keeps the planner's exact MISSION_ITEM_INTs (gimbal, speed,
yaw commands, ArduPilot's seq-0 home placeholder) and its download works on both PX4 and ArduPilot.
"""

from __future__ import annotations

import logging
import re
from collections.abc import Sequence

from mavsdk.asyncio.plugins.mission_raw import MissionItem as RawItem
from mavsdk.asyncio.plugins.mission_raw import MissionRawError

from companion.errors import CompanionError
from companion.flight.status_texts import StatusTexts, quote
from companion.flight.stored_form import mismatches
from companion.mission.autopilot import Autopilot, autopilot_for
from companion.mission.items import MissionItem

log = logging.getLogger(__name__)

_UPLOAD_FIXES = {
    "TOO_MANY_MISSION_ITEMS": "the vehicle has no room for this many items: shorten the scan or split it",
    "UNSUPPORTED": "the vehicle refused a command or frame it does not support: check the plan's item list "
                   "against the autopilot (see docs/FLIGHT.md)",
    "INVALID_ARGUMENT": "an item has a parameter value the vehicle refuses: plan for this autopilot "
                        "(plan.mavlink_items('ardupilot') sends no NaN where ArduPilot refuses it)",
    "DENIED": "the vehicle refused the upload (busy or armed in a mission?): land, disarm and retry",
    "TIMEOUT": "the vehicle stopped answering during the upload: check the link quality and retry",
    "TRANSFER_CANCELLED": "the vehicle gave up on the transfer (items lost on the link): check the link quality and "
                          "retry",
    "PROTOCOL_ERROR": "the vehicle answered out of protocol: check for a second ground station on the link",
}


def to_raw(items: Sequence[MissionItem]) -> list[RawItem]:
    return [RawItem(it.seq, it.frame, it.command, 1 if i == 0 else 0, it.autocontinue, float(it.param1),
                    float(it.param2), float(it.param3), float(it.param4), int(it.x), int(it.y), float(it.z),
                    it.mission_type) for i, it in enumerate(items)]


def from_raw(raw: Sequence[RawItem]) -> list[MissionItem]:
    return [MissionItem(r.seq, r.frame, r.command, r.current, r.autocontinue, r.param1, r.param2, r.param3,
                        r.param4, r.x, r.y, r.z, r.mission_type) for r in raw]


def compare_missions(sent: Sequence[MissionItem], got: Sequence[MissionItem],
                     autopilot: str | Autopilot) -> list[str]:
    """Differences in meaning between what was uploaded and what the vehicle holds (empty list: the same mission).

    Each firmware stores some fields in its own form (``companion.flight.stored_form``, checked against real
    downloads); those forms are not differences. Another command, coordinate, order or count is."""
    autopilot = autopilot_for(autopilot)
    problems = []
    if len(sent) != len(got):
        problems.append(f"the vehicle holds {len(got)} items, {len(sent)} were uploaded")
    for s, g in zip(sent, got, strict=False):
        problems += [m.describe() for m in mismatches(s, g, autopilot)]
    return problems


def _culprit(items: Sequence[MissionItem], autopilot: str | Autopilot, result: str) -> str:
    """Which item the refusal is about. mavsdk reports only the result, so name the item the firmware's own
    per-command check refuses (ArduPilot: NaN/inf params), when there is one."""
    if result != "INVALID_ARGUMENT":
        return ""
    refusal = autopilot_for(autopilot).param_refusal(items)
    if refusal is None:
        return ": mavsdk does not say which item; no item holds a value this firmware is known to refuse"
    return ": " + refusal.describe()


_LINK_FAILURES = ("TIMEOUT", "TRANSFER_CANCELLED")


async def _with_retries(what: str, coro_fn, attempts: int):
    """Run a mission transfer, starting it again after a link failure: mavsdk gives up on an item after a few lost
    round trips (TIMEOUT), and the vehicle gives up on a transfer whose items stop arriving (it answers
    MAV_MISSION_OPERATION_CANCELLED, which mavsdk reports as TRANSFER_CANCELLED; the companion never cancels its own
    transfers); a 20 % lossy link reaches either now and then. A refusal (any other result) is final."""
    for attempt in range(1, attempts + 1):
        try:
            return await coro_fn()
        except MissionRawError as exc:
            if getattr(exc.result, "name", "") not in _LINK_FAILURES or attempt == attempts:
                raise
            log.warning("%s failed on the link (%s, attempt %d of %d), starting it again", what, exc.result.name,
                        attempt, attempts)
    return None


_CAPACITY_TEXT = re.compile(r"Only (\d+) items are supported")


def _refusal_fix(name: str, said: list[str], count: int) -> str:
    """The fix for a refused upload, from what the vehicle said when it says more than the result code: ArduPilot's
    "Only N items are supported" gives its capacity, and N = 0 means its mission storage is not initialised yet
    (real ArduCopter SITL right after boot), which no shorter mission fixes."""
    for text in said:
        match = _CAPACITY_TEXT.search(text)
        if match and int(match.group(1)) == 0:
            return ("the vehicle is still starting up (its mission storage is not initialised, so it takes no "
                    "items): wait until it has finished booting, then retry")
        if match:
            return (f"the vehicle takes at most {match.group(1)} items and this mission has {count}: shorten the "
                    "scan or split it")
    return _UPLOAD_FIXES.get(name, "check the vehicle's messages and the plan")


async def upload_and_verify(mission_plugin, items: Sequence[MissionItem], autopilot: str | Autopilot,
                            attempts: int = 4,
                            texts: StatusTexts | None = None) -> None:
    """Upload ``items``, download them again and compare; raises CompanionError naming the problem.

    ``texts``: the vehicle's STATUSTEXTs being collected; a refusal then quotes what the vehicle said about it."""
    if not items:
        raise CompanionError("the mission has no items", "plan the scan first (companion plan ...)")
    seqs = [it.seq for it in items]
    if seqs != list(range(len(items))):
        raise CompanionError("mission items are not numbered 0..N-1 in order", "renumber the items (seq)")
    raw = to_raw(items)
    mark = texts.mark() if texts is not None else 0
    try:
        await _with_retries("mission upload", lambda: mission_plugin.upload_mission(raw), attempts)
    except MissionRawError as exc:
        name = getattr(exc.result, "name", str(exc.result))
        if name in _LINK_FAILURES:
            raise CompanionError(f"mission upload failed: the link lost too much ({name}, "
                                 f"{attempts} attempts, {len(items)} items)", _UPLOAD_FIXES[name]) from exc
        said = await texts.reason(mark) if texts is not None else []
        raise CompanionError(f"the vehicle rejected the mission upload ({name}, {len(items)} items)"
                             + _culprit(items, autopilot, name) + (f"; {quote(said)}" if texts is not None else ""),
                             _refusal_fix(name, said, len(items))) from exc
    log.info("uploaded %d mission items", len(items))
    try:
        got = from_raw(await _with_retries("mission download", mission_plugin.download_mission, attempts))
    except MissionRawError as exc:
        raise CompanionError(f"could not download the mission back to verify it ({exc.result.name})",
                             "check the link; the upload itself was accepted") from exc
    problems = compare_missions(items, got, autopilot)
    if problems:
        more = f" (and {len(problems) - 5} more)" if len(problems) > 5 else ""
        raise CompanionError("the mission on the vehicle differs from the plan: " + "; ".join(problems[:5]) + more,
                             "do not fly it: re-upload; if it persists, the autopilot stores items in a form "
                             "docs/FLIGHT.md does not list (check its firmware version against the tables there)")
    log.info("verified: the vehicle holds the planned %d items", len(items))

"""Put back the parameters an earlier run left changed on this vehicle (its parameter journal), before anything else.

Why before anything else: a run killed mid-flight (``kill -9``, a crash, a power cut of the companion computer)
leaves the flight's values on the vehicle: on real ArduCopter WP_YAW_BEHAVIOR=0, FS_GCS_ENABLE=1 and RTL_ALT=1800
stayed (issue 31). The next flight would read them as the vehicle's own and journal them as the values to go back
to, so they would never be undone. ``companion fly`` therefore restores first and refuses to fly while a value
cannot be put back; ``companion restore --connect URL`` does only that.

Each journaled parameter is read first:
* still the value the run set: the old value is written back;
* already the old value (the run died between journal and PARAM_SET, or a person put it back): nothing to do;
* a third value: someone set it since; it is left as it is and said, since overwriting a person's later choice
  with an older one is not a restore.
Each is dropped from the journal once settled; one that cannot be written stays, and the error names it with the
value to set by hand.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
from dataclasses import dataclass
from pathlib import Path

from mavsdk.asyncio.plugins.mavlink_direct import MavlinkMessage

from companion.errors import CompanionError
from companion.flight.connection import Vehicle
from companion.flight.link_watch import ARDUPILOT_GCS_SYSID, HEARTBEAT_PERIOD_WAIT_S
from companion.flight.param_journal import (
    JOURNAL_DIR,
    Journal,
    ParamJournal,
    VehicleIdentity,
    journals_in,
    state_dir,
)
from companion.flight.parameters import ParamValue, read_parameter, same_value, write_parameter

log = logging.getLogger(__name__)

MAV_CMD_REQUEST_MESSAGE = 512
MSG_ID_AUTOPILOT_VERSION = 148
IDENTITY_TIMEOUT_S = 5.0  # a vehicle that answers at all answers within a second; asked three times


def uid_text(fields: dict) -> str | None:
    """The autopilot's hardware uid from AUTOPILOT_VERSION (``uid``, else the 18-byte ``uid2``), as hex; None when
    it reports none (zeros)."""
    uid = int(fields.get("uid") or 0)
    if uid:
        return f"{uid:016x}"
    uid2 = [int(b) for b in fields.get("uid2") or []]
    return bytes(uid2).hex() if any(uid2) else None


async def vehicle_identity(vehicle: Vehicle, timeout_s: float = IDENTITY_TIMEOUT_S) -> VehicleIdentity:
    """The vehicle's system id and, when it answers within ``timeout_s``, its AUTOPILOT_VERSION uid."""
    fields: dict = {}

    async def _first():
        async for msg in vehicle.direct.subscribe_message("AUTOPILOT_VERSION"):
            with contextlib.suppress(ValueError, TypeError):
                fields.update(json.loads(msg.fields_json))
                return

    async def _ask():  # fire and forget: a request waiting for its ACK would outlive a mavsdk closed under it
        fields = {"target_system": vehicle.system_id, "target_component": 1, "command": MAV_CMD_REQUEST_MESSAGE,
                  "confirmation": 0, "param1": float(MSG_ID_AUTOPILOT_VERSION)}
        fields.update({f"param{i}": 0.0 for i in range(2, 8)})
        request = MavlinkMessage("COMMAND_LONG", 0, 0, vehicle.system_id, 1, json.dumps(fields))
        for _ in range(3):
            with contextlib.suppress(Exception):
                await vehicle.direct.send_message(request)
            await asyncio.sleep(timeout_s / 3)

    asker = asyncio.create_task(_ask())
    try:
        await asyncio.wait_for(_first(), timeout_s)
    except TimeoutError:
        log.info("no AUTOPILOT_VERSION within %g s: the parameter journal knows this vehicle by its system id only",
                 timeout_s)
    finally:
        asker.cancel()
        with contextlib.suppress(asyncio.CancelledError, Exception):
            await asker
    return VehicleIdentity(vehicle.system_id, uid_text(fields) if fields else None)


@dataclass(frozen=True)
class RestoreOutcome:
    """What a restore found and did; each tuple holds ``NAME (detail)`` texts for a person."""

    vehicle: VehicleIdentity
    journal: Path | None
    restored: tuple[str, ...] = ()
    already_back: tuple[str, ...] = ()
    changed_since: tuple[str, ...] = ()
    failed: tuple[str, ...] = ()
    other_vehicles: tuple[str, ...] = ()

    @property
    def complete(self) -> bool:
        return not self.failed

    def summary(self) -> str:
        if self.journal is None:
            return f"nothing to restore: no parameter journal for this vehicle ({self.vehicle.text()})"
        parts = [f"restored {len(self.restored)}: {', '.join(self.restored) or '-'}"]
        if self.already_back:
            parts.append(f"already back {len(self.already_back)}: {', '.join(self.already_back)}")
        if self.changed_since:
            parts.append(f"changed since, left as they are {len(self.changed_since)}: "
                         f"{', '.join(self.changed_since)}")
        if self.failed:
            parts.append(f"NOT restored {len(self.failed)}: {', '.join(self.failed)}")
        return "; ".join(parts)


def _journals_of(directory: Path, identity: VehicleIdentity) -> tuple[list[Journal], list[str]]:
    """This vehicle's journals, and a description of the other vehicles' (kept for when they connect). Refuses
    when a journal may or may not be this vehicle's (same system id, a uid on one side only)."""
    mine, others = [], []
    for journal in journals_in(directory):
        if journal.vehicle.same_vehicle(identity):
            mine.append(journal)
        elif journal.vehicle.maybe_same_vehicle(identity):
            raise CompanionError(
                f"the parameter journal {journal.path} ({journal.vehicle.text()}) may belong to this vehicle "
                f"({identity.text()}): it lists {', '.join(e.name for e in journal.entries)} as left changed, and "
                "without both uids it cannot be told whether this is the same vehicle",
                "connect again (the uid comes with AUTOPILOT_VERSION, asked for at connection); if it is another "
                "vehicle, restore that one with `companion restore`, or delete the file after checking its values")
        else:
            others.append(f"{journal.vehicle.text()}: {', '.join(e.name for e in journal.entries)} ({journal.path})")
    return mine, others


async def _restore_entry(vehicle: Vehicle, store: ParamJournal, entry, outcome: dict) -> None:
    """Settle one journaled change (see the module docstring); a failure stays in the journal."""
    before = ParamValue(entry.name, entry.before, entry.is_int)
    try:
        now = await read_parameter(vehicle.param, entry.name)
        if same_value(now.value, entry.before, entry.is_int):
            outcome["already_back"].append(f"{entry.name} ({before.text()})")
            log.info("parameter %s is already back to %s", entry.name, before.text())
        elif same_value(now.value, entry.during, entry.is_int):
            await write_parameter(vehicle.param, entry.name, entry.before, entry.is_int)
            outcome["restored"].append(f"{entry.name} ({before.text(entry.during)} -> {before.text()})")
            log.info("parameter %s restored to %s (a previous run left it %s)", entry.name, before.text(),
                     before.text(entry.during))
        else:
            outcome["changed_since"].append(f"{entry.name} (is {now.text()}; the run set {before.text(entry.during)}, "
                                            f"it was {before.text()})")
            log.warning("parameter %s is %s, neither the %s a previous run set nor its old %s: someone changed it "
                        "since; left as it is", entry.name, now.text(), before.text(entry.during), before.text())
        store.settled(entry.name)
    except CompanionError as exc:
        outcome["failed"].append(f"{entry.name} (set it back to {before.text()})")
        log.error("could not restore parameter %s to %s: %s", entry.name, before.text(), exc.problem)


async def restore_left_parameters(vehicle: Vehicle, directory: Path, identity: VehicleIdentity) -> RestoreOutcome:
    """Restore every change this vehicle's journal(s) in ``directory`` hold; the outcome says what happened."""
    journals, others = _journals_of(directory, identity)
    for text in others:
        log.info("parameter journal of another vehicle kept (connect it and run `companion restore`): %s", text)
    if not journals:
        return RestoreOutcome(identity, None, other_vehicles=tuple(others))
    outcome: dict[str, list[str]] = {"restored": [], "already_back": [], "changed_since": [], "failed": []}
    await _let_the_failsafe_see_the_companion(journals)
    for journal in journals:
        names = ", ".join(e.name for e in journal.entries)
        log.warning("a previous run left parameters changed on this vehicle (%s; journal %s): restoring them "
                    "before anything else: %s", identity.text(), journal.path, names or "none")
        store = ParamJournal(directory, journal.vehicle, journal.autopilot)
        for entry in reversed(journal.entries):  # newest first, as a flight restores: a failsafe is disabled
            await _restore_entry(vehicle, store, entry, outcome)  # before the GCS id it watches goes back
    return RestoreOutcome(identity, journals[-1].path, other_vehicles=tuple(others),
                          **{k: tuple(v) for k, v in outcome.items()})


async def _let_the_failsafe_see_the_companion(journals: list[Journal]) -> None:
    """A killed run that made the companion the GCS left ArduCopter's GCS failsafe on (that is how it returned).
    Copter clears it only at a counted heartbeat while FS_GCS_ENABLE is on (``Copter::failsafe_gcs_check``
    returns early when disabled) and refuses to arm while it is on ("PreArm: GCS failsafe on"). So before
    FS_GCS_ENABLE goes back to 0, one heartbeat period passes with MAV_GCS_SYSID still the companion's: the
    companion's heartbeat is counted and the failsafe cleared; disabled first, it would stay on for good."""
    if any(e.name in ARDUPILOT_GCS_SYSID for journal in journals for e in journal.entries):
        log.info("waiting %.1f s for the vehicle to count a heartbeat from the companion (it clears the GCS "
                 "failsafe the killed run left on) before restoring", HEARTBEAT_PERIOD_WAIT_S)
        await asyncio.sleep(HEARTBEAT_PERIOD_WAIT_S)


def journal_directory(state: str | Path | None = None) -> Path:
    return state_dir(state) / JOURNAL_DIR


async def restore_before_flight(vehicle: Vehicle, state: str | Path | None = None) -> ParamJournal:
    """Restore what earlier runs left on this vehicle, refuse to go on while anything could not be, and return the
    journal the coming flight writes its own changes to."""
    directory = journal_directory(state)
    identity = await vehicle_identity(vehicle)
    outcome = await restore_left_parameters(vehicle, directory, identity)
    if outcome.journal is not None:
        log.warning("parameters left by a previous run: %s", outcome.summary())
    refuse_unless_restored(outcome)
    return ParamJournal(directory, identity, vehicle.autopilot)


def refuse_unless_restored(outcome: RestoreOutcome) -> None:
    """CompanionError naming each parameter still changed, the value to set by hand and the journal file."""
    if outcome.complete:
        return
    raise CompanionError(
        f"a previous run left parameters changed on this vehicle and they could not be restored: "
        f"{', '.join(outcome.failed)}; flying now would take them for the vehicle's own values",
        f"check the link and run `companion restore --connect URL` again, or set them on the ground station and "
        f"delete {outcome.journal}")


async def restore_vehicle(url: str, *, connect_timeout_s: float, state: str | Path | None = None) -> RestoreOutcome:
    """``companion restore``: connect, restore what earlier runs left on this vehicle, disconnect. Raises
    CompanionError when a value could not be put back (the journal keeps it)."""
    from companion.flight.connection import connect

    vehicle = await connect(url, timeout_s=connect_timeout_s)
    try:
        outcome = await restore_left_parameters(vehicle, journal_directory(state), await vehicle_identity(vehicle))
    finally:
        vehicle.close()
    refuse_unless_restored(outcome)
    return outcome

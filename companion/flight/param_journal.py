"""The parameter journal: every autopilot parameter a flight changes, written to disk before the change is made.

Why: :class:`companion.flight.parameters.FlightParameters` restores what it set on every way out Python sees, but
not on ``kill -9``, a power cut of the companion computer or a crash of the interpreter. Real ArduCopter kept
WP_YAW_BEHAVIOR=0, FS_GCS_ENABLE=1 and RTL_ALT=1800 after the companion was killed (issue 31), and would have flown
the next mission, from any ground station, with them. So each change is journaled (name, value before, value set,
vehicle, time) durably and atomically *before* the PARAM_SET goes out, and dropped only once the old value is back
on the vehicle; whatever a run leaves is restored by the next ``companion fly`` or by ``companion restore``
(``companion/flight/restore.py``).

Where: one JSON file per vehicle under the per-user state directory (``$COMPANION_STATE_DIR``, else
``$XDG_STATE_HOME/companion``, else ``~/.local/state/companion``), in ``parameter-journal/``. A vehicle is its
MAVLink system id plus its autopilot's hardware uid where it reports one: system ids repeat (every vehicle ships
as 1), so two vehicles on the same id keep separate journals when their uid tells them apart.

This module only stores; talking to the vehicle is ``restore.py``'s job.
"""

from __future__ import annotations

import json
import os
import re
from dataclasses import asdict, dataclass
from datetime import UTC, datetime
from pathlib import Path

from companion.errors import CompanionError
from companion.files import write_atomic

STATE_DIR_ENV = "COMPANION_STATE_DIR"
JOURNAL_DIR = "parameter-journal"
FORMAT = 1


def state_dir(override: str | Path | None = None) -> Path:
    """The per-user state directory: ``override`` (an option), ``$COMPANION_STATE_DIR``, ``$XDG_STATE_HOME/companion``
    or ``~/.local/state/companion`` (the XDG base directory default), first one given."""
    if override:
        return Path(override).expanduser()
    if os.environ.get(STATE_DIR_ENV):
        return Path(os.environ[STATE_DIR_ENV]).expanduser()
    xdg = os.environ.get("XDG_STATE_HOME")
    base = Path(xdg).expanduser() if xdg else Path.home() / ".local" / "state"
    return base / "companion"


@dataclass(frozen=True)
class VehicleIdentity:
    """Which vehicle a journal belongs to: MAVLink system id, and the autopilot's uid (hex) when it reports one."""

    system_id: int
    uid: str | None = None

    @property
    def key(self) -> str:
        uid = re.sub(r"[^0-9A-Za-z]", "", self.uid or "") or "nouid"
        return f"system{self.system_id}-{uid}"

    def text(self) -> str:
        return f"system {self.system_id}" + (f", uid {self.uid}" if self.uid else ", no uid reported")

    def same_vehicle(self, other: VehicleIdentity) -> bool:
        """Same system id and same uid (or neither reports one)."""
        return self.system_id == other.system_id and self.uid == other.uid

    def maybe_same_vehicle(self, other: VehicleIdentity) -> bool:
        """Same system id, and only one of the two has a uid: it cannot be told whether this is the vehicle (every
        vehicle ships as system 1; a simulator's journal must not be restored onto a real vehicle that did not
        answer in time, nor a vehicle's own journal ignored)."""
        return self.system_id == other.system_id and (self.uid is None) != (other.uid is None)


@dataclass(frozen=True)
class JournalEntry:
    """One parameter change: the value before it, the value the flight set, and when it was journaled (UTC)."""

    name: str
    before: float
    during: float
    is_int: bool
    time_utc: str


@dataclass(frozen=True)
class Journal:
    """What one vehicle's journal file holds."""

    path: Path
    vehicle: VehicleIdentity
    autopilot: str
    entries: tuple[JournalEntry, ...]


def _utc_now() -> str:
    return datetime.now(UTC).isoformat(timespec="seconds")


def read_journal(path: Path) -> Journal:
    """A journal file; CompanionError naming the file when it cannot be read (never silently treated as empty: that
    would fly a vehicle left changed)."""
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
        vehicle = VehicleIdentity(int(data["vehicle"]["system_id"]), data["vehicle"].get("uid"))
        entries = tuple(JournalEntry(str(e["name"]), float(e["before"]), float(e["during"]), bool(e["is_int"]),
                                     str(e.get("time_utc", ""))) for e in data["changes"])
        return Journal(path, vehicle, str(data.get("autopilot", "")), entries)
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise CompanionError(f"the parameter journal {path} cannot be read ({exc})",
                             "read it (it lists the parameters a run changed and their old values), set them on the "
                             "ground station, then delete the file") from exc


def journals_in(directory: Path) -> list[Journal]:
    """Every journal in ``directory`` (oldest file first); none when it does not exist."""
    if not directory.is_dir():
        return []
    return [read_journal(p) for p in sorted(directory.glob("system*.json"), key=lambda p: p.stat().st_mtime)]


class ParamJournal:
    """One vehicle's journal file. ``record`` before a PARAM_SET, ``settled`` once the old value is back."""

    def __init__(self, directory: Path, vehicle: VehicleIdentity, autopilot: str):
        self.directory = Path(directory)
        self.vehicle = vehicle
        self.autopilot = autopilot
        self.path = self.directory / f"{vehicle.key}.json"

    def entries(self) -> tuple[JournalEntry, ...]:
        return read_journal(self.path).entries if self.path.exists() else ()

    def record(self, name: str, before: float, during: float, is_int: bool) -> None:
        """Journal a change about to be made (replacing an older entry of the same name keeps its first ``before``:
        the value the vehicle had before any run changed it)."""
        old = {e.name: e for e in self.entries()}
        first = old.get(name)
        entry = JournalEntry(name, first.before if first else float(before), float(during), is_int, _utc_now())
        old[name] = entry
        self._write(list(old.values()))

    def settled(self, name: str) -> None:
        """``name`` is back to its old value on the vehicle: drop it; the file goes with the last entry."""
        rest = [e for e in self.entries() if e.name != name]
        if rest:
            self._write(rest)
        else:
            self.path.unlink(missing_ok=True)

    def _write(self, entries: list[JournalEntry]) -> None:
        try:
            self.directory.mkdir(parents=True, exist_ok=True)
            data = {"format": FORMAT, "vehicle": asdict(self.vehicle), "autopilot": self.autopilot,
                    "written_utc": _utc_now(), "changes": [asdict(e) for e in entries]}
            write_atomic(self.path, json.dumps(data, indent=1) + "\n", durable=True)
        except OSError as exc:
            raise CompanionError(f"cannot write the parameter journal {self.path} ({exc}): a parameter changed "
                                 "without it would stay changed if the companion died",
                                 f"make {self.directory} writable, or give another with --state-dir") from exc

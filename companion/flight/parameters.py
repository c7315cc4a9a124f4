"""Autopilot parameters for one flight: read them, set them for the flight, and always put them back afterwards.

Why a context manager: a flight may need firmware settings that differ from what the vehicle keeps (a lost-link
action, a return altitude, vertical scan speeds). Left changed, they would silently alter the next flight, so the
previous values are restored on every way out (normal end, error, Ctrl-C) and every change is logged both ways.
Ways out Python never sees (``kill -9``, a power cut) are covered by the journal (``param_journal.py``): each change
is written there before it is made and dropped once restored, so the next run can put back what this one left.

Types: PX4 sends integer parameters byte-wise inside the float field, ArduPilot as a C cast; mavsdk's param plugin
decodes both, but only when asked with the parameter's own type (``WRONG_TYPE`` otherwise). So each parameter is
read as a float first and as an int on ``WRONG_TYPE``, and written back with the type it was read with.
"""

from __future__ import annotations

import asyncio
import logging
import math
from collections.abc import Mapping
from dataclasses import dataclass

from companion.errors import CompanionError
from companion.flight.param_journal import ParamJournal

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class ParamValue:
    name: str
    value: float
    is_int: bool

    def text(self, value: float | None = None) -> str:
        v = self.value if value is None else value
        return f"{int(round(v))}" if self.is_int else f"{v:g}"


@dataclass(frozen=True)
class ParamChange:
    """One parameter set for the flight: its value before and during it."""

    name: str
    before: float
    during: float
    is_int: bool


def _result_name(exc: Exception) -> str:
    return getattr(getattr(exc, "result", None), "name", type(exc).__name__)


LINK_ATTEMPTS = 3  # mavsdk already re-sends each request 5 times; a lossy link (20 % each way) still loses some


async def _over_the_link(request, what: str, attempts: int = LINK_ATTEMPTS):
    """``await request()``, asked again when mavsdk gave up with ``TIMEOUT``.

    Why: mavsdk's parameter client re-sends a request a few times within about 3 s and then reports TIMEOUT. Over a
    link losing a fifth of its packets each way (SITL's packet-loss test, a real radio at the edge of its range) that
    happened for one of the flight's parameter reads; the flight then stopped before take-off although the vehicle
    was answering. A read or a write of the same value is safe to repeat; any other result is the vehicle's answer
    and is raised at once."""
    for attempt in range(1, attempts + 1):
        try:
            return await request()
        except Exception as exc:
            if _result_name(exc) != "TIMEOUT" or attempt == attempts:
                raise
            log.warning("%s timed out over the link (attempt %d of %d); asking again", what, attempt, attempts)


async def read_parameter(param_plugin, name: str, *, attempts: int = LINK_ATTEMPTS) -> ParamValue:
    """The vehicle's value of ``name`` with its type; CompanionError if the vehicle does not have it.

    ArduPilot does not answer a read of a parameter it lacks (no PARAM_ERROR): that reads as a link TIMEOUT. A
    parameter only some firmware versions have is read with ``attempts=1``, so its absence costs one mavsdk
    request (about 3 s), not ``LINK_ATTEMPTS``."""
    try:
        value = await _over_the_link(lambda: param_plugin.get_param_float(name), f"reading {name}", attempts)
        return ParamValue(name, float(value), False)
    except Exception as exc:
        if _result_name(exc) != "WRONG_TYPE":
            raise CompanionError(f"cannot read parameter {name} from the vehicle ({_result_name(exc)})",
                                 "check the parameter name for this firmware and the link") from exc
    try:
        value = await _over_the_link(lambda: param_plugin.get_param_int(name), f"reading {name}", attempts)
        return ParamValue(name, float(value), True)
    except Exception as exc:
        raise CompanionError(f"cannot read parameter {name} from the vehicle ({_result_name(exc)})",
                             "check the parameter name for this firmware and the link") from exc


async def write_parameter(param_plugin, name: str, value: float, is_int: bool) -> None:
    def request():
        if is_int:
            return param_plugin.set_param_int(name, int(round(value)))
        return param_plugin.set_param_float(name, float(value))

    try:
        await _over_the_link(request, f"setting {name}")
    except Exception as exc:
        raise CompanionError(f"the vehicle did not accept {name} = {value:g} ({_result_name(exc)})",
                             "check the value's range for this firmware, or set it on the ground station") from exc


def same_value(a: float, b: float, is_int: bool) -> bool:
    return int(round(a)) == int(round(b)) if is_int else math.isclose(a, b, rel_tol=1e-6, abs_tol=1e-6)


class FlightParameters:
    """``async with FlightParameters(vehicle.param, {"RTL_RETURN_ALT": 40.0}) as fp:`` sets the values that differ
    and restores them on exit, whatever the exit. ``fp.changes`` says what was changed; a value that could not be
    restored is logged as an error naming the parameter and the value to set by hand (``fp.restore_failures``)."""

    def __init__(self, param_plugin, wanted: Mapping[str, float] | None, journal: ParamJournal | None = None):
        self.param = param_plugin
        self.journal = journal
        self.wanted = dict(wanted or {})
        self.changes: list[ParamChange] = []  # still to restore
        self.applied: list[ParamChange] = []  # everything set for the flight (kept for the report)
        self.restore_failures: list[str] = []
        self.unreachable: str | None = None  # why the vehicle cannot be reached: the restore is not attempted

    async def __aenter__(self) -> FlightParameters:
        try:
            for name, value in self.wanted.items():
                if not math.isfinite(float(value)):
                    raise CompanionError(f"parameter {name} = {value} is not a finite number",
                                         "give a finite value")
                old = await read_parameter(self.param, name)
                if same_value(old.value, float(value), old.is_int):
                    log.info("parameter %s is already %s", name, old.text())
                    continue
                change = ParamChange(name, old.value, float(value), old.is_int)
                if self.journal is not None:  # on disk before the vehicle changes
                    self.journal.record(name, old.value, float(value), old.is_int)
                self.changes.append(change)
                await self._set(change)
                self.applied.append(change)
                log.info("parameter %s set to %s for this flight (was %s)", name, old.text(float(value)), old.text())
        except BaseException:
            await self.restore()
            raise
        return self

    async def _set(self, change: ParamChange) -> None:
        """Write the flight's value. Refused by the vehicle: nothing changed, so nothing to put back or journal.
        Timed out: it may have landed, so it stays to be put back (now, and by the journal if that fails)."""
        try:
            await write_parameter(self.param, change.name, change.during, change.is_int)
        except CompanionError as exc:
            cause = exc.__cause__
            if cause is None or _result_name(cause) != "TIMEOUT":
                self.changes.remove(change)
                if self.journal is not None:
                    self.journal.settled(change.name)
            raise

    async def __aexit__(self, *exc) -> None:
        await self.restore()

    async def restore(self) -> None:
        """Put every changed parameter back (newest first). Shielded: a Ctrl-C during the restore does not cut it."""
        changes, self.changes = self.changes, []
        for ch in reversed(changes):
            if self.unreachable:
                # a dead link: each write would only wait for mavsdk's retries to run out (5 s on real ArduCopter
                # SITL) and push the end past the --link-dead limit; say what to set by hand instead
                text = ParamValue(ch.name, ch.before, ch.is_int).text()
                self.restore_failures.append(f"{ch.name} (set it back to {text})")
                log.error("parameter %s not restored to %s: %s; it stays in the parameter journal: the next "
                          "`companion fly` or `companion restore` puts it back (or set it on the ground station)",
                          ch.name, text, self.unreachable)
                continue
            try:
                await asyncio.shield(write_parameter(self.param, ch.name, ch.before, ch.is_int))
                if self.journal is not None:
                    self.journal.settled(ch.name)
                value = ParamValue(ch.name, ch.before, ch.is_int)
                log.info("parameter %s restored to %s", ch.name, value.text())
            except (Exception, asyncio.CancelledError) as exc:
                text = ParamValue(ch.name, ch.before, ch.is_int).text()
                self.restore_failures.append(f"{ch.name} (set it back to {text})")
                log.error("could not restore parameter %s to %s: %s; it stays in the parameter journal: the next "
                          "`companion fly` or `companion restore` puts it back (or set it on the ground station)",
                          ch.name, text, exc)

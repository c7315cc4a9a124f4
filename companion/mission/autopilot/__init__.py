"""One home per autopilot firmware: everything that differs between PX4 and ArduPilot, chosen once.

``autopilot_for(flavour)`` gives the home of a flavour named in a file or on the command line (``px4``,
``ardupilot``: ``Flavour``); ``autopilot_from_heartbeat(n)`` the home of the MAV_AUTOPILOT number a vehicle's
HEARTBEAT carries, and refuses any other with an error naming the number. The planner, the exports and the flight
code ask the home (``base.Autopilot``) instead of comparing names.

A new firmware is one module in this package with one ``Autopilot`` subclass: the package finds it, and its
``flavour`` becomes a ``Flavour`` member, a ``--autopilot`` choice and an export.
"""

from __future__ import annotations

import importlib
import inspect
import pkgutil
from enum import StrEnum

from pymavlink.dialects.v20 import common as mavlink

from companion.errors import CompanionError
from companion.mission.autopilot.base import Autopilot


def _discover() -> dict[str, Autopilot]:
    """Every ``Autopilot`` subclass defined in a module of this package, by flavour, PX4 first (the default)."""
    homes: dict[str, Autopilot] = {}
    for info in pkgutil.iter_modules(__path__):
        module = importlib.import_module(f"{__name__}.{info.name}")
        for obj in vars(module).values():
            if isinstance(obj, type) and issubclass(obj, Autopilot) and not inspect.isabstract(obj):
                homes[obj.flavour] = obj()
    return dict(sorted(homes.items(), key=lambda kv: -kv[1].mav_autopilot))


_HOMES = _discover()
# the flavours as named in files and on the command line (the enum's values): Flavour.PX4 == "px4"
Flavour = StrEnum("Flavour", {name.upper(): name for name in _HOMES})
Flavour.__doc__ = "An autopilot flavour as files and the command line name it; ``autopilot_for`` gives its home."
# the heartbeat's number -> the first home that claims it (a release of the same firmware with other mission
# semantics shares its number: it is chosen by name, --autopilot, until it is told apart by its version)
_BY_NUMBER: dict[int, Autopilot] = {}
for _home in _HOMES.values():
    _BY_NUMBER.setdefault(_home.mav_autopilot, _home)
DEFAULT_FLAVOUR = Flavour("px4")  # what a plan exports for when no autopilot is named


def flavours() -> list[Flavour]:
    return list(Flavour)


def homes() -> list[Autopilot]:
    """Every firmware's home."""
    return list(_HOMES.values())


def autopilot_for(flavour: str | Autopilot) -> Autopilot:
    """The home of ``flavour`` (a ``Flavour``, its name, or a home, returned as it is); an unknown name is an
    error naming the ones there are."""
    if isinstance(flavour, Autopilot):
        return flavour
    try:
        return _HOMES[str(flavour)]
    except KeyError:
        known = " or ".join(repr(name) for name in _HOMES)
        raise CompanionError(f"unknown autopilot flavour {flavour!r}", f"use {known}") from None


def autopilot_from_heartbeat(mav_autopilot: int) -> Autopilot:
    """The home of the firmware whose HEARTBEAT says ``mav_autopilot``; any other number is refused, naming it:
    flying a firmware by another's rules (mission items, arming mode, failsafe parameters) is not safe."""
    home = _BY_NUMBER.get(int(mav_autopilot))
    if home is not None:
        return home
    entry = mavlink.enums["MAV_AUTOPILOT"].get(int(mav_autopilot))
    name = f" ({entry.name})" if entry is not None else ""
    known = ", ".join(f"{h.label} ({h.mav_autopilot})" for h in _HOMES.values())
    choices = "|".join(_HOMES)
    raise CompanionError(
        f"the vehicle's heartbeat names autopilot {int(mav_autopilot)}{name}, which the companion cannot fly: it "
        f"knows {known}",
        f"connect to a {' or '.join(h.label for h in _HOMES.values())} vehicle; if this firmware behaves exactly as "
        f"one of them, say which with --autopilot {choices}")


def flight_parameters(plan, flavour: str | Autopilot) -> dict[str, float]:
    """The parameters ``plan`` needs set for its flight on ``flavour`` (``Autopilot.flight_parameters``)."""
    ap = autopilot_for(flavour)
    return ap.flight_parameters(plan.for_autopilot(ap) if hasattr(plan, "for_autopilot") else plan)


__all__ = ["DEFAULT_FLAVOUR", "Autopilot", "Flavour", "autopilot_for", "autopilot_from_heartbeat", "homes",
           "flavours", "flight_parameters"]

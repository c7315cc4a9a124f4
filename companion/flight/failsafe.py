"""Pre-flight check of the firmware's lost-link failsafe: what it does when the ground link is lost, and how high
it returns, against what this scan needs.

Why: the defaults are not safe for a facade scan. ArduCopter 4.7 ships FS_GCS_ENABLE=0 (a lost ground link keeps
flying the AUTO mission) and RTL_ALT=1500 cm (15 m, below the demo's 18 m transit altitude, i.e. a return that can
cross the roof line lower than planned); PX4 ships NAV_DLL_ACT=0 (no action) and RTL_RETURN_ALT=30 m. The check
warns; the explicit options (``--lost-link-action``, ``--return-alt``) set them for the flight only, through
:class:`companion.flight.parameters.FlightParameters`, which restores them afterwards.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from companion.errors import CompanionError
from companion.flight.parameters import read_parameter
from companion.mission import items as mi
from companion.mission.autopilot import Autopilot, autopilot_for
from companion.mission.autopilot.base import FailsafeNames


@dataclass(frozen=True)
class FailsafeSettings:
    autopilot: str  # its flavour (``companion.mission.autopilot``, whose home names the parameters)
    link_action: int
    return_alt_m: float

    @property
    def names(self) -> FailsafeNames:
        return autopilot_for(self.autopilot).failsafe

    @property
    def link_action_text(self) -> str:
        return self.names.action_names.get(self.link_action, f"value {self.link_action}")

    @property
    def keeps_flying(self) -> bool:
        return self.link_action in self.names.keeps_flying


@dataclass(frozen=True)
class ReturnAltitudeNeed:
    """The lowest safe return altitude above home, and why."""

    alt_m: float
    reason: str


def required_return_alt(plan) -> ReturnAltitudeNeed | None:
    """The transit altitude or the wall's top plus the roof margin, whichever is higher (metres above home).
    For a bare item list: the highest relative-altitude item. None when the plan says nothing usable."""
    waypoints = getattr(plan, "waypoints", None)
    mission = getattr(plan, "mission", None)
    if waypoints and mission is not None and getattr(plan, "home", None) is not None:
        transit = max((w.rel_alt_m for w in waypoints if w.kind == "transit"), default=0.0)
        facade = mission.facade
        wall_top = facade.height_m + mission.margins.roof_m + (facade.ground_alt_amsl_m - plan.home.alt_amsl_m)
        if transit >= wall_top:
            return ReturnAltitudeNeed(transit, f"the transit altitude {transit:.1f} m")
        return ReturnAltitudeNeed(wall_top, f"the wall's top plus {mission.margins.roof_m:g} m margin "
                                            f"({wall_top:.1f} m)")
    rel = [it.z for it in plan if isinstance(it, mi.MissionItem)
           and it.frame in (mi.MAV_FRAME_GLOBAL_RELATIVE_ALT, mi.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT)]
    if rel:
        return ReturnAltitudeNeed(max(rel), f"the mission's highest item ({max(rel):.1f} m)")
    return None


async def read_failsafe(param_plugin, autopilot: str | Autopilot) -> FailsafeSettings:
    ap = autopilot_for(autopilot)
    names = ap.failsafe
    action = await read_parameter(param_plugin, names.link_action)
    alt = await read_parameter(param_plugin, names.return_alt)
    return FailsafeSettings(ap.flavour, int(round(action.value)), alt.value / names.return_alt_scale)


def failsafe_warnings(settings: FailsafeSettings, need: ReturnAltitudeNeed | None) -> list[str]:
    """What is unsafe for this scan, each naming the parameter and the option that fixes it for the flight."""
    n = settings.names
    out = []
    if settings.keeps_flying:
        out.append(f"lost-link failsafe {n.link_action}={settings.link_action} ({settings.link_action_text}): a "
                   f"lost ground link keeps flying the mission; use --lost-link-action rtl to return for this flight")
    if need is not None and settings.return_alt_m + 1e-6 < need.alt_m:
        out.append(f"return altitude {n.return_alt} is {settings.return_alt_m:g} m, below {need.reason}: a return "
                   f"could fly into the building; use --return-alt auto (or a height in m) for this flight")
    return out


def failsafe_overrides(autopilot: str | Autopilot, *, link_action: str | None, return_alt: str | float | None,
                       need: ReturnAltitudeNeed | None, current: FailsafeSettings | None = None) -> dict[str, float]:
    """The parameter values the explicit options ask for (empty: change nothing). ``return_alt='auto'`` raises the
    return altitude to what the scan needs and never lowers one that is already high enough (``current``)."""
    names = autopilot_for(autopilot).failsafe
    out: dict[str, float] = {}
    if link_action is not None:
        if link_action not in names.action_values:
            raise CompanionError(f"lost-link action {link_action!r} is not one of {sorted(names.action_values)}",
                                 "use --lost-link-action rtl")
        out[names.link_action] = float(names.action_values[link_action])
    if return_alt is not None:
        if return_alt == "auto":
            if need is None:
                raise CompanionError("--return-alt auto needs a planned scan (transit altitude, wall height)",
                                     "give the return altitude in metres, e.g. --return-alt 30")
            alt_m = float(math.ceil(need.alt_m))
            if current is not None and current.return_alt_m >= need.alt_m:
                return out
        else:
            try:
                alt_m = float(return_alt)
            except ValueError:
                raise CompanionError(f"--return-alt {return_alt!r} is not a height in metres or 'auto'",
                                     "write e.g. --return-alt 30 or --return-alt auto") from None
            if not math.isfinite(alt_m) or alt_m <= 0:
                raise CompanionError(f"--return-alt {return_alt} must be a positive height in metres",
                                     "write e.g. --return-alt 30")
        out[names.return_alt] = alt_m * names.return_alt_scale
    return out

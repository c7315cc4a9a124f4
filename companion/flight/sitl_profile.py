"""What a simulator needs from a flight that a real vehicle must never get, asked for explicitly.

Why explicit: the companion behaves the same on a simulator and on a vehicle; it detects nothing and changes nothing
because a vehicle looks simulated. A simulator whose sensor model and its autopilot's default tuning disagree (PX4's
SIH: IMU noise 3.5x / 8x what EKF2 assumes) or whose GPS altitude noise is white (SIH: PX4's in-flight home
correction then follows noise, not drift) gets its accommodations from a profile file the operator names:
``companion fly --sitl-profile sim/sitl/px4-sih.yaml`` (docs/FLIGHT.md). The file says::

    parameters: {EKF2_ACC_NOISE: 1.0}   # set for this flight only, restored after (like --set-param)
    restore_home: true                  # put home back where it was at arming once the autopilot's correction
                                        # window is over, and hand it back after landing

Without a profile the flight sets no such parameter and moves no home: it reports each home move it sees
(``home_watch.py``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from companion.errors import CompanionError

_KEYS = {"parameters", "restore_home"}


@dataclass(frozen=True)
class SitlProfile:
    """A simulator's accommodations for one flight: ``parameters`` set for the flight (restored after) and
    ``restore_home`` (put home back after the autopilot's correction window). ``source``: where it was read."""

    parameters: dict[str, float] = field(default_factory=dict)
    restore_home: bool = False
    source: str = ""

    def describe(self) -> str:
        said = [f"{k} {v:g}" for k, v in self.parameters.items()]
        if self.restore_home:
            said.append("home put back after the autopilot's correction window")
        return ", ".join(said) or "nothing"


def load_sitl_profile(path: Path | str) -> SitlProfile:
    """Read a profile file (YAML with ``parameters`` and ``restore_home``); a wrong one names what is wrong."""
    path = Path(path)
    fix = f"write {path} as in sim/sitl/px4-sih.yaml (parameters: {{NAME: number}}, restore_home: true|false)"
    try:
        doc = yaml.safe_load(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise CompanionError(f"cannot read the SITL profile {path}: {exc.strerror or exc}",
                             "give the path of a profile file, e.g. --sitl-profile sim/sitl/px4-sih.yaml") from exc
    except yaml.YAMLError as exc:
        raise CompanionError(f"the SITL profile {path} is not YAML: {exc}", fix) from exc
    if not isinstance(doc, dict) or not set(doc) <= _KEYS:
        extra = sorted(set(doc) - _KEYS) if isinstance(doc, dict) else None
        raise CompanionError(f"the SITL profile {path} " + (f"has unknown keys {extra}" if extra else
                                                            "is not a mapping"), fix)
    params = doc.get("parameters") or {}
    if not isinstance(params, dict):
        raise CompanionError(f"the SITL profile {path}: parameters is not a mapping of names to numbers", fix)
    out: dict[str, float] = {}
    for name, value in params.items():
        if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
            raise CompanionError(f"the SITL profile {path}: parameter {name} = {value!r} is not a number", fix)
        out[str(name)] = float(value)
    restore = doc.get("restore_home", False)
    if not isinstance(restore, bool):
        raise CompanionError(f"the SITL profile {path}: restore_home = {restore!r} is not true or false", fix)
    return SitlProfile(out, restore, str(path))

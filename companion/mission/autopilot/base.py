"""What every autopilot home says about its firmware: the interface the planner, the exports and the flight code
ask, so that none of them branches on a flavour's name.

Each firmware is one module beside this one (``px4.py``, ``ardupilot.py``) holding everything that differs: the
mission items it accepts and honours and the form it stores them in, the mode it arms in, where its mission starts,
the parameters a scan needs set, its lost-link failsafe parameters, how it treats home in flight and the yaw. A
firmware with other semantics (a PX4 release that stores items otherwise, another autopilot) is one more module:
the package finds it (``companion.mission.autopilot``).
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import ClassVar

from companion.mission import items as mi
from companion.mission.firmware import command_name

# (frame, command, param1..param4, lat, lon, z): one mission item before it is numbered
Row = tuple[int, int, float, float, float, float, float, float, float]


@dataclass(frozen=True)
class FailsafeNames:
    """A firmware's lost-link failsafe: its parameters, their units and what their values do."""

    link_action: str
    return_alt: str
    return_alt_scale: float  # parameter units per metre
    action_values: dict[str, int]  # our action name -> parameter value
    action_names: dict[int, str]  # parameter value -> what the firmware does
    keeps_flying: frozenset[int]  # values with which a lost link does not end the mission


@dataclass(frozen=True)
class LinkWatch:
    """Which heartbeats the firmware's lost-link failsafe counts, and what makes it count the companion's for a flight
    (``companion.flight.link_watch``): a GCS system id it counts alone (the first of ``gcs_id_params`` the firmware
    has, with an optional upper end of a range), and a bitmask of modes in which a lost link is ignored
    (``exception_bits`` cleared for the flight). Empty: any ground station's heartbeat counts, nothing to set."""

    gcs_id_params: tuple[str, ...] = ()
    gcs_id_hi_param: str | None = None
    exception_param: str | None = None
    exception_bits: int = 0


@dataclass(frozen=True)
class ArmingMode:
    """The mode from which the firmware arms and starts a mission (MAV_CMD_DO_SET_MODE params after base mode)."""

    name: str
    custom_mode: tuple[float, ...]


@dataclass(frozen=True)
class StoredForm:
    """How the firmware stores one uploaded item: what a download must hold to mean the same.

    ``compared``: False for an item the vehicle fills in itself (ArduPilot's home at seq 0); ``z_truncated_cm``: the
    altitude comes back truncated to whole centimetres; ``params``: the value expected back (and the rule's
    wording) where not the one sent; ``heading_params``: params compared as headings (wrapped)."""

    frame: int
    compared: bool = True
    z_truncated_cm: bool = False
    params: Mapping[str, tuple[float, str]] = field(default_factory=dict)
    heading_params: frozenset[str] = frozenset()


@dataclass(frozen=True)
class ParamRefusal:
    """An item the firmware refuses at upload: ``param`` is 1-based (MAV_MISSION_INVALID_PARAM<param>)."""

    seq: int
    command: int
    param: int
    value: float
    firmware: str = "the autopilot"

    def describe(self) -> str:
        return (f"item {self.seq} ({command_name(self.command)}) has param{self.param} = {self.value}, which "
                f"{self.firmware} refuses (MAV_MISSION_INVALID_PARAM{self.param})")


def nan_refusal(items: Sequence[mi.MissionItem], nan_allowed: Mapping[int, frozenset[int]],
                firmware: str) -> ParamRefusal | None:
    """The first item with an inf param, or a NaN where ``nan_allowed`` (command -> 1-based params) has none."""
    for it in items:
        allowed = nan_allowed.get(it.command, frozenset())
        for k, value in enumerate((it.param1, it.param2, it.param3, it.param4), start=1):
            if math.isinf(value) or (math.isnan(value) and k not in allowed):
                return ParamRefusal(it.seq, it.command, k, value, firmware)
    return None


class Autopilot(ABC):
    """One firmware's rules. Class attributes are its facts; methods build or judge what depends on a plan.

    ``flavour``: its name in files and on the command line (``--autopilot px4``, ``mavlink_items_px4.json``);
    ``mav_autopilot``: the MAV_AUTOPILOT number its HEARTBEAT carries (and QGroundControl's ``firmwareType``)."""

    flavour: ClassVar[str]
    label: ClassVar[str]  # for a person: "PX4", "ArduPilot"
    mav_autopilot: ClassVar[int]
    arming_mode: ClassVar[ArmingMode]
    first_item_seq: ClassVar[int]  # the first item of the mission proper (ArduPilot keeps home at 0)
    # how long after take-off the firmware may move home's altitude on its own (0: never) and how far down it is taken
    # to move it in that time: the plan flies only what stays clear of the ground by then in the window, the rest
    # after it (``planner.plan_scan``), and the flight watches the moves (``companion.flight.home_watch``)
    home_correction_window_s: ClassVar[float]
    home_move_max_m: ClassVar[float] = 0.0
    failsafe: ClassVar[FailsafeNames]
    link_watch: ClassVar[LinkWatch]
    no_value: ClassVar[float]  # what a param the item does not use holds (NaN where the firmware takes it)
    plan_file_suffix: ClassVar[str]  # QGroundControl .plan export: ``<mission><suffix>.plan``

    def __repr__(self) -> str:
        return f"<autopilot {self.flavour}>"

    # --- the mission items (companion.mission.planner.build_mission_items) -------------------------------------
    @abstractmethod
    def home_rows(self, home) -> list[Row]:
        """Items before the take-off (a home placeholder where the firmware keeps home in the mission)."""

    @abstractmethod
    def speed_rows(self, speed_m_s: float, moves_vertically: bool) -> list[Row]:
        """DO_CHANGE_SPEED items for a new scan speed (``moves_vertically``: a leg at it climbs or descends)."""

    @abstractmethod
    def waypoint_rows(self, wp, hold_s: float) -> list[Row]:
        """The items of one waypoint facing the wall (``wp.yaw_deg``), holding ``hold_s`` there."""

    # --- upload and verify ------------------------------------------------------------------------------------
    @abstractmethod
    def param_refusal(self, items: Sequence[mi.MissionItem]) -> ParamRefusal | None:
        """The first item the firmware refuses for a param value it does not take; None if none."""

    @abstractmethod
    def stored_form(self, item: mi.MissionItem) -> StoredForm:
        """How the firmware stores ``item`` (what its download holds when it means the same)."""

    # --- the flight ------------------------------------------------------------------------------------------
    @abstractmethod
    def flight_parameters(self, plan) -> dict[str, float]:
        """Every parameter the plan needs set for its flight (and restored after), by name; raises CompanionError
        when a needed value lies outside what the firmware accepts."""

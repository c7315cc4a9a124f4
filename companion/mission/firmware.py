"""What each autopilot firmware accepts, stores and honours, as data the planner and the flight code share.

Checked against real firmware (recorded in ``../shared/data/real-firmware/``, notes in
``../shared/notes/real-firmware.md``) and read from source:

* ArduCopter 4.7.0-dev @ 2598e9d4: ``AP_Mission::sanity_check_params`` refuses NaN in any param except param4 of
  NAV_WAYPOINT / NAV_LOITER_UNLIM / NAV_LAND / NAV_TAKEOFF / NAV_VTOL_TAKEOFF and params 3/4 of NAV_VTOL_LAND
  (and refuses +/-inf everywhere), answering MAV_MISSION_INVALID_PARAMn at the first offending item.
  NAV_WAYPOINT keeps only param1 (hold) as whole seconds; the heading comes from WP_YAW_BEHAVIOR or CONDITION_YAW.
  DO_CHANGE_SPEED honours types 0/1 (horizontal), 2 (climb) and 3 (descent).
* PX4 main @ 02e73e3b6f: accepts NaN, honours NAV_WAYPOINT param4 (yaw), applies DO_CHANGE_SPEED param2 of *any*
  type to the horizontal cruise speed (navigator_main.cpp), so climb/descent speed is a parameter
  (MPC_Z_V_AUTO_UP 0.5..8 m/s, default 3; MPC_Z_V_AUTO_DN 0.5..4 m/s, default 1.5; multicopter_autonomous_params.c).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from companion.errors import CompanionError
from companion.mission import items as mi

AUTOPILOTS = ("px4", "ardupilot")

MAV_CMD_NAV_LOITER_UNLIM = 17
MAV_CMD_NAV_VTOL_TAKEOFF = 84
MAV_CMD_NAV_VTOL_LAND = 85

# ArduPilot: which params (1-based) may hold NaN, per command (AP_Mission::sanity_check_params).
ARDUPILOT_NAN_ALLOWED: dict[int, frozenset[int]] = {
    mi.MAV_CMD_NAV_WAYPOINT: frozenset({4}),
    MAV_CMD_NAV_LOITER_UNLIM: frozenset({4}),
    mi.MAV_CMD_NAV_LAND: frozenset({4}),
    mi.MAV_CMD_NAV_TAKEOFF: frozenset({4}),
    MAV_CMD_NAV_VTOL_TAKEOFF: frozenset({4}),
    MAV_CMD_NAV_VTOL_LAND: frozenset({3, 4}),
}

# DO_CHANGE_SPEED param1 (SPEED_TYPE): which motion each type changes.
SPEED_TYPE_GROUND = 1
SPEED_TYPE_CLIMB = 2
SPEED_TYPE_DESCENT = 3

# PX4 parameter ranges (multicopter_autonomous_params.c at 02e73e3b6f).
PX4_Z_V_AUTO_UP_RANGE = (0.5, 8.0)
PX4_Z_V_AUTO_DN_RANGE = (0.5, 4.0)
PX4_Z_VEL_MAX_UP_DEFAULT = 3.0  # multicopter_position_control_limits_params.c (range 0.5..8)
PX4_Z_VEL_MAX_DN_DEFAULT = 1.5  # (range 0.5..4)
PX4_MC_ALT_RAD_RANGE = (0.05, 200.0)  # NAV_MC_ALT_RAD (navigator_params.c; default 0.8 m)
# PX4 moves home's altitude in flight for this long after take-off (commander HomePosition.hpp
# kHomePositionCorrectionTimeWindow, COM_HOME_EN 1 the default): whenever the barometer and one raw GPS altitude
# sample disagree by more than 1 m, home is shifted by the difference, and every later mission altitude (relative to
# home) with it. Over 11 PX4 SIH flights home ended -1.51 .. +1.50 m off the ground (docs/FLIGHT.md).
PX4_HOME_CORRECTION_WINDOW_S = 120.0
PX4_MAX_CLIMB_M_S = 3.0  # MPC_Z_VEL_MAX_UP default: no take-off climbs faster

COMMAND_NAMES = {
    mi.MAV_CMD_NAV_WAYPOINT: "NAV_WAYPOINT", mi.MAV_CMD_NAV_RETURN_TO_LAUNCH: "NAV_RETURN_TO_LAUNCH",
    mi.MAV_CMD_NAV_LAND: "NAV_LAND", mi.MAV_CMD_NAV_TAKEOFF: "NAV_TAKEOFF", mi.MAV_CMD_DO_CHANGE_SPEED:
    "DO_CHANGE_SPEED", mi.MAV_CMD_DO_MOUNT_CONTROL: "DO_MOUNT_CONTROL", mi.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW:
    "DO_GIMBAL_MANAGER_PITCHYAW", mi.MAV_CMD_CONDITION_YAW: "CONDITION_YAW", MAV_CMD_NAV_LOITER_UNLIM:
    "NAV_LOITER_UNLIM", MAV_CMD_NAV_VTOL_TAKEOFF: "NAV_VTOL_TAKEOFF", MAV_CMD_NAV_VTOL_LAND: "NAV_VTOL_LAND",
}


def command_name(command: int) -> str:
    return COMMAND_NAMES.get(command, f"command {command}")


def check_autopilot(autopilot: str) -> None:
    if autopilot not in AUTOPILOTS:
        raise CompanionError(f"unknown autopilot flavour {autopilot!r}", "use 'px4' or 'ardupilot'")


@dataclass(frozen=True)
class ParamRefusal:
    """An item the firmware refuses at upload: ``param`` is 1-based (MAV_MISSION_INVALID_PARAM<param>)."""

    seq: int
    command: int
    param: int
    value: float

    def describe(self) -> str:
        return (f"item {self.seq} ({command_name(self.command)}) has param{self.param} = {self.value}, which "
                f"ArduPilot refuses (MAV_MISSION_INVALID_PARAM{self.param})")


def ardupilot_param_refusal(items: Sequence[mi.MissionItem]) -> ParamRefusal | None:
    """The first item ArduPilot would refuse for a NaN/inf param, as its mission code checks it; None if none."""
    for it in items:
        allowed = ARDUPILOT_NAN_ALLOWED.get(it.command, frozenset())
        for k, value in enumerate((it.param1, it.param2, it.param3, it.param4), start=1):
            if math.isinf(value) or (math.isnan(value) and k not in allowed):
                return ParamRefusal(it.seq, it.command, k, value)
    return None


def whole_seconds(hold_s: float) -> float:
    """ArduCopter keeps a waypoint hold as whole seconds (truncated): round up so a settle hold is never dropped."""
    return float(math.ceil(hold_s - 1e-9)) if hold_s > 0 else 0.0


def _vertical_scan_speed(plan) -> float | None:
    """The planned speed of scan legs that move vertically (vertical strips), or None when no scan leg climbs."""
    wps = plan.waypoints
    speeds = [wps[j].speed_m_s for i, j in plan.scan_legs if abs(wps[j].rel_alt_m - wps[i].rel_alt_m) > 0.05]
    return min(speeds) if speeds else None


def _scan_acceptance_m(plan) -> float:
    """The acceptance radius the plan gives the ends of its scan legs (the tightest one)."""
    return min(plan.waypoints[j].acceptance_m for _, j in plan.scan_legs)


def flight_parameters(plan, autopilot: str) -> dict[str, float]:
    """Every autopilot parameter the plan needs set for its flight (and restored after), by name.

    * ArduPilot: ``WP_YAW_BEHAVIOR = 0`` (never change yaw). Copter ignores NAV_WAYPOINT param4 and at every new
      waypoint resets its yaw mode to the WP_YAW_BEHAVIOR default (2: face the next waypoint), unless the yaw mode
      is ROI, or FIXED with WP_YAW_BEHAVIOR = 0 (ModeAuto::wp_start). The plan puts a CONDITION_YAW (FIXED, facing
      the wall) before every waypoint, which Copter re-asserts while it is the active do-command; with
      WP_YAW_BEHAVIOR = 0 the FIXED heading also persists across waypoints on its own, so the camera keeps facing
      the wall on every leg. Climb and descent speeds need no parameter: the plan sets them with DO_CHANGE_SPEED
      types 2 and 3, which Copter 4.7 honours.
    * PX4: ``MPC_Z_V_AUTO_UP`` and ``MPC_Z_V_AUTO_DN`` = the vertical scan speed, when scan legs move vertically.
      PX4 applies DO_CHANGE_SPEED to horizontal motion only (and reads param2 of any speed type as the horizontal
      cruise speed), so without them vertical strips fly at 3 m/s up, 1.5 m/s down (defaults; 2.66/1.77 m/s
      measured on PX4 SIH), several times the planned speed and the motion-blur budget. They also slow the
      descent of a landing above MPC_LAND_ALT1 and of an RTL to the scan speed, which is safe. PX4 honours
      NAV_WAYPOINT param4, so yaw needs no parameter. PX4 caps the auto speeds at MPC_Z_VEL_MAX_UP/DN: when the
      scan speed is above their defaults (3 / 1.5 m/s) they are raised to it too.
    * PX4: ``NAV_MC_ALT_RAD`` = the plan's scan acceptance radius (0.3 m), when scan legs move vertically. PX4
      accepts a multicopter waypoint within its acceptance radius (param2) horizontally but within NAV_MC_ALT_RAD
      (default 0.8 m) vertically (``MissionBlock::is_mission_item_reached``); no mission item can set the vertical
      one (``alt_acceptance_radius`` is NaN for mission items, ``mission_block.cpp``). So a vertical strip was
      accepted up to 0.8 m before its planned end, still moving, and turned there: real PX4 SIH turned the demo's
      last strip 0.5-0.8 m above its bottom, losing the wall's base from it. With the plan's radius PX4 accepts the
      strip's end where the plan means it to, in 3D as horizontally (real PX4 SIH: last strip 0.06 m early). Its
      trajectory already brakes to a stop in z at a strip end (the next leg is level or reverses), so the tighter
      radius is no hover: the real flights with it took no longer (docs/FLIGHT.md).

    Raises CompanionError when a needed value lies outside the range the firmware accepts.
    """
    check_autopilot(autopilot)
    if autopilot == "ardupilot":
        return {"WP_YAW_BEHAVIOR": 0.0}
    v = _vertical_scan_speed(plan)
    if v is None:
        return {}
    params = {}
    for name, (lo, hi) in (("MPC_Z_V_AUTO_UP", PX4_Z_V_AUTO_UP_RANGE), ("MPC_Z_V_AUTO_DN", PX4_Z_V_AUTO_DN_RANGE)):
        if not lo <= v <= hi:
            raise CompanionError(
                f"the vertical scan speed {v:.3f} m/s is outside PX4's {name} range {lo}..{hi} m/s",
                "change what limits the scan speed (camera.exposure_s, motion_blur_budget_px, max_speed_m_s) or "
                "fly pattern: horizontal, whose speed PX4 takes from the mission items",
            )
        params[name] = round(v, 3)
    lo, hi = PX4_MC_ALT_RAD_RANGE
    params["NAV_MC_ALT_RAD"] = round(min(max(_scan_acceptance_m(plan), lo), hi), 3)
    # PX4 caps the auto speeds at MPC_Z_VEL_MAX_UP/DN (MulticopterPositionControl.cpp): raise a cap only when the
    # scan speed is above its default, so a pilot taking over keeps the vehicle's normal limits otherwise.
    for name, default, (lo, hi) in (("MPC_Z_VEL_MAX_UP", PX4_Z_VEL_MAX_UP_DEFAULT, PX4_Z_V_AUTO_UP_RANGE),
                                    ("MPC_Z_VEL_MAX_DN", PX4_Z_VEL_MAX_DN_DEFAULT, PX4_Z_V_AUTO_DN_RANGE)):
        if v > default:
            params[name] = round(min(max(v, lo), hi), 3)
    return params

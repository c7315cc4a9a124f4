"""PX4 (main @ 02e73e3b6f, read from source and flown in SITL; ``../shared/notes/real-firmware.md``).

* Accepts NaN ("no change") in mission params, honours NAV_WAYPOINT param4 (yaw) and param2 (acceptance radius),
  and stores every item as sent (float32) except that yaw, kept in radians wrapped to [0, 2pi).
* Applies DO_CHANGE_SPEED param2 of *any* speed type to the horizontal cruise speed (navigator_main.cpp), so the
  climb/descent speed of a vertical strip is a parameter (MPC_Z_V_AUTO_UP/DN), set for the flight.
* Arms in Hold (AUTO_LOITER), not in Return nor in Mission without a valid mission; mission seq 0 is the take-off.
* Moves home's altitude for 120 s after take-off (commander HomePosition.hpp kHomePositionCorrectionTimeWindow,
  COM_HOME_EN 1 the default): whenever the barometer and one raw GPS altitude sample disagree by more than 1 m, home
  is shifted by the difference, and every later mission altitude (relative to home) with it. Over 11 PX4 SIH
  flights home ended -1.51 .. +1.50 m off the ground (docs/FLIGHT.md); in the window it swung by up to -2.36 /
  +2.78 m (22 flights' logs). The PX4 plan flies only waypoints ``PX4_HOME_MOVE_MAX_M`` + 1 m above home in the
  window and the part below after it (``planner.plan_scan``).
* Lost link: NAV_DLL_ACT (default 0: keeps flying the mission), return altitude RTL_RETURN_ALT in metres.
"""

from __future__ import annotations

from companion.errors import CompanionError
from companion.mission import items as mi
from companion.mission.autopilot.base import ArmingMode, Autopilot, FailsafeNames, LinkWatch, Row, StoredForm
from companion.mission.firmware import SPEED_TYPE_GROUND

MAV_AUTOPILOT_PX4 = 12
PX4_MAIN_AUTO, PX4_SUB_LOITER = 4, 3
# PX4 parameter ranges (multicopter_autonomous_params.c at 02e73e3b6f).
PX4_Z_V_AUTO_UP_RANGE = (0.5, 8.0)
PX4_Z_V_AUTO_DN_RANGE = (0.5, 4.0)
PX4_Z_VEL_MAX_UP_DEFAULT = 3.0  # multicopter_position_control_limits_params.c (range 0.5..8)
PX4_Z_VEL_MAX_DN_DEFAULT = 1.5  # (range 0.5..4)
PX4_MC_ALT_RAD_RANGE = (0.05, 200.0)  # NAV_MC_ALT_RAD (navigator_params.c; default 0.8 m)
PX4_HOME_CORRECTION_WINDOW_S = 120.0
# Position and velocity gains for a scan flight (defaults 0.95 and 1.8; ranges 0..2 and 1.2..5,
# multicopter_position_control_gain_params.c). Real PX4 SIH (2026-12-04, docs/FLIGHT.md "Re-measured 2026-12-04"),
# the demo's worst standoff error per flight: 0.293 / 0.284 m at the defaults; 0.171 / 0.160 / 0.215 / 0.204 m with
# 1.8 / 2.7; 0.193 / 0.149 / 0.160 / 0.149 m with 2.0 / 3.6. The error wanders about zero (per-strip std
# 0.073 -> 0.048 -> 0.042 m), so stiffer loops hold it closer. MPC_XY_P 2.0 is the top of PX4's range and the
# velocity gain twice its default: stiff for a real airframe tuned at the defaults, so they are set for the scan
# flight only and restored after it like the others.
PX4_SCAN_GAINS = {"MPC_XY_P": 2.0, "MPC_XY_VEL_P_ACC": 3.6}
# The furthest home is taken to move DOWN at any moment of that window, for the waypoints flown in it. Real PX4 SIH
# (22 flights' ULogs, tests/data/real-px4-sih-home.json): home's lowest in each window -0.57 .. -2.36 m, below -2.0 m
# for 0.02 % of the windows' time and never below -2.36 m; PX4 computes a waypoint's altitude from home when the
# waypoint becomes active, so it is the offset at that moment that counts. 2.5 m covers every move seen (the flight's
# home watch still ends the scan if a bigger one brings a waypoint of the window under 1 m above the ground).
PX4_HOME_MOVE_MAX_M = 2.5
PX4_MAX_CLIMB_M_S = 3.0  # MPC_Z_VEL_MAX_UP default: no take-off climbs faster
# the commands whose param4 PX4 keeps as a yaw in radians (and hands back in degrees, wrapped)
PX4_YAW_COMMANDS = frozenset({mi.MAV_CMD_NAV_WAYPOINT, mi.MAV_CMD_NAV_TAKEOFF, mi.MAV_CMD_NAV_LAND})


def _vertical_scan_speed(plan) -> float | None:
    """The planned speed of scan legs that move vertically (vertical strips), or None when no scan leg climbs."""
    wps = plan.waypoints
    speeds = [wps[j].speed_m_s for i, j in plan.scan_legs if abs(wps[j].rel_alt_m - wps[i].rel_alt_m) > 0.05]
    return min(speeds) if speeds else None


def _scan_acceptance_m(plan) -> float:
    """The acceptance radius the plan gives the ends of its scan legs (the tightest one)."""
    return min(plan.waypoints[j].acceptance_m for _, j in plan.scan_legs)


class Px4(Autopilot):
    flavour = "px4"
    label = "PX4"
    mav_autopilot = MAV_AUTOPILOT_PX4
    arming_mode = ArmingMode("Hold (AUTO_LOITER)", (PX4_MAIN_AUTO, PX4_SUB_LOITER))
    first_item_seq = 0
    home_correction_window_s = PX4_HOME_CORRECTION_WINDOW_S
    home_move_max_m = PX4_HOME_MOVE_MAX_M
    failsafe = FailsafeNames(
        "NAV_DLL_ACT", "RTL_RETURN_ALT", 1.0, {"rtl": 2, "land": 3},
        {0: "disabled (keeps flying the mission)", 1: "hold", 2: "return", 3: "land", 5: "terminate",
         6: "disarm"}, frozenset({0}))
    # a HEARTBEAT of type GCS from any system counts (MavlinkReceiver); COM_DLL_EXCEPT bit 0 ignores a lost link in
    # Mission, bit 1 in the other auto modes (commander_params.c): cleared for the flight
    link_watch = LinkWatch(exception_param="COM_DLL_EXCEPT", exception_bits=0b11)
    no_value = float("nan")
    plan_file_suffix = ""

    def home_rows(self, home) -> list[Row]:
        return []  # PX4 keeps home outside the mission

    def speed_rows(self, speed_m_s: float, moves_vertically: bool) -> list[Row]:
        # type 1 only: PX4 reads any type as the horizontal speed (the vertical one is a flight parameter)
        return [(mi.MAV_FRAME_MISSION, mi.MAV_CMD_DO_CHANGE_SPEED, SPEED_TYPE_GROUND, speed_m_s, -1, 0, 0, 0, 0)]

    def waypoint_rows(self, wp, hold_s: float) -> list[Row]:
        # PX4 honours the acceptance radius (param2) and the yaw (param4): the heading needs no other item
        return [(mi.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, mi.MAV_CMD_NAV_WAYPOINT, hold_s, wp.acceptance_m, 0,
                 wp.yaw_deg, wp.lat, wp.lon, wp.rel_alt_m)]

    def param_refusal(self, items):
        return None  # PX4 takes NaN in any param

    def stored_form(self, item: mi.MissionItem) -> StoredForm:
        """Everything as sent (float32; NaN stays NaN), except the yaw of NAV_WAYPOINT / TAKEOFF / LAND, kept in
        radians wrapped to [0, 2pi) (359.99991 comes back 359.99988; -10 would come back 350): compared as a
        heading."""
        yaw = frozenset({"param4"}) if item.command in PX4_YAW_COMMANDS else frozenset()
        return StoredForm(item.frame, heading_params=yaw)

    def flight_parameters(self, plan) -> dict[str, float]:
        """``MPC_Z_V_AUTO_UP`` / ``MPC_Z_V_AUTO_DN`` = the vertical scan speed, and ``NAV_MC_ALT_RAD`` = the scan's
        acceptance radius, when scan legs move vertically; ``MPC_Z_VEL_MAX_UP/DN`` raised to that speed when it is
        above their defaults.

        Why: PX4 applies DO_CHANGE_SPEED to horizontal motion only, so without them vertical strips fly at 3 m/s up,
        1.5 m/s down (defaults; 2.66/1.77 m/s measured on PX4 SIH), several times the planned speed and the
        motion-blur budget; they also slow the descent of a landing above MPC_LAND_ALT1 and of an RTL to the scan
        speed, which is safe. PX4 accepts a multicopter waypoint within its acceptance radius (param2) horizontally
        but within NAV_MC_ALT_RAD (default 0.8 m) vertically (``MissionBlock::is_mission_item_reached``), which no
        mission item can set: a vertical strip was accepted up to 0.8 m before its planned end, still moving, and
        turned there, losing the wall's base from the last strip. With the plan's radius PX4 accepts the strip's
        end where the plan means it to (its trajectory brakes to a stop in z there anyway: no longer flights). PX4
        caps the auto speeds at MPC_Z_VEL_MAX_UP/DN, so those are raised only when the scan speed is above their
        defaults: a pilot taking over keeps the vehicle's normal limits otherwise. Yaw needs no parameter.

        ``PX4_SCAN_GAINS`` (MPC_XY_P 2.0, MPC_XY_VEL_P_ACC 3.6) with them: on real PX4 SIH the standoff on the strips
        wandered about zero by up to 0.29 m at the default gains and under 0.2 m with these (measured on vertical
        strips only, so set for those only); restored after the flight like the others."""
        v = _vertical_scan_speed(plan)
        if v is None:
            return {}
        params = {}
        for name, (lo, hi) in (("MPC_Z_V_AUTO_UP", PX4_Z_V_AUTO_UP_RANGE), ("MPC_Z_V_AUTO_DN", PX4_Z_V_AUTO_DN_RANGE)):
            if not lo <= v <= hi:
                raise CompanionError(
                    f"the vertical scan speed {v:.3f} m/s is outside PX4's {name} range {lo}..{hi} m/s",
                    "change what limits the scan speed (camera.exposure_s, motion_blur_budget_px, max_speed_m_s) "
                    "or fly pattern: horizontal, whose speed PX4 takes from the mission items",
                )
            params[name] = round(v, 3)
        lo, hi = PX4_MC_ALT_RAD_RANGE
        params["NAV_MC_ALT_RAD"] = round(min(max(_scan_acceptance_m(plan), lo), hi), 3)
        for name, default, (lo, hi) in (("MPC_Z_VEL_MAX_UP", PX4_Z_VEL_MAX_UP_DEFAULT, PX4_Z_V_AUTO_UP_RANGE),
                                        ("MPC_Z_VEL_MAX_DN", PX4_Z_VEL_MAX_DN_DEFAULT, PX4_Z_V_AUTO_DN_RANGE)):
            if v > default:
                params[name] = round(min(max(v, lo), hi), 3)
        params.update(PX4_SCAN_GAINS)
        return params

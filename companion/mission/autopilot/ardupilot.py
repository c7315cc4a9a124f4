"""ArduPilot (ArduCopter 4.7.0-dev @ 2598e9d4, read from source and checked against real SITL downloads in
``../shared/data/real-firmware/``; notes in ``../shared/notes/real-firmware.md`` and ``ardupilot-with-mavsdk4.md``).

* ``AP_Mission::sanity_check_params`` refuses NaN in any param except param4 of NAV_WAYPOINT / NAV_LOITER_UNLIM /
  NAV_LAND / NAV_TAKEOFF / NAV_VTOL_TAKEOFF and params 3/4 of NAV_VTOL_LAND (and +/-inf everywhere), answering
  MAV_MISSION_INVALID_PARAMn at the first offending item.
* Keeps home at mission seq 0 (whatever is uploaded there): the mission proper starts at 1.
* NAV_WAYPOINT keeps only param1 (hold) as whole seconds, truncated; the heading comes from WP_YAW_BEHAVIOR or
  CONDITION_YAW, not param4. DO_CHANGE_SPEED honours types 0/1 (horizontal), 2 (climb) and 3 (descent).
* Arms in GUIDED (mavsdk's ``arm()`` switches to BRAKE first, where Copter refuses).
* Keeps home where it armed (no in-flight correction).
* Lost link: FS_GCS_ENABLE (default 0: keeps flying the AUTO mission), return altitude RTL_ALT in centimetres
  (default 1500: 15 m, below the demo's 18 m transit altitude).
"""

from __future__ import annotations

import math

from companion.mission import items as mi
from companion.mission.autopilot.base import (
    ArmingMode,
    Autopilot,
    FailsafeNames,
    LinkWatch,
    Row,
    StoredForm,
    nan_refusal,
)
from companion.mission.firmware import (
    LOCATION_COMMANDS,
    MAV_CMD_NAV_LOITER_UNLIM,
    MAV_CMD_NAV_VTOL_LAND,
    MAV_CMD_NAV_VTOL_TAKEOFF,
    SPEED_TYPE_CLIMB,
    SPEED_TYPE_DESCENT,
    SPEED_TYPE_GROUND,
)

MAV_AUTOPILOT_ARDUPILOTMEGA = 3
ARDUCOPTER_GUIDED = 4
# Which params (1-based) may hold NaN, per command (AP_Mission::sanity_check_params).
ARDUPILOT_NAN_ALLOWED: dict[int, frozenset[int]] = {
    mi.MAV_CMD_NAV_WAYPOINT: frozenset({4}),
    MAV_CMD_NAV_LOITER_UNLIM: frozenset({4}),
    mi.MAV_CMD_NAV_LAND: frozenset({4}),
    mi.MAV_CMD_NAV_TAKEOFF: frozenset({4}),
    MAV_CMD_NAV_VTOL_TAKEOFF: frozenset({4}),
    MAV_CMD_NAV_VTOL_LAND: frozenset({3, 4}),
}
ARDUPILOT_FLOAT_FRAME = {mi.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT: mi.MAV_FRAME_GLOBAL_RELATIVE_ALT,
                         mi.MAV_FRAME_GLOBAL_INT: mi.MAV_FRAME_GLOBAL}


def whole_seconds(hold_s: float) -> float:
    """ArduCopter keeps a waypoint hold as whole seconds (truncated): round up so a settle hold is never dropped."""
    return float(math.ceil(hold_s - 1e-9)) if hold_s > 0 else 0.0


def _whole(value: float) -> float:
    """A float param kept in an integer field: truncated towards zero."""
    return float(math.trunc(value)) if math.isfinite(value) else value


def _stored_params(s: mi.MissionItem) -> dict[str, tuple[float, str]]:
    """Expected stored params (and the rule's wording) for commands ArduPilot does not store as sent."""
    cmd = s.command
    if cmd == mi.MAV_CMD_NAV_WAYPOINT:
        return {"param1": (_whole(s.param1), "ArduCopter keeps the hold in whole seconds, truncated"),
                "param2": (0.0, "not stored by ArduCopter"), "param3": (0.0, "not stored by ArduCopter"),
                "param4": (0.0, "not stored by ArduCopter")}
    if cmd == mi.MAV_CMD_NAV_TAKEOFF:
        return {"param1": (_whole(s.param1), "stored as a whole number"), "param2": (0.0, "not stored"),
                "param3": (0.0, "not stored"), "param4": (0.0, "not stored")}
    if cmd == mi.MAV_CMD_NAV_LAND:
        return {"param1": (_whole(s.param1), "stored as a whole number"), "param2": (0.0, "not stored"),
                "param3": (0.0, "not stored"),
                "param4": (-1.0 if s.param4 < 0 else 1.0, "ArduCopter keeps only a direction flag")}
    if cmd == mi.MAV_CMD_CONDITION_YAW:
        return {"param3": (_whole(s.param3), "stored as an integer"),
                "param4": (_whole(s.param4), "stored as an integer")}
    if cmd == mi.MAV_CMD_DO_CHANGE_SPEED:
        return {"param1": (_whole(s.param1), "stored as an integer"), "param4": (0.0, "not stored")}
    return {}


class ArduPilot(Autopilot):
    flavour = "ardupilot"
    label = "ArduPilot"
    mav_autopilot = MAV_AUTOPILOT_ARDUPILOTMEGA
    arming_mode = ArmingMode("GUIDED", (ARDUCOPTER_GUIDED,))
    first_item_seq = 1
    home_correction_window_s = 0.0
    failsafe = FailsafeNames(
        "FS_GCS_ENABLE", "RTL_ALT", 100.0, {"rtl": 1, "land": 5},
        {0: "disabled (keeps flying the mission)", 1: "RTL", 2: "continue the AUTO mission", 3: "SmartRTL or RTL",
         4: "SmartRTL or land", 5: "land", 6: "DO_LAND_START or RTL", 7: "brake or land"}, frozenset({0, 2}))
    # Copter::failsafe_gcs_check counts only HEARTBEATs from MAV_GCS_SYSID (SYSID_MYGCS before 4.7; default 255) or
    # the range up to MAV_GCS_SYSID_HI; the companion sends from mavsdk's 245 (issue 31)
    link_watch = LinkWatch(gcs_id_params=("MAV_GCS_SYSID", "SYSID_MYGCS"), gcs_id_hi_param="MAV_GCS_SYSID_HI")
    no_value = 0.0  # refused as NaN outside the params above (the gimbal's rates, take-off and land yaw become 0)
    plan_file_suffix = "-ardupilot"

    def home_rows(self, home) -> list[Row]:
        return [(mi.MAV_FRAME_GLOBAL, mi.MAV_CMD_NAV_WAYPOINT, 0, 0, 0, 0, home.lat, home.lon, home.alt_amsl_m)]

    def speed_rows(self, speed_m_s: float, moves_vertically: bool) -> list[Row]:
        """Types 2 and 3 give the planned climb/descent speed wherever a leg at this speed moves vertically."""
        rows = [(mi.MAV_FRAME_MISSION, mi.MAV_CMD_DO_CHANGE_SPEED, SPEED_TYPE_GROUND, speed_m_s, -1, 0, 0, 0, 0)]
        if moves_vertically:
            rows += [(mi.MAV_FRAME_MISSION, mi.MAV_CMD_DO_CHANGE_SPEED, speed_type, speed_m_s, -1, 0, 0, 0, 0)
                     for speed_type in (SPEED_TYPE_CLIMB, SPEED_TYPE_DESCENT)]
        return rows

    def waypoint_rows(self, wp, hold_s: float) -> list[Row]:
        """A CONDITION_YAW facing the wall before every waypoint (absolute heading, shortest turn, default slew
        rate: Copter ignores NAV_WAYPOINT param4, so params 2-4 are sent as the 0 it stores); the hold in whole
        seconds, rounded up."""
        return [(mi.MAV_FRAME_MISSION, mi.MAV_CMD_CONDITION_YAW, wp.yaw_deg % 360.0, 0, 0, 0, 0, 0, 0),
                (mi.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, mi.MAV_CMD_NAV_WAYPOINT, whole_seconds(hold_s), 0, 0, 0,
                 wp.lat, wp.lon, wp.rel_alt_m)]

    def param_refusal(self, items):
        return nan_refusal(items, ARDUPILOT_NAN_ALLOWED, self.label)

    def stored_form(self, item: mi.MissionItem) -> StoredForm:
        """Home (seq 0) is the vehicle's own; located commands come back in the float frame twins with the altitude
        truncated to whole centimetres, everything else in frame 0; params as ``_stored_params`` says."""
        if item.seq == 0:
            return StoredForm(item.frame, compared=False)
        located = item.command in LOCATION_COMMANDS  # AP_Mission::stored_in_location
        frame = ARDUPILOT_FLOAT_FRAME.get(item.frame, item.frame) if located else mi.MAV_FRAME_GLOBAL
        return StoredForm(frame, z_truncated_cm=located, params=_stored_params(item))

    def flight_parameters(self, plan) -> dict[str, float]:
        """``WP_YAW_BEHAVIOR = 0`` (never change yaw). Copter ignores NAV_WAYPOINT param4 and at every new waypoint
        resets its yaw mode to the WP_YAW_BEHAVIOR default (2: face the next waypoint), unless the yaw mode is ROI,
        or FIXED with WP_YAW_BEHAVIOR = 0 (ModeAuto::wp_start). The plan puts a CONDITION_YAW (FIXED, facing the
        wall) before every waypoint, which Copter re-asserts while it is the active do-command; with
        WP_YAW_BEHAVIOR = 0 the FIXED heading also persists across waypoints on its own, so the camera keeps facing
        the wall on every leg. Climb and descent speeds need no parameter: the plan sets them with DO_CHANGE_SPEED
        types 2 and 3, which Copter 4.7 honours."""
        return {"WP_YAW_BEHAVIOR": 0.0}

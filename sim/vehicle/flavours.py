"""What differs between a PX4-like and an ArduCopter-like autopilot, in one place: the rest of the simulator asks
the flavour (``vehicle.flavour``) and never compares its name, so a third flavour is one more class here (a subclass
of the one it behaves like) and its entry in ``FLAVOURS``.

Mode encodings follow what mavsdk 4.1 decodes: PX4 packs main mode in bits 16-23 and sub mode in bits 24-31 of
HEARTBEAT.custom_mode; ArduCopter uses its mode number. The ArduPilot flavour reproduces the behaviours listed in
/work/shared/notes/ardupilot-with-mavsdk4.md (seq 0 = home, NaN takeoff params refused, no telemetry streams until
asked, BRAKE refuses arming, AUTO refused on the ground without a takeoff item).
"""

from __future__ import annotations

import math
import struct
from pathlib import Path

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink  # common + ArduPilot messages

from companion.mission import items as mi

# Internal mode names used by the autopilot.
HOLD, TAKEOFF, MISSION, RTL, LAND, POSCTL, GUIDED, BRAKE = "hold", "takeoff", "mission", "rtl", "land", "posctl", \
    "guided", "brake"

PX4_MAIN = {"manual": 1, "altctl": 2, "posctl": 3, "auto": 4, "acro": 5, "offboard": 6, "stabilized": 7}
PX4_AUTO_SUB = {"ready": 1, "takeoff": 2, "loiter": 3, "mission": 4, "rtl": 5, "land": 6}
_PX4_MODES = {
    HOLD: (4, 3), TAKEOFF: (4, 2), MISSION: (4, 4), RTL: (4, 5), LAND: (4, 6), POSCTL: (3, 0), GUIDED: (6, 0),
    BRAKE: (4, 3),
}
_COPTER_MODES = {HOLD: 5, GUIDED: 4, MISSION: 3, RTL: 6, LAND: 9, BRAKE: 17, POSCTL: 16, TAKEOFF: 4}
_COPTER_FROM_NUMBER = {0: POSCTL, 2: POSCTL, 3: MISSION, 4: GUIDED, 5: HOLD, 6: RTL, 9: LAND, 16: POSCTL, 17: BRAKE}

SUPPORTED_COMMANDS = {
    mi.MAV_CMD_NAV_WAYPOINT, mi.MAV_CMD_NAV_TAKEOFF, mi.MAV_CMD_NAV_LAND, mi.MAV_CMD_NAV_RETURN_TO_LAUNCH,
    mi.MAV_CMD_DO_CHANGE_SPEED, mi.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW, mi.MAV_CMD_DO_MOUNT_CONTROL,
    mi.MAV_CMD_CONDITION_YAW,
}
NAV_COMMANDS = {mi.MAV_CMD_NAV_WAYPOINT, mi.MAV_CMD_NAV_TAKEOFF, mi.MAV_CMD_NAV_LAND}
GLOBAL_FRAMES = {mi.MAV_FRAME_GLOBAL, mi.MAV_FRAME_GLOBAL_RELATIVE_ALT, mi.MAV_FRAME_GLOBAL_INT,
                 mi.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT}
SUPPORTED_FRAMES = GLOBAL_FRAMES | {mi.MAV_FRAME_MISSION}

# ArduPilot's per-command NaN mask (AP_Mission::sanity_check_params, ArduCopter 4.7): 1-based params that may be NaN.
_COPTER_NAN_OK = {16: {4}, 17: {4}, 21: {4}, 22: {4}, 84: {4}, 85: {3, 4}}
_COPTER_INVALID_PARAM = {1: mavlink.MAV_MISSION_INVALID_PARAM1, 2: mavlink.MAV_MISSION_INVALID_PARAM2,
                         3: mavlink.MAV_MISSION_INVALID_PARAM3, 4: mavlink.MAV_MISSION_INVALID_PARAM4}
# Commands ArduPilot stores with a location (AP_Mission::stored_in_location; the ones the simulator flies).
_COPTER_LOCATED = {mi.MAV_CMD_NAV_WAYPOINT, mi.MAV_CMD_NAV_TAKEOFF, mi.MAV_CMD_NAV_LAND}
_F32 = np.float32
# The profiles a flight on each flavour passes to `companion fly --sitl-profile` (companion/flight/sitl_profile.py)
SITL_PROFILES = Path(__file__).resolve().parents[1] / "sitl"
COPTER_PREARM_NO_POSITION = "PreArm: Need Position Estimate"
COPTER_PREARM_GCS_FAILSAFE = "PreArm: GCS failsafe on"  # AP_Arming_Copter::gcs_failsafe_check
# PX4 keeps a GCS heartbeat alive this long (telemetry_status HEARTBEAT_TIMEOUT_US) before COM_DL_LOSS_T starts
PX4_HEARTBEAT_ALIVE_S = 2.5
# ArduPilot: these messages from a GCS system id reset the GCS failsafe timer (GCS_Common.cpp sysid_mygcs_seen)
COPTER_GCS_ALIVE_MESSAGES = frozenset({"HEARTBEAT", "RC_CHANNELS_OVERRIDE", "MANUAL_CONTROL"})
PX4_DLL_EXCEPT_MISSION, PX4_DLL_EXCEPT_AUTO = 1, 2  # COM_DLL_EXCEPT bits (commander_params.c)
# The SITL's own truth messages (libraries/SITL/SITL.cpp sim_state_send / simstate_send)
SIM_STATE_MESSAGES = ("SIM_STATE", "SIMSTATE")


def _validate_common(item: mi.MissionItem) -> int | None:
    if item.command not in SUPPORTED_COMMANDS:
        return mavlink.MAV_MISSION_UNSUPPORTED
    if item.frame not in SUPPORTED_FRAMES:
        return mavlink.MAV_MISSION_UNSUPPORTED_FRAME
    if item.command in NAV_COMMANDS and item.frame in GLOBAL_FRAMES:
        land_here = item.command in (mi.MAV_CMD_NAV_LAND, mi.MAV_CMD_NAV_TAKEOFF) and item.x == 0 and item.y == 0
        if not land_here and not -90e7 <= item.x <= 90e7:
            return mavlink.MAV_MISSION_INVALID_PARAM5_X
        if not land_here and not -180e7 <= item.y <= 180e7:
            return mavlink.MAV_MISSION_INVALID_PARAM6_Y
        if not math.isfinite(item.z):
            return mavlink.MAV_MISSION_INVALID_PARAM7
    if item.command == mi.MAV_CMD_NAV_WAYPOINT and (item.param1 < 0 or item.param2 < 0):
        return mavlink.MAV_MISSION_INVALID_PARAM1 if item.param1 < 0 else mavlink.MAV_MISSION_INVALID_PARAM2
    return None


class Px4:
    name = "px4"
    autopilot = mavlink.MAV_AUTOPILOT_PX4
    first_seq = 0
    max_mission_items = 500  # a larger MISSION_COUNT is refused with NO_SPACE
    too_many_items_text: str | None = None  # STATUSTEXT (WARNING) after that refusal, {n} = the limit
    # STATUSTEXT (CRITICAL) before the ACK that refuses an item (PX4 MavlinkMissionManager::handle_mission_item:
    # "IGN MISSION_ITEM: Invalid item", tab-terminated like all PX4 mavlink_log texts); ArduPilot says nothing
    invalid_item_text: str | None = "IGN MISSION_ITEM: Invalid item\t"
    # COMMAND_ACK of a refused mode change (Commander::handle_command DO_SET_MODE / MISSION_START)
    mode_refused_result = mavlink.MAV_RESULT_TEMPORARILY_REJECTED
    param_bytewise = True
    # SIM_STATE / SIMSTATE on request: PX4 SIH has no such stream (its ground truth goes out, if at all, as
    # HIL_STATE_QUATERNION in the GROUND_TRUTH stream), so the PX4 flavour refuses them as unsupported
    sim_state = False
    default_rates_hz = {
        "HEARTBEAT": 1.0, "SYS_STATUS": 1.0, "GPS_RAW_INT": 5.0, "GLOBAL_POSITION_INT": 10.0,
        "LOCAL_POSITION_NED": 10.0, "ATTITUDE": 20.0, "ATTITUDE_QUATERNION": 20.0, "HOME_POSITION": 0.5,
        "EXTENDED_SYS_STATE": 2.0, "BATTERY_STATUS": 1.0, "MISSION_CURRENT": 1.0, "VFR_HUD": 4.0,
        "GIMBAL_DEVICE_ATTITUDE_STATUS": 5.0,
        "DISTANCE_SENSOR": 10.0,  # sent only with --rangefinder
    }
    params = {
        "MIS_TAKEOFF_ALT": 2.5, "RTL_RETURN_ALT": 15.0, "RTL_DESCEND_ALT": 10.0, "MPC_XY_CRUISE": 5.0,
        "MPC_XY_VEL_MAX": 12.0, "MPC_Z_VEL_MAX_UP": 3.0, "MPC_Z_VEL_MAX_DN": 1.5, "MPC_LAND_SPEED": 0.7,
        "MPC_ACC_HOR": 4.0, "MPC_YAWRAUTO_MAX": 60.0, "NAV_ACC_RAD": 2.0, "COM_DL_LOSS_T": 10, "NAV_DLL_ACT": 2,
        "COM_DISARM_LAND": 2.0, "BAT_LOW_THR": 0.15, "MIS_YAWMODE": 0, "MPC_Z_V_AUTO_UP": 3.0,
        "MPC_Z_V_AUTO_DN": 1.5, "NAV_MC_ALT_RAD": 0.8,
        "MPC_XY_P": 0.95, "MPC_XY_VEL_P_ACC": 1.8,  # held, not flown by: the model tracks its path as tuned
        # PX4 SIH SITL as it boots (SYS_AUTOSTART 10040, init.d-posix/rcS: CAL_*_ID = SIH's simulated IMU, device id
        # 1310988 = DRV_IMU_DEVTYPE_SIM on bus type SIMULATION) with EKF2's default sensor noise (ekf2 module.yaml).
        # A real vehicle: --params CAL_ACC0_ID=<its IMU's id>,CAL_GYRO0_ID=...,SYS_AUTOSTART=<its airframe>.
        "SYS_AUTOSTART": 10040, "SYS_HITL": 0, "CAL_ACC0_ID": 1310988, "CAL_GYRO0_ID": 1310988,
        "EKF2_ACC_NOISE": 0.35, "EKF2_GYR_NOISE": 0.015, "EKF2_BARO_NOISE": 3.5,
    }
    waypoint_reached_m: float | None = None  # None: the item's acceptance radius (param2), else NAV_ACC_RAD
    # what this flavour's flights ask `companion fly` for (SIH's estimator noise, home put back): the simulator
    # boots as PX4 SIH does, so it needs what real SIH needs (sim/sitl/px4-sih.yaml); None: nothing
    sitl_profile: Path | None = SITL_PROFILES / "px4-sih.yaml"

    # --- boot, modes and start-up --------------------------------------------------------------------------
    boot_mode = HOLD  # the mode after (re)boot
    after_takeoff_mode = HOLD  # the mode a finished TAKEOFF command leaves the vehicle in
    sw_version = (1 << 24) | (15 << 16) | (0 << 8) | 255  # AUTOPILOT_VERSION flight_sw_version (1.15.0 release)
    # Real defaults (PX4 main 2026-03: commander/navigator params).
    failsafe_defaults = {"NAV_DLL_ACT": 0, "COM_DL_LOSS_T": 10, "RTL_RETURN_ALT": 30.0, "COM_DISARM_PRFLT": 10.0,
                         "GF_MAX_HOR_DIST": 0.0, "COM_DLL_EXCEPT": 0}
    # Simulated seconds after boot before the estimator uses GPS (ArduCopter 4.7 SITL: 35-40 s; PX4 SIH: a few).
    gps_ready_after_s = 0.0
    # Wall seconds from (re)boot until the autopilot has initialised (PX4 SITL answers from its first heartbeat).
    init_wall_s = 0.0
    ready_text: str | None = None  # STATUSTEXT once initialised
    no_position_text = "Preflight Fail: No position"  # pre-arm refusal before the estimator uses GPS
    gcs_failsafe_prearm_text: str | None = None  # pre-arm refusal while the lost-link failsafe is on (None: arms)
    # --- what PX4 does and ArduCopter does not (firmware.py) ----------------------------------------------
    refuses_arming_without_valid_mission = True  # in Mission mode: "Arming denied: no valid mission"
    keeps_current_on_identical_upload = True  # the current item survives an upload of the same mission
    keeps_current_on_reboot = True  # ... and a restart (dataman), like the mission itself
    persistent_storage = True  # --storage: the mission survives a restart of the simulator process
    checks_geofence_at_start = True  # a mission beyond GF_MAX_HOR_DIST is refused at its start
    moves_home_in_flight = True  # HomePosition's 120 s correction (home_drift.py); home set again at arming
    command_int_frames: frozenset[int] | None = frozenset({mavlink.MAV_FRAME_GLOBAL_INT})  # None: any frame
    copter_yaw = False  # True: yaw from WP_YAW_BEHAVIOR and CONDITION_YAW (copter_yaw.py), not NAV_WAYPOINT param4

    def auto_climb_m_s(self, v) -> float:
        """Climb speed of mission legs: MPC_Z_V_AUTO_UP capped by MPC_Z_VEL_MAX_UP."""
        return min(v.param("MPC_Z_V_AUTO_UP", 3.0), v.param("MPC_Z_VEL_MAX_UP", 3.0))

    def auto_descent_m_s(self, v) -> float:
        """Descent speed of mission legs: MPC_Z_V_AUTO_DN capped by MPC_Z_VEL_MAX_DN."""
        return min(v.param("MPC_Z_V_AUTO_DN", 1.5), v.param("MPC_Z_VEL_MAX_DN", 1.5))

    def land_speed_m_s(self, v) -> float:
        return v.param("MPC_LAND_SPEED", 0.7)

    def takeoff_alt_m(self, v) -> float:
        return v.param("MIS_TAKEOFF_ALT", 2.5)

    def rtl_alt_m(self, v) -> float:
        return v.param("RTL_RETURN_ALT", 15.0)

    def change_speed(self, v, speed_type: int, speed: float) -> None:
        """DO_CHANGE_SPEED: PX4 applies param2 of any type to the horizontal cruise speed (navigator_main.cpp)."""
        v.cruise_m_s = min(float(speed), v.limits.max_speed_h_m_s)

    def takeoff_command(self, v, param7: float) -> str | None:
        """MAV_CMD_NAV_TAKEOFF: its altitude (param7, AMSL) becomes the take-off height. The refusal, or None."""
        if math.isfinite(param7):
            v.params["MIS_TAKEOFF_ALT"] = float(param7) - v.cfg.home.alt_amsl_m
        return None

    def link_loss_timeout_s(self, params: dict) -> float:
        """Seconds from the last counted heartbeat to the failsafe: COM_DL_LOSS_T (default 10) after the heartbeat's
        own 2.5 s (Commander::dataLinkCheck)."""
        return float(params.get("COM_DL_LOSS_T", 10.0)) + PX4_HEARTBEAT_ALIVE_S

    def counts_for_link_failsafe(self, params: dict, msg, own_system: int) -> bool:
        """Whether ``msg`` keeps the lost-link failsafe from firing (``MavlinkReceiver::handle_message_heartbeat``):
        a HEARTBEAT of type MAV_TYPE_GCS from any system, or any HEARTBEAT from its own system id."""
        return msg.get_type() == "HEARTBEAT" and (msg.type == mavlink.MAV_TYPE_GCS or msg.get_srcSystem() == own_system)

    def lost_link_ignored(self, params: dict, mode: str) -> bool:
        """A lost link is ignored in Mission with COM_DLL_EXCEPT bit 0, in the other auto modes with bit 1
        (``Failsafe::isFailsafeIgnored``)."""
        bits = int(params.get("COM_DLL_EXCEPT", 0))
        if mode == MISSION:
            return bool(bits & PX4_DLL_EXCEPT_MISSION)
        return mode in (HOLD, TAKEOFF, RTL, LAND) and bool(bits & PX4_DLL_EXCEPT_AUTO)

    def lost_link_action(self, params: dict) -> str | None:
        """NAV_DLL_ACT: 0 disabled, 1 hold, 2 return, 3 land, 5 terminate, 6 disarm ('rtl', 'land', 'hold' or None:
        flies on)."""
        return {1: "hold", 2: "rtl", 3: "land"}.get(int(params.get("NAV_DLL_ACT", 0)))

    def custom_mode(self, mode: str) -> int:
        main, sub = _PX4_MODES[mode]
        return (main << 16) | (sub << 24)

    def mode_from_set_mode(self, base: float, main: float, sub: float) -> str | None:
        if not math.isfinite(base) or not int(base) & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
            return None
        main, sub = (int(v) if math.isfinite(v) else 0 for v in (main, sub))
        if main == PX4_MAIN["auto"]:
            return {3: HOLD, 2: TAKEOFF, 4: MISSION, 5: RTL, 6: LAND}.get(sub)
        if main in (PX4_MAIN["posctl"], PX4_MAIN["altctl"], PX4_MAIN["manual"], PX4_MAIN["stabilized"]):
            return POSCTL
        if main == PX4_MAIN["offboard"]:
            return GUIDED
        return None

    def validate(self, item: mi.MissionItem, index: int) -> int | None:
        return _validate_common(item)

    def arm_refusal(self, mode: str) -> str | None:
        return None if mode in (HOLD, POSCTL, TAKEOFF, MISSION, GUIDED) else f"arming not allowed in {mode}"

    def ground_start_refusal(self, items: list) -> list[tuple[int, str]]:
        """The STATUSTEXTs (severity, text) with which the firmware refuses to start ``items`` on the ground."""
        return []

    def transform_upload(self, items: list, home_item: mi.MissionItem) -> list:
        return [px4_stored_item(it) for it in items]

    def transform_download(self, items: list, home_item: mi.MissionItem) -> list:
        return [_with_current(it, 1 if k == 0 else 0) for k, it in enumerate(items)]

    def encode_param(self, value) -> tuple[float, int]:
        if isinstance(value, int):
            if self.param_bytewise:
                return struct.unpack("<f", struct.pack("<i", value))[0], mavlink.MAV_PARAM_TYPE_INT32
            return float(value), mavlink.MAV_PARAM_TYPE_INT32
        return float(value), mavlink.MAV_PARAM_TYPE_REAL32

    def decode_param(self, raw: float, ptype: int, old):
        if isinstance(old, int):
            if self.param_bytewise:
                return struct.unpack("<i", struct.pack("<f", raw))[0]
            return int(round(raw))
        return float(raw)


class ArduCopter(Px4):
    name = "ardupilot"
    autopilot = mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA
    first_seq = 1
    param_bytewise = False
    # ArduPilot SITL sends SIM_STATE only when asked (SET_MESSAGE_INTERVAL; no stream group has it) and SIMSTATE
    # in the EXTRA1 stream (GCS_MAVLink_Parameters.cpp), whose Copter rate SR0_EXTRA1 is 0 by default: so neither
    # flows until asked, like everything else here
    sim_state = True
    default_rates_hz = {"HEARTBEAT": 1.0}
    # real ArduCopter 4.7.0-dev SITL refused a 1628-item upload with NO_SPACE, then said "Only 650 items are
    # supported" (MissionItemProtocol::handle_mission_count: ack first, then the text)
    max_mission_items = 650
    too_many_items_text = "Only {n} items are supported"
    invalid_item_text = None  # MissionItemProtocol::handle_mission_item acks the refusal without a text
    mode_refused_result = mavlink.MAV_RESULT_FAILED  # GCS_MAVLINK::_set_mode_common: set_mode() false -> FAILED
    params = {
        "WPNAV_SPEED": 500.0, "WPNAV_SPEED_UP": 250.0, "WPNAV_SPEED_DN": 150.0, "WPNAV_RADIUS": 200.0,
        "WP_YAW_BEHAVIOR": 2,
        "WPNAV_ACCEL": 400.0, "LAND_SPEED": 70.0, "RTL_ALT": 1500.0, "PILOT_TKOFF_ALT": 250.0, "FS_GCS_ENABLE": 1,
        "FS_GCS_TIMEOUT": 10.0, "SR0_POSITION": 0, "SR0_EXTRA1": 0, "SR0_EXT_STAT": 0,
    }
    # Copter keeps no acceptance radius per waypoint; its S-curve target reaches the waypoint and the vehicle trails
    # it by a few decimetres before the next leg starts.
    waypoint_reached_m = 0.3
    sitl_profile = None  # ArduCopter SITL takes the companion's flight as a real Copter does
    boot_mode = POSCTL
    after_takeoff_mode = GUIDED
    sw_version = (4 << 24) | (6 << 16) | 255
    # ArduCopter 4.7 Parameters.cpp; MAV_GCS_SYSID: the only source system whose heartbeats the GCS failsafe counts
    # (GCS.cpp). No MAV_GCS_SYSID_HI: real ArduCopter V4.7.0-dev SITL (2598e9d4) has none and leaves a read of it
    # unanswered (the companion's read timed out); a later firmware's range is what the companion's rule still reads
    failsafe_defaults = {"FS_GCS_ENABLE": 0, "FS_GCS_TIMEOUT": 5.0, "RTL_ALT": 1500, "MAV_GCS_SYSID": 255}
    gps_ready_after_s = 38.0
    # Real ArduCopter 4.7 SITL (-w, wiped storage): its first words ("ArduPilot Ready") came about 1 s after the first
    # heartbeat at speed-up 1 and at 5 alike, so the start-up is wall time (storage and sensor set-up).
    init_wall_s = 1.0
    ready_text = "ArduPilot Ready"
    no_position_text = COPTER_PREARM_NO_POSITION
    gcs_failsafe_prearm_text = COPTER_PREARM_GCS_FAILSAFE
    refuses_arming_without_valid_mission = False
    keeps_current_on_identical_upload = False
    keeps_current_on_reboot = False
    persistent_storage = False
    checks_geofence_at_start = False
    moves_home_in_flight = False
    command_int_frames = None
    copter_yaw = True

    def auto_climb_m_s(self, v) -> float:
        """WPNAV_SPEED_UP, or the mission's DO_CHANGE_SPEED type 2."""
        return v.climb_override_m_s or v.param("WPNAV_SPEED_UP", 250.0) / 100.0

    def auto_descent_m_s(self, v) -> float:
        """WPNAV_SPEED_DN, or the mission's DO_CHANGE_SPEED type 3."""
        return v.descent_override_m_s or v.param("WPNAV_SPEED_DN", 150.0) / 100.0

    def land_speed_m_s(self, v) -> float:
        return v.param("LAND_SPEED", 70.0) / 100.0

    def takeoff_alt_m(self, v) -> float:
        return v.param("PILOT_TKOFF_ALT", 250.0) / 100.0

    def rtl_alt_m(self, v) -> float:
        return v.param("RTL_ALT", 1500.0) / 100.0

    def change_speed(self, v, speed_type: int, speed: float) -> None:
        """Copter 4.7 honours types 2 (climb) and 3 (descent); others set the horizontal speed."""
        if speed_type == 2:
            v.climb_override_m_s = float(speed)
        elif speed_type == 3:
            v.descent_override_m_s = float(speed)
        else:
            super().change_speed(v, speed_type, speed)

    def takeoff_command(self, v, param7: float) -> str | None:
        """Copter takes off by command only in GUIDED and armed, to param7 metres (PILOT_TKOFF_ALT in cm)."""
        if v.mode != GUIDED or not v.armed:
            return "Takeoff needs GUIDED and armed"
        v.params["PILOT_TKOFF_ALT"] = float(param7 if math.isfinite(param7) else 2.5) * 100.0
        return None

    def link_loss_timeout_s(self, params: dict) -> float:
        """FS_GCS_TIMEOUT (default 5 s) from the last counted message (Copter::failsafe_gcs_check)."""
        return float(params.get("FS_GCS_TIMEOUT", 5.0))

    def counts_for_link_failsafe(self, params: dict, msg, own_system: int) -> bool:
        """``GCS_MAVLINK::handle_heartbeat``: a HEARTBEAT, RC override or MANUAL_CONTROL whose source system is a GCS
        id: MAV_GCS_SYSID (default 255; this firmware has no MAV_GCS_SYSID_HI range, so it is never set here).
        Anything from another system id (mavsdk's 245) does not count: real ArduCopter 4.7 flew on after the
        companion was killed."""
        if msg.get_type() not in COPTER_GCS_ALIVE_MESSAGES:
            return False
        return msg.get_srcSystem() == int(params.get("MAV_GCS_SYSID", 255))

    def lost_link_ignored(self, params: dict, mode: str) -> bool:
        return False  # no such exception by default (FS_OPTIONS 0)

    def lost_link_action(self, params: dict) -> str | None:
        """FS_GCS_ENABLE: 0 disabled, 1 RTL, 2 continue in AUTO, 3/4 SmartRTL (RTL here), 5 land, 6 DO_LAND_START or
        RTL, 7 brake/land."""
        return {1: "rtl", 3: "rtl", 4: "rtl", 5: "land", 6: "rtl", 7: "land"}.get(int(params.get("FS_GCS_ENABLE", 0)))

    def custom_mode(self, mode: str) -> int:
        return _COPTER_MODES[mode]

    def mode_from_set_mode(self, base: float, main: float, sub: float) -> str | None:
        if not math.isfinite(base) or not int(base) & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
            return None
        return _COPTER_FROM_NUMBER.get(int(main) if math.isfinite(main) else -1)

    def validate(self, item: mi.MissionItem, index: int) -> int | None:
        refusal = copter_param_check(item)  # every item goes through the conversion, seq 0 too
        if refusal is not None or index == 0:
            return refusal  # seq 0 is otherwise replaced by home whatever it holds
        return _validate_common(item)

    def arm_refusal(self, mode: str) -> str | None:
        if mode == BRAKE:
            return "Arm: Mode not armable (BRAKE)"
        if mode in (MISSION, RTL, LAND):
            return f"Arm: Mode not armable ({mode})"
        return None

    def ground_start_refusal(self, items: list) -> list[tuple[int, str]]:
        """ModeAuto::init refuses AUTO when landed and armed unless the mission starts with a takeoff, then
        Copter::set_mode says the mode change failed (ArduCopter 4.7 source; the command is answered FAILED)."""
        if len(items) < 2 or items[1].command != mi.MAV_CMD_NAV_TAKEOFF:
            return [(mavlink.MAV_SEVERITY_CRITICAL, "Auto: Missing Takeoff Cmd"),
                    (mavlink.MAV_SEVERITY_WARNING, "Mode change to AUTO failed: init failed")]
        return []

    def transform_upload(self, items: list, home_item: mi.MissionItem) -> list:
        """What Copter keeps: home at seq 0, every other item in its stored form (which it then flies)."""
        return [home_item] + [copter_stored_item(it) for it in items[1:]]

    def transform_download(self, items: list, home_item: mi.MissionItem) -> list:
        return [_with_current(home_item, 0)] + [_with_current(it, 0) for it in items[1:]]


FLAVOURS = {"px4": Px4, "ardupilot": ArduCopter}


# --- what each firmware stores (checked against ../shared/data/real-firmware/ downloads) ----------------------------
def _with_current(item: mi.MissionItem, current: int) -> mi.MissionItem:
    return mi.MissionItem(item.seq, item.frame, item.command, current, item.autocontinue, item.param1, item.param2,
                          item.param3, item.param4, item.x, item.y, item.z, item.mission_type)


def copter_param_check(item: mi.MissionItem) -> int | None:
    """MAV_MISSION_INVALID_PARAMn for the first NaN param the command does not allow, or any inf; else None."""
    allowed = _COPTER_NAN_OK.get(item.command, set())
    for k, value in enumerate((item.param1, item.param2, item.param3, item.param4), start=1):
        if math.isinf(value) or (math.isnan(value) and k not in allowed):
            return _COPTER_INVALID_PARAM[k]
    return None


def _trunc(value: float) -> float:
    return float(math.trunc(value)) if math.isfinite(value) else 0.0


def copter_stored_item(it: mi.MissionItem) -> mi.MissionItem:
    """The item as ArduCopter 4.7 stores it (AP_Mission's 15-byte command) and hands it back on download.

    Located commands: altitude in whole centimetres (float32 arithmetic, truncated), frame 6/5 as the float twins
    3/0, NAV_WAYPOINT keeping only the hold (uint16 seconds), NAV_TAKEOFF/LAND only param1 (and LAND a direction
    flag in param4). Other commands come back in frame 0; CONDITION_YAW and DO_CHANGE_SPEED keep integer fields as
    integers."""
    p = [it.param1, it.param2, it.param3, it.param4]
    frame, z = it.frame, it.z
    if it.command in _COPTER_LOCATED:
        frame = {mi.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT: mi.MAV_FRAME_GLOBAL_RELATIVE_ALT,
                 mi.MAV_FRAME_GLOBAL_INT: mi.MAV_FRAME_GLOBAL}.get(frame, frame)
        cm = int(_F32(z) * _F32(100.0))
        z = float(_F32(cm) * _F32(0.01))
        land_flag = -1.0 if it.command == mi.MAV_CMD_NAV_LAND and p[3] < 0 else 1.0
        p = [float(min(max(_trunc(p[0]), 0.0), 65535.0)), 0.0, 0.0,
             land_flag if it.command == mi.MAV_CMD_NAV_LAND else 0.0]
    else:
        frame = mi.MAV_FRAME_GLOBAL
        if it.command == mi.MAV_CMD_CONDITION_YAW:
            p = [p[0], p[1], _trunc(p[2]), _trunc(p[3])]
        elif it.command == mi.MAV_CMD_DO_CHANGE_SPEED:
            p = [_trunc(p[0]), p[1], p[2], 0.0]
    return mi.MissionItem(it.seq, frame, it.command, it.current, it.autocontinue, *(float(v) for v in p), it.x, it.y,
                          z, it.mission_type)


def _px4_yaw(deg: float) -> float:
    """PX4 keeps a mission yaw in radians (float32 arithmetic) wrapped to [0, 2pi) and hands it back in degrees."""
    if not math.isfinite(deg):
        return deg
    two_pi = _F32(2.0 * math.pi)
    rad = _F32(deg) * (_F32(math.pi) / _F32(180.0))  # matrix::radians/degrees in float: pi and 180 as floats
    while rad < 0:
        rad = _F32(rad + two_pi)
    while rad >= two_pi:
        rad = _F32(rad - two_pi)
    return float(rad * (_F32(180.0) / _F32(math.pi)))


def px4_stored_item(it: mi.MissionItem) -> mi.MissionItem:
    """The item as PX4 main stores it: as sent, except the yaw of NAV_WAYPOINT/TAKEOFF/LAND (see ``_px4_yaw``)."""
    if it.command not in NAV_COMMANDS:
        return it
    return mi.MissionItem(it.seq, it.frame, it.command, it.current, it.autocontinue, it.param1, it.param2, it.param3,
                          _px4_yaw(it.param4), it.x, it.y, it.z, it.mission_type)

"""What differs between a PX4-like and an ArduCopter-like autopilot, in one place.

Mode encodings follow what mavsdk 4.1 decodes: PX4 packs main mode in bits 16-23 and sub mode in bits 24-31 of
HEARTBEAT.custom_mode; ArduCopter uses its mode number. The ArduPilot flavour reproduces the behaviours listed in
/work/shared/notes/ardupilot-with-mavsdk4.md (seq 0 = home, NaN takeoff params refused, no telemetry streams until
asked, BRAKE refuses arming, AUTO refused on the ground without a takeoff item).
"""

from __future__ import annotations

import math
import struct

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
    param_bytewise = True
    default_rates_hz = {
        "HEARTBEAT": 1.0, "SYS_STATUS": 1.0, "GPS_RAW_INT": 5.0, "GLOBAL_POSITION_INT": 10.0,
        "LOCAL_POSITION_NED": 10.0, "ATTITUDE": 20.0, "ATTITUDE_QUATERNION": 20.0, "HOME_POSITION": 0.5,
        "EXTENDED_SYS_STATE": 2.0, "BATTERY_STATUS": 1.0, "MISSION_CURRENT": 1.0, "VFR_HUD": 4.0,
        "GIMBAL_DEVICE_ATTITUDE_STATUS": 5.0,
    }
    params = {
        "MIS_TAKEOFF_ALT": 2.5, "RTL_RETURN_ALT": 15.0, "RTL_DESCEND_ALT": 10.0, "MPC_XY_CRUISE": 5.0,
        "MPC_XY_VEL_MAX": 12.0, "MPC_Z_VEL_MAX_UP": 3.0, "MPC_Z_VEL_MAX_DN": 1.5, "MPC_LAND_SPEED": 0.7,
        "MPC_ACC_HOR": 4.0, "MPC_YAWRAUTO_MAX": 60.0, "NAV_ACC_RAD": 2.0, "COM_DL_LOSS_T": 10, "NAV_DLL_ACT": 2,
        "COM_DISARM_LAND": 2.0, "BAT_LOW_THR": 0.15, "MIS_YAWMODE": 0,
    }

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

    def ground_start_refusal(self, items: list) -> str | None:
        return None

    def transform_upload(self, items: list, home_item: mi.MissionItem) -> list:
        return items

    def transform_download(self, items: list, home_item: mi.MissionItem) -> list:
        return items

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
    default_rates_hz = {"HEARTBEAT": 1.0}
    params = {
        "WPNAV_SPEED": 500.0, "WPNAV_SPEED_UP": 300.0, "WPNAV_SPEED_DN": 150.0, "WPNAV_RADIUS": 200.0,
        "WPNAV_ACCEL": 400.0, "LAND_SPEED": 70.0, "RTL_ALT": 1500.0, "PILOT_TKOFF_ALT": 250.0, "FS_GCS_ENABLE": 1,
        "FS_GCS_TIMEOUT": 10.0, "SR0_POSITION": 0, "SR0_EXTRA1": 0, "SR0_EXT_STAT": 0,
    }

    def custom_mode(self, mode: str) -> int:
        return _COPTER_MODES[mode]

    def mode_from_set_mode(self, base: float, main: float, sub: float) -> str | None:
        if not math.isfinite(base) or not int(base) & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
            return None
        return _COPTER_FROM_NUMBER.get(int(main) if math.isfinite(main) else -1)

    def validate(self, item: mi.MissionItem, index: int) -> int | None:
        if index == 0:
            return None  # seq 0 is replaced by home whatever it holds
        if item.command == mi.MAV_CMD_NAV_TAKEOFF and any(math.isnan(p) for p in (item.param1, item.param2,
                                                                                   item.param3)):
            return mavlink.MAV_MISSION_INVALID_PARAM1
        return _validate_common(item)

    def arm_refusal(self, mode: str) -> str | None:
        if mode == BRAKE:
            return "Arm: Mode not armable (BRAKE)"
        if mode in (MISSION, RTL, LAND):
            return f"Arm: Mode not armable ({mode})"
        return None

    def ground_start_refusal(self, items: list) -> str | None:
        if len(items) < 2 or items[1].command != mi.MAV_CMD_NAV_TAKEOFF:
            return "Auto: Missing Takeoff Cmd"
        return None

    def transform_upload(self, items: list, home_item: mi.MissionItem) -> list:
        return [home_item] + list(items[1:])

    def transform_download(self, items: list, home_item: mi.MissionItem) -> list:
        out = [home_item]
        for it in items[1:]:
            frame = it.frame
            if frame == mi.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT:
                frame = mi.MAV_FRAME_GLOBAL_RELATIVE_ALT
            elif frame == mi.MAV_FRAME_GLOBAL_INT:
                frame = mi.MAV_FRAME_GLOBAL
            out.append(mi.MissionItem(it.seq, frame, it.command, it.current, it.autocontinue, it.param1, it.param2,
                                      it.param3, it.param4, it.x, it.y, it.z, it.mission_type))
        return out


FLAVOURS = {"px4": Px4, "ardupilot": ArduCopter}

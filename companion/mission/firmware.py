"""MAVLink mission facts every autopilot shares: command numbers the plans use beyond ``items``, DO_CHANGE_SPEED's
speed types and the commands' names for messages.

What differs between firmwares (what each accepts, stores and honours, the parameters a scan needs) lives in
each autopilot's home: ``companion.mission.autopilot`` (``px4.py``, ``ardupilot.py``).
"""

from __future__ import annotations

from companion.mission import items as mi

MAV_CMD_NAV_LOITER_UNLIM = 17
MAV_CMD_NAV_VTOL_TAKEOFF = 84
MAV_CMD_NAV_VTOL_LAND = 85

# Commands whose x/y/z are a position (the ones a scan plan can hold; ArduPilot stores exactly these with a location,
# AP_Mission::stored_in_location).
LOCATION_COMMANDS = frozenset({mi.MAV_CMD_NAV_WAYPOINT, mi.MAV_CMD_NAV_TAKEOFF, mi.MAV_CMD_NAV_LAND, 17, 18, 19, 30, 31,
                               82, 84, 85, 94})

# DO_CHANGE_SPEED param1 (SPEED_TYPE): which motion each type changes.
SPEED_TYPE_GROUND = 1
SPEED_TYPE_CLIMB = 2
SPEED_TYPE_DESCENT = 3

COMMAND_NAMES = {
    mi.MAV_CMD_NAV_WAYPOINT: "NAV_WAYPOINT", mi.MAV_CMD_NAV_RETURN_TO_LAUNCH: "NAV_RETURN_TO_LAUNCH",
    mi.MAV_CMD_NAV_LAND: "NAV_LAND", mi.MAV_CMD_NAV_TAKEOFF: "NAV_TAKEOFF", mi.MAV_CMD_DO_CHANGE_SPEED:
    "DO_CHANGE_SPEED", mi.MAV_CMD_DO_MOUNT_CONTROL: "DO_MOUNT_CONTROL", mi.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW:
    "DO_GIMBAL_MANAGER_PITCHYAW", mi.MAV_CMD_CONDITION_YAW: "CONDITION_YAW", MAV_CMD_NAV_LOITER_UNLIM:
    "NAV_LOITER_UNLIM", MAV_CMD_NAV_VTOL_TAKEOFF: "NAV_VTOL_TAKEOFF", MAV_CMD_NAV_VTOL_LAND: "NAV_VTOL_LAND",
}


def command_name(command: int) -> str:
    return COMMAND_NAMES.get(command, f"command {command}")

"""MAVLink mission items (MISSION_ITEM_INT fields): the raw-protocol form of a scan plan.

Kept independent of mavsdk and pymavlink so the planner, the exporters, the flight code and the simulator all
agree on one record.
"""

from __future__ import annotations

from dataclasses import dataclass

# MAV_CMD / MAV_FRAME numbers used by the planner (from the MAVLink common dialect).
MAV_CMD_NAV_WAYPOINT = 16
MAV_CMD_NAV_RETURN_TO_LAUNCH = 20
MAV_CMD_NAV_LAND = 21
MAV_CMD_NAV_TAKEOFF = 22
MAV_CMD_DO_CHANGE_SPEED = 178
MAV_CMD_DO_MOUNT_CONTROL = 205
MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW = 1000
MAV_CMD_CONDITION_YAW = 115

MAV_FRAME_GLOBAL = 0
MAV_FRAME_GLOBAL_RELATIVE_ALT = 3
MAV_FRAME_GLOBAL_INT = 5
MAV_FRAME_GLOBAL_RELATIVE_ALT_INT = 6
MAV_FRAME_MISSION = 2

MAV_MISSION_TYPE_MISSION = 0


@dataclass(frozen=True)
class MissionItem:
    """One MISSION_ITEM_INT. ``x``/``y`` are lat/lon in degrees * 1e7 for global frames; ``z`` is metres."""

    seq: int
    frame: int
    command: int
    current: int
    autocontinue: int
    param1: float
    param2: float
    param3: float
    param4: float
    x: int
    y: int
    z: float
    mission_type: int = MAV_MISSION_TYPE_MISSION

    @property
    def lat(self) -> float:
        return self.x / 1e7

    @property
    def lon(self) -> float:
        return self.y / 1e7

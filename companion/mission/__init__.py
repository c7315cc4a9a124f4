"""Facade scan missions: YAML spec, validation, planner and exports."""

from companion.mission.planner import Footprint, PlanEstimates, ScanPlan, Waypoint, camera_footprint, plan_scan
from companion.mission.spec import Mission, load_mission, parse_mission

__all__ = [
    "Footprint",
    "Mission",
    "PlanEstimates",
    "ScanPlan",
    "Waypoint",
    "camera_footprint",
    "load_mission",
    "parse_mission",
    "plan_scan",
]

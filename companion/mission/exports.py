"""Plan exports for autopilots, ground stations and GIS: mavsdk items, raw MAVLink, QGC .plan, WPL 110, KML, GeoJSON.

Everything is rendered in memory first and written with ``write_outputs`` so a failure leaves no partial output.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import tempfile
from dataclasses import asdict
from pathlib import Path

import simplekml

from companion.errors import CompanionError
from companion.mission import items as mi
from companion.mission.firmware import AUTOPILOTS, flight_parameters
from companion.mission.planner import ScanPlan

QGC_FIRMWARE = {"px4": 12, "ardupilot": 3}  # MAV_AUTOPILOT numbers QGroundControl stores
QGC_VEHICLE_MULTIROTOR = 2


def _num(v: float) -> float | None:
    """JSON has no NaN: QGroundControl writes null for 'unset' params."""
    return None if isinstance(v, float) and math.isnan(v) else v


def mavlink_items_json(plan: ScanPlan, flavour: str) -> str:
    """Raw MISSION_ITEM_INT list, the form mavsdk's MissionRaw.upload_mission takes."""
    rows = [{k: _num(v) for k, v in asdict(item).items()} for item in plan.mavlink_items(flavour)]
    return json.dumps({"autopilot": flavour, "mission_items": rows}, indent=1)


def mavsdk_mission_json(plan: ScanPlan) -> str:
    """High-level mavsdk Mission plugin items (mavsdk.mission.MissionItem fields) for PX4-style uploads."""
    pitch = plan.mission.gimbal_pitch_deg
    items = []
    for wp in plan.waypoints:
        if wp.kind in ("takeoff", "land"):
            continue
        items.append(
            {
                "latitude_deg": wp.lat,
                "longitude_deg": wp.lon,
                "relative_altitude_m": wp.rel_alt_m,
                "speed_m_s": wp.speed_m_s,
                "is_fly_through": wp.hold_s == 0.0,
                "gimbal_pitch_deg": pitch,
                "gimbal_yaw_deg": 0.0,
                "camera_action": "NONE",
                "loiter_time_s": wp.hold_s,
                "camera_photo_interval_s": None,
                "acceptance_radius_m": wp.acceptance_m,
                "yaw_deg": wp.yaw_deg,
                "camera_photo_distance_m": None,
                "vehicle_action": "NONE",
            }
        )
    end = "LAND" if plan.mission.end_action == "land" else "RTL"
    return json.dumps(
        {
            "mission_items": items,
            "takeoff_first": True,
            "end_action": end,
            "note": "takeoff with action.takeoff() and finish with action.land()/return_to_launch()",
        },
        indent=1,
    )


def qgc_plan_json(plan: ScanPlan, flavour: str = "px4") -> str:
    """QGroundControl .plan with the mission items themselves (SimpleItems), readable by any tool."""
    raw = plan.mavlink_items(flavour)
    if flavour == "ardupilot":
        raw = raw[1:]  # QGC keeps home in plannedHomePosition, not as an item
    items = []
    for k, it in enumerate(raw, start=1):
        is_global = it.frame in (mi.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, mi.MAV_FRAME_GLOBAL_RELATIVE_ALT)
        lat = it.lat if is_global else 0.0
        lon = it.lon if is_global else 0.0
        frame = mi.MAV_FRAME_GLOBAL_RELATIVE_ALT if is_global else it.frame
        params = [it.param1, it.param2, it.param3, it.param4, lat, lon, it.z]
        items.append(
            {
                "type": "SimpleItem",
                "autoContinue": True,
                "command": it.command,
                "doJumpId": k,
                "frame": frame,
                "params": [_num(float(p)) for p in params],
                "AMSLAltAboveTerrain": None,
                "Altitude": it.z,
                "AltitudeMode": 1,
            }
        )
    h = plan.home
    speed = plan.estimates.scan_speed_m_s
    doc = {
        "fileType": "Plan",
        "version": 1,
        "groundStation": "companion",
        "mission": {
            "version": 2,
            "firmwareType": QGC_FIRMWARE[flavour],
            "vehicleType": QGC_VEHICLE_MULTIROTOR,
            "cruiseSpeed": plan.mission.max_speed_m_s,
            "hoverSpeed": speed,
            "plannedHomePosition": [h.lat, h.lon, h.alt_amsl_m],
            "items": items,
        },
        "geoFence": {"circles": [], "polygons": [], "version": 2},
        "rallyPoints": {"points": [], "version": 2},
    }
    return json.dumps(doc, indent=1)


def wpl_text(plan: ScanPlan) -> str:
    """MAVLink 'QGC WPL 110' text (Mission Planner .waypoints): line 0 is home, as ArduPilot stores it."""
    lines = ["QGC WPL 110"]
    for it in plan.mavlink_items("ardupilot"):
        frame = it.frame
        if frame == mi.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT:
            frame = mi.MAV_FRAME_GLOBAL_RELATIVE_ALT
        elif frame == mi.MAV_FRAME_GLOBAL_INT:
            frame = mi.MAV_FRAME_GLOBAL
        params = [0.0 if math.isnan(p) else p for p in (it.param1, it.param2, it.param3, it.param4)]
        fields = [it.seq, 1 if it.seq == 0 else 0, frame, it.command, *params, it.lat, it.lon, it.z, it.autocontinue]
        lines.append("\t".join(f"{v:.8f}" if isinstance(v, float) else str(v) for v in fields))
    return "\n".join(lines) + "\n"


def _wall_corners(plan: ScanPlan) -> list[tuple[float, float, float]]:
    f = plan.frame
    h = plan.mission.facade.height_m
    pts = []
    for a, u in ((0.0, 0.0), (f.length_m, 0.0), (f.length_m, h), (0.0, h), (0.0, 0.0)):
        lat, lon, alt = f.facade_to_geodetic(a, 0.0, u)
        pts.append((float(lon), float(lat), float(alt)))
    return pts


def geojson_text(plan: ScanPlan) -> str:
    path = [[wp.lon, wp.lat, wp.alt_amsl_m] for wp in plan.waypoints]
    wall = _wall_corners(plan)
    feats = [
        {
            "type": "Feature",
            "properties": {"name": "wall", "height_m": plan.mission.facade.height_m, "length_m": plan.frame.length_m},
            "geometry": {"type": "LineString", "coordinates": [list(wall[0]), list(wall[1])]},
        },
        {
            "type": "Feature",
            "properties": {"name": "wall face (vertical polygon)"},
            "geometry": {"type": "Polygon", "coordinates": [[list(p) for p in wall]]},
        },
        {
            "type": "Feature",
            "properties": {"name": "scan path"},
            "geometry": {"type": "LineString", "coordinates": path},
        },
    ]
    for k, wp in enumerate(plan.waypoints):
        feats.append(
            {
                "type": "Feature",
                "properties": {
                    "seq": k,
                    "kind": wp.kind,
                    "rel_alt_m": round(wp.rel_alt_m, 3),
                    "yaw_deg": round(wp.yaw_deg, 3),
                    "speed_m_s": round(wp.speed_m_s, 3),
                    "standoff_m": round(wp.out_m, 3),
                },
                "geometry": {"type": "Point", "coordinates": [wp.lon, wp.lat, wp.alt_amsl_m]},
            }
        )
    return json.dumps({"type": "FeatureCollection", "features": feats}, indent=1)


def kml_text(plan: ScanPlan) -> str:
    kml = simplekml.Kml(name=plan.mission.name)
    wall = kml.newpolygon(name="wall", outerboundaryis=_wall_corners(plan))
    wall.altitudemode = simplekml.AltitudeMode.absolute
    wall.style.polystyle.color = simplekml.Color.changealphaint(120, simplekml.Color.gray)
    path = kml.newlinestring(name="scan path", coords=[(wp.lon, wp.lat, wp.alt_amsl_m) for wp in plan.waypoints])
    path.altitudemode = simplekml.AltitudeMode.absolute
    path.style.linestyle.color = simplekml.Color.red
    path.style.linestyle.width = 2
    for k, wp in enumerate(plan.waypoints):
        p = kml.newpoint(name=f"{k} {wp.kind}", coords=[(wp.lon, wp.lat, wp.alt_amsl_m)])
        p.altitudemode = simplekml.AltitudeMode.absolute
    return kml.kml()


def flight_parameters_by_autopilot(plan: ScanPlan) -> dict[str, dict]:
    """Per autopilot, the parameters the flight needs (``firmware.flight_parameters``), or why it cannot be flown."""
    out: dict[str, dict] = {}
    for autopilot in AUTOPILOTS:
        try:
            out[autopilot] = flight_parameters(plan, autopilot)
        except CompanionError as exc:
            out[autopilot] = {"error": exc.problem, "fix": exc.fix}
    return out


def summary_json(plan: ScanPlan) -> str:
    return json.dumps(
        {
            "mission": plan.mission.name,
            "wall_length_m": round(plan.frame.length_m, 3),
            "wall_height_m": plan.mission.facade.height_m,
            "standoff_m": plan.mission.standoff_m,
            "yaw_facing_wall_deg": round(plan.frame.yaw_facing_wall_deg, 3),
            "home": {"lat": plan.home.lat, "lon": plan.home.lon, "alt_amsl_m": plan.home.alt_amsl_m},
            "waypoints": len(plan.waypoints),
            "estimates": plan.estimates.as_dict(),
            "flight_parameters": flight_parameters_by_autopilot(plan),
            "warnings": plan.warnings,
        },
        indent=1,
    )


def render_outputs(plan: ScanPlan) -> dict[str, bytes]:
    """File name -> content for every export (the plot included)."""
    from companion.mission.plot import plot_png

    stem = plan.mission.name
    texts = {
        "mavsdk_mission.json": mavsdk_mission_json(plan),
        "mavlink_items_px4.json": mavlink_items_json(plan, "px4"),
        "mavlink_items_ardupilot.json": mavlink_items_json(plan, "ardupilot"),
        f"{stem}.plan": qgc_plan_json(plan, "px4"),
        f"{stem}-ardupilot.plan": qgc_plan_json(plan, "ardupilot"),
        f"{stem}.waypoints": wpl_text(plan),
        f"{stem}.kml": kml_text(plan),
        f"{stem}.geojson": geojson_text(plan),
        "summary.json": summary_json(plan),
    }
    out = {k: v.encode("utf-8") for k, v in texts.items()}
    out[f"{stem}-path.png"] = plot_png(plan)
    return out


def write_outputs(files: dict[str, bytes], out_dir: Path) -> list[Path]:
    """Write all files or none: stage in a temp dir beside ``out_dir``, then move each into place."""
    out_dir = Path(out_dir)
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
        stage = Path(tempfile.mkdtemp(prefix=".plan-", dir=out_dir))
    except OSError as exc:
        raise CompanionError(
            f"cannot write to {out_dir}: {exc.strerror}", "choose a writable --out directory"
        ) from None
    try:
        for name, data in files.items():
            with open(stage / name, "wb") as fh:
                fh.write(data)
                fh.flush()
                os.fsync(fh.fileno())
        written = []
        for name in files:
            os.replace(stage / name, out_dir / name)
            written.append(out_dir / name)
        return written
    except OSError as exc:
        raise CompanionError(
            f"writing the plan to {out_dir} failed: {exc.strerror}", "free disk space or pick another --out"
        ) from None
    finally:
        shutil.rmtree(stage, ignore_errors=True)

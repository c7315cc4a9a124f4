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

import pymap3d
import simplekml

from companion.errors import CompanionError
from companion.mission import items as mi
from companion.mission.autopilot import DEFAULT_FLAVOUR, Autopilot, Flavour, autopilot_for
from companion.mission.planner import ScanPlan
from companion.polygons import signed_area

QGC_VEHICLE_MULTIROTOR = 2


def _num(v: float) -> float | None:
    """JSON has no NaN: QGroundControl writes null for 'unset' params."""
    return None if isinstance(v, float) and math.isnan(v) else v


def mavlink_items_json(plan: ScanPlan, flavour: str | Autopilot) -> str:
    """Raw MISSION_ITEM_INT list, the form mavsdk's MissionRaw.upload_mission takes."""
    ap = autopilot_for(flavour)
    rows = [{k: _num(v) for k, v in asdict(item).items()} for item in plan.mavlink_items(ap)]
    return json.dumps({"autopilot": ap.flavour, "mission_items": rows}, indent=1)


# mavsdk.plugins.mission.MissionItem.CameraAction / VehicleAction are IntEnums: JSON holds their integer values,
# which MissionItem(**item) and the enums themselves accept (a name string such as "NONE" is refused by both).
MAVSDK_CAMERA_ACTION_NONE = 0
MAVSDK_VEHICLE_ACTION_NONE = 0


def mavsdk_mission_json(plan: ScanPlan) -> str:
    """High-level mavsdk Mission plugin items: each one is ``mavsdk.plugins.mission.MissionItem(**item)``."""
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
                "camera_action": MAVSDK_CAMERA_ACTION_NONE,
                "loiter_time_s": wp.hold_s,
                "camera_photo_interval_s": None,
                "acceptance_radius_m": wp.acceptance_m,
                "yaw_deg": wp.yaw_deg,
                "camera_photo_distance_m": None,
                "vehicle_action": MAVSDK_VEHICLE_ACTION_NONE,
            }
        )
    end = "LAND" if plan.mission.end_action == "land" else "RTL"
    return json.dumps(
        {
            "mission_items": items,
            "takeoff_first": True,
            "end_action": end,
            "note": "each item: mavsdk.plugins.mission.MissionItem(**item) (camera_action/vehicle_action are the "
            "IntEnum values, 0 = NONE; null = mavsdk's default). Take off with action.takeoff() first and finish "
            "with action.land()/return_to_launch().",
        },
        indent=1,
    )


def qgc_geofence(plan: ScanPlan) -> dict:
    """QGroundControl geoFence (version 2): the mission's horizontal limit as an inclusion circle around home.

    The altitude limit has no place in QGC's fence JSON (it is a vehicle parameter: PX4 GF_MAX_VER_DIST,
    ArduPilot FENCE_ALT_MAX); docs/OUTPUTS.md says so.
    """
    gf = plan.mission.geofence
    circle = {"circle": {"center": [plan.home.lat, plan.home.lon], "radius": gf.max_distance_m}, "inclusion": True,
              "version": 1}
    return {"circles": [circle], "polygons": [], "version": 2}


def qgc_plan_json(plan: ScanPlan, flavour: str | Autopilot = DEFAULT_FLAVOUR) -> str:
    """QGroundControl .plan with the mission items themselves (SimpleItems), readable by any tool."""
    ap = autopilot_for(flavour)
    raw = plan.mavlink_items(ap)[ap.first_item_seq:]  # QGC keeps home in plannedHomePosition, not as an item
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
    # No cruiseSpeed/hoverSpeed: QGroundControl copies them into the user's saved offline-editing speeds on load.
    # The flown speeds are in the DO_CHANGE_SPEED items.
    doc = {
        "fileType": "Plan",
        "version": 1,
        "groundStation": "companion",
        "mission": {
            "version": 2,
            "firmwareType": ap.mav_autopilot,  # QGroundControl stores the MAV_AUTOPILOT number
            "vehicleType": QGC_VEHICLE_MULTIROTOR,
            "plannedHomePosition": [h.lat, h.lon, h.alt_amsl_m],
            "items": items,
        },
        "geoFence": qgc_geofence(plan),
        "rallyPoints": {"points": [], "version": 2},
    }
    return json.dumps(doc, indent=1)


def wpl_text(plan: ScanPlan) -> str:
    """MAVLink 'QGC WPL 110' text (Mission Planner .waypoints): line 0 is home, as ArduPilot stores it.

    Written here, not by pymavlink's ``MAVWPLoader.save`` (2.4.50): that writes every field with ``%f``, 6
    decimals, so latitudes and longitudes lose up to 5e-7 degree (5.6 cm at the wall) against the 1e-7 degree the
    MISSION_ITEM_INT items carry and the plan's other exports keep; it also writes only to a file path, not into
    the in-memory render that ``write_outputs`` commits all or nothing. pymavlink's loader still reads this file
    back item for item (tests/test_mission_exports.py)."""
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
    """The wall face, base to top, as (lon, lat, alt AMSL) with the altitudes of the wall's ground + height."""
    f = plan.frame
    h = plan.mission.facade.height_m
    ground = plan.mission.facade.ground_alt_amsl_m
    pts = []
    for a, u in ((0.0, 0.0), (f.length_m, 0.0), (f.length_m, h), (0.0, h), (0.0, 0.0)):
        lat, lon, _ = f.facade_to_geodetic(a, 0.0, 0.0)
        # to 1e-8 degree (about a millimetre), as the planner's waypoints: no float noise (37.56649999999999)
        pts.append((round(float(lon), 8), round(float(lat), 8), round(ground + u, 3)))
    return pts


def _mission_amsl_m(plan: ScanPlan, rel_alt_m: float) -> float:
    """Altitude above mean sea level of a mission altitude (the items fly relative to home)."""
    return plan.home.alt_amsl_m + rel_alt_m


def signed_area_deg2(ring: list[list[float]]) -> float:
    """Shoelace area of a closed [lon, lat] ring: > 0 counter-clockwise (RFC 7946's right-hand rule for exteriors)."""
    return signed_area(ring)  # the closing edge (last point = first) adds nothing


def _ccw(ring: list[list[float]]) -> list[list[float]]:
    return ring if signed_area_deg2(ring) > 0 else ring[::-1]


def _geofence_ring(plan: ScanPlan, vertices: int = 72) -> list[list[float]]:
    """The horizontal geofence (circle around home) as an inscribed polygon: inside the ring is inside the fence."""
    h = plan.home
    r = plan.mission.geofence.max_distance_m
    ring = []
    for k in range(vertices + 1):
        a = 2 * math.pi * (k % vertices) / vertices
        lat, lon, _ = pymap3d.enu2geodetic(r * math.sin(a), r * math.cos(a), 0.0, h.lat, h.lon, h.alt_amsl_m)
        ring.append([round(float(lon), 9), round(float(lat), 9)])
    return _ccw(ring)


def geojson_text(plan: ScanPlan) -> str:
    """GeoJSON per RFC 7946: 2-D positions (its heights would be ellipsoidal; ours are above mean sea level, as
    MAVLink's), heights as properties, one JSON type per property name (GIS tools type a field once for the whole
    layer); polygon exteriors counter-clockwise (right-hand rule)."""
    m = plan.mission
    wall = _wall_corners(plan)
    feats = [
        {
            "type": "Feature",
            "properties": {
                "name": "wall base",
                "ground_alt_amsl_m": m.facade.ground_alt_amsl_m,
                "height_m": m.facade.height_m,
                "length_m": round(plan.frame.length_m, 3),
                "yaw_facing_wall_deg": round(plan.frame.yaw_facing_wall_deg, 3),
            },
            "geometry": {"type": "LineString", "coordinates": [list(wall[0][:2]), list(wall[1][:2])]},
        },
        {
            "type": "Feature",
            "properties": {
                "name": "scan path",
                # scalars only (GIS tools type a field once per layer: a list became RealList, which a GeoPackage
                # stores as text and a shapefile refuses); each vertex's heights are on the waypoint Point whose
                # seq is the vertex's index
                "vertices": len(plan.waypoints),
                "alt_amsl_min_m": round(min(_mission_amsl_m(plan, wp.rel_alt_m) for wp in plan.waypoints), 3),
                "alt_amsl_max_m": round(max(_mission_amsl_m(plan, wp.rel_alt_m) for wp in plan.waypoints), 3),
            },
            "geometry": {"type": "LineString", "coordinates": [[wp.lon, wp.lat] for wp in plan.waypoints]},
        },
        {
            "type": "Feature",
            "properties": {
                "name": "geofence",
                "max_distance_m": m.geofence.max_distance_m,
                "max_alt_rel_m": m.geofence.max_alt_m,
                "max_alt_amsl_m": round(_mission_amsl_m(plan, m.geofence.max_alt_m), 3),
            },
            "geometry": {"type": "Polygon", "coordinates": [_geofence_ring(plan)]},
        },
    ]
    fp = m.facade.footprint
    if fp is not None and fp.coordinates:
        ring = [[float(lon), float(lat)] for lon, lat in fp.coordinates]
        if ring[0] != ring[-1]:
            ring.append(ring[0])
        feats.append(
            {
                "type": "Feature",
                "properties": {"name": "building footprint", "ground_alt_amsl_m": m.facade.ground_alt_amsl_m,
                               "height_m": m.facade.height_m, "face": fp.face},
                "geometry": {"type": "Polygon", "coordinates": [_ccw(ring)]},
            }
        )
    for k, wp in enumerate(plan.waypoints):
        feats.append(
            {
                "type": "Feature",
                "properties": {
                    "seq": k,
                    "kind": wp.kind,
                    "alt_amsl_m": round(_mission_amsl_m(plan, wp.rel_alt_m), 3),
                    "rel_alt_m": round(wp.rel_alt_m, 3),
                    "yaw_deg": round(wp.yaw_deg, 3),
                    "speed_m_s": round(wp.speed_m_s, 3),
                    "standoff_m": round(wp.out_m, 3),
                },
                "geometry": {"type": "Point", "coordinates": [wp.lon, wp.lat]},
            }
        )
    return json.dumps(
        {
            "type": "FeatureCollection",
            "heights": "2-D positions; alt_amsl_m is above mean sea level (home altitude + rel_alt_m, the mission's "
            "frame), rel_alt_m above home; the scan path's vertex k: the waypoint with seq k",
            "features": feats,
        },
        indent=1,
    )


def kml_text(plan: ScanPlan) -> str:
    """KML in altitudeMode absolute (above mean sea level, as KML defines it): home altitude + each item's altitude
    above home, so the drawn path is the one the autopilot flies in its relative-to-home frame (relativeToGround
    would follow the terrain under each point instead)."""
    h = plan.home
    kml = simplekml.Kml(name=plan.mission.name)
    kml.document.description = (
        f"Altitudes above mean sea level = home {h.alt_amsl_m:.2f} m + the mission's altitudes above home "
        "(MAV_FRAME_GLOBAL_RELATIVE_ALT)."
    )
    wall = kml.newpolygon(name="wall", outerboundaryis=_wall_corners(plan))
    wall.altitudemode = simplekml.AltitudeMode.absolute
    wall.style.polystyle.color = simplekml.Color.changealphaint(120, simplekml.Color.gray)
    coords = [(wp.lon, wp.lat, _mission_amsl_m(plan, wp.rel_alt_m)) for wp in plan.waypoints]
    path = kml.newlinestring(name="scan path", coords=coords)
    path.altitudemode = simplekml.AltitudeMode.absolute
    path.style.linestyle.color = simplekml.Color.red
    path.style.linestyle.width = 2
    for k, (wp, c) in enumerate(zip(plan.waypoints, coords, strict=True)):
        p = kml.newpoint(name=f"{k} {wp.kind}", coords=[c])
        p.altitudemode = simplekml.AltitudeMode.absolute
    return kml.kml()


def flight_parameters_by_autopilot(plan: ScanPlan) -> dict[str, dict]:
    """Per autopilot, the parameters the flight needs (``Autopilot.flight_parameters``), or why it cannot be flown."""
    out: dict[str, dict] = {}
    for autopilot in Flavour:
        try:
            out[str(autopilot)] = autopilot_for(autopilot).flight_parameters(plan.for_autopilot(autopilot))
        except CompanionError as exc:
            out[str(autopilot)] = {"error": exc.problem, "fix": exc.fix}
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
        **{f"mavlink_items_{ap}.json": mavlink_items_json(plan, ap) for ap in Flavour},
        **{f"{stem}{autopilot_for(ap).plan_file_suffix}.plan": qgc_plan_json(plan, ap) for ap in Flavour},
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

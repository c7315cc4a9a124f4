"""Mission exports read by their tools: mavsdk's own types and QGC importer, RFC 7946 GeoJSON, KML altitudes."""

from __future__ import annotations

import asyncio
import json
import shutil
import subprocess
import threading
import time
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest
from matplotlib.path import Path as PolyPath
from mavsdk.plugins.mission import MissionItem, MissionPlan

from companion.mission import load_mission, plan_scan
from companion.mission.exports import render_outputs, signed_area_deg2

ROOT = Path(__file__).resolve().parents[1]
MISSIONS = [ROOT / "missions" / "demo-facade.yaml", ROOT / "missions" / "paper-edge-18-storey.yaml"]
MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION = 5003


@pytest.fixture(scope="module", params=MISSIONS, ids=lambda p: p.stem)
def planned(request):
    plan = plan_scan(load_mission(request.param))
    return plan, render_outputs(plan)


def test_every_mavsdk_item_builds_with_mavsdk(planned):
    plan, files = planned
    doc = json.loads(files["mavsdk_mission.json"])
    items = [MissionItem(**item) for item in doc["mission_items"]]
    assert len(items) == sum(wp.kind not in ("takeoff", "land") for wp in plan.waypoints)
    for item, raw in zip(items, doc["mission_items"], strict=True):
        item.to_c_struct()  # what upload_mission hands the C library: every value must convert
        assert item.camera_action == MissionItem.CameraAction(raw["camera_action"]) == MissionItem.CameraAction.NONE
        assert item.vehicle_action == MissionItem.VehicleAction(raw["vehicle_action"])
    MissionPlan(items)
    # the old form (enum names as strings) is what mavsdk refuses
    with pytest.raises((ValueError, TypeError)):
        MissionItem(**{**doc["mission_items"][0], "camera_action": "NONE"}).to_c_struct()


def test_qgc_plan_keeps_the_users_speeds_and_carries_the_geofence(planned):
    plan, files = planned
    doc = json.loads(files[f"{plan.mission.name}.plan"])
    assert "cruiseSpeed" not in doc["mission"] and "hoverSpeed" not in doc["mission"]
    fence = doc["geoFence"]
    assert fence["version"] == 2 and fence["polygons"] == []
    (circle,) = fence["circles"]
    assert circle["inclusion"] is True
    assert circle["circle"]["center"] == [plan.home.lat, plan.home.lon]
    assert circle["circle"]["radius"] == plan.mission.geofence.max_distance_m


def test_mavsdk_imports_the_plan_with_its_geofence(planned, tmp_path):
    """MAVSDK's own QGroundControl importer (needs a system: a bare heartbeat stands in for the autopilot)."""
    from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
    from mavsdk.asyncio.plugins.mission_raw import MissionRawAsync
    from pymavlink import mavutil

    from sim.process import free_port

    plan, files = planned
    path = tmp_path / "m.plan"
    path.write_bytes(files[f"{plan.mission.name}.plan"])
    port = free_port()
    stop = threading.Event()

    def heartbeat():
        link = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=1, source_component=1)
        while not stop.is_set():
            link.mav.heartbeat_send(mavutil.mavlink.MAV_TYPE_QUADROTOR, mavutil.mavlink.MAV_AUTOPILOT_PX4, 0, 0, 0)
            time.sleep(0.1)
        link.close()

    async def imported():
        m = Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION))
        try:
            await m.add_any_connection(f"udpin://127.0.0.1:{port}")
            system = await m.first_autopilot(timeout_s=60.0)
            assert system is not None, "no heartbeat reached mavsdk"
            return await MissionRawAsync(system).import_qgroundcontrol_mission(str(path))
        finally:
            m.destroy()

    beat = threading.Thread(target=heartbeat, daemon=True)
    beat.start()
    try:
        data = asyncio.run(imported())
    finally:
        stop.set()
        beat.join(5.0)
    raw = plan.mavlink_items("px4")
    assert [it.command for it in data.mission_items] == [it.command for it in raw]
    (fence,) = data.geofence_items
    assert fence.command == MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION
    assert fence.param1 == pytest.approx(plan.mission.geofence.max_distance_m)
    assert (fence.x / 1e7, fence.y / 1e7) == (pytest.approx(plan.home.lat, abs=1e-7),
                                              pytest.approx(plan.home.lon, abs=1e-7))


def test_geojson_is_rfc7946_two_d_with_heights_as_properties(planned):
    plan, files = planned
    doc = json.loads(files[f"{plan.mission.name}.geojson"])

    def positions(geom):
        c = geom["coordinates"]
        return [c] if geom["type"] == "Point" else c if geom["type"] == "LineString" else [p for r in c for p in r]

    for f in doc["features"]:
        assert all(len(p) == 2 for p in positions(f["geometry"])), f["properties"].get("name")
    polygons = [f for f in doc["features"] if f["geometry"]["type"] == "Polygon"]
    assert {f["properties"]["name"] for f in polygons} >= {"geofence"}
    for f in polygons:
        for k, ring in enumerate(f["geometry"]["coordinates"]):
            assert ring[0] == ring[-1]
            assert (signed_area_deg2(ring) > 0) == (k == 0)  # exterior counter-clockwise (holes would be clockwise)
    if plan.mission.facade.footprint is not None:
        assert any(f["properties"]["name"] == "building footprint" for f in polygons)
    fence = next(f for f in polygons if f["properties"]["name"] == "geofence")
    inside = PolyPath(fence["geometry"]["coordinates"][0]).contains_points([[w.lon, w.lat] for w in plan.waypoints])
    assert inside.all()
    pts = [f for f in doc["features"] if f["geometry"]["type"] == "Point"]
    for f, wp in zip(pts, plan.waypoints, strict=True):
        assert f["properties"]["alt_amsl_m"] == pytest.approx(plan.home.alt_amsl_m + wp.rel_alt_m, abs=1e-3)
    path = next(f for f in doc["features"] if f["properties"]["name"] == "scan path")
    assert path["properties"]["vertices"] == len(path["geometry"]["coordinates"]) == len(plan.waypoints) == len(pts)
    for f, (lon, lat) in zip(pts, path["geometry"]["coordinates"], strict=True):  # vertex k is the waypoint seq k
        assert f["geometry"]["coordinates"] == [lon, lat]
    assert path["properties"]["alt_amsl_max_m"] == pytest.approx(max(f["properties"]["alt_amsl_m"] for f in pts))
    kinds: dict[str, set[str]] = {}  # one JSON type per property name: GIS tools type a field once per layer
    for f in doc["features"]:
        for key, value in f["properties"].items():
            kinds.setdefault(key, set()).add("number" if isinstance(value, int | float) else type(value).__name__)
    assert {k: v for k, v in kinds.items() if len(v) > 1} == {}


def test_geojson_opens_in_gdal(planned, tmp_path):
    ogrinfo = shutil.which("ogrinfo")
    if ogrinfo is None:
        pytest.fail("ogrinfo is not installed: apt-get install -y gdal-bin (scripts/bootstrap.sh)")
    plan, files = planned
    path = tmp_path / "m.geojson"
    path.write_bytes(files[f"{plan.mission.name}.geojson"])
    out = subprocess.run([ogrinfo, "-ro", "-al", "-so", str(path)], capture_output=True, text=True, check=True).stdout
    assert f"Feature Count: {len(json.loads(path.read_text())['features'])}" in out
    assert "WGS 84" in out
    fields = dict(line.split(": ", 1) for line in out.splitlines() if line.endswith(")") and ": " in line)
    # every property a scalar: a list became RealList (text in a GeoPackage, refused by a shapefile)
    assert fields["alt_amsl_m"].startswith("Real (") and fields["rel_alt_m"].startswith("Real (")
    assert fields and not [name for name, kind in fields.items() if "List" in kind], fields


def test_kml_altitudes_are_the_mission_frame_above_sea_level(planned):
    plan, files = planned
    root = ET.fromstring(files[f"{plan.mission.name}.kml"])
    ns = {"k": "http://www.opengis.net/kml/2.2"}
    modes = {e.text for e in root.iter("{http://www.opengis.net/kml/2.2}altitudeMode")}
    assert modes == {"absolute"}
    points = [pm for pm in root.iterfind(".//k:Placemark", ns) if pm.find("k:Point", ns) is not None]
    nav = [it for it in plan.mavlink_items("px4") if it.command == 16]  # NAV_WAYPOINT, relative to home
    scan_points = [pm for pm in points if pm.findtext("k:name", "", ns).split()[1] in ("scan", "transit")]
    assert len(scan_points) == len(nav)
    for pm, it in zip(scan_points, nav, strict=True):
        lon, lat, alt = (float(v) for v in pm.findtext("k:Point/k:coordinates", "", ns).split(","))
        assert alt == pytest.approx(plan.home.alt_amsl_m + it.z, abs=1e-6)
        assert (lat, lon) == (pytest.approx(it.lat, abs=1e-7), pytest.approx(it.lon, abs=1e-7))

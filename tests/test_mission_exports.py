"""Exports are readable by the tools they are for, and `companion plan` writes all or nothing."""

from __future__ import annotations

import json
import math
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest
from pymavlink import mavwp

from companion.cli import main
from companion.mission import load_mission, plan_scan
from companion.mission.exports import qgc_plan_json, render_outputs

ROOT = Path(__file__).resolve().parents[1]
DEMO = ROOT / "missions" / "demo-facade.yaml"


@pytest.fixture(scope="module")
def plan():
    return plan_scan(load_mission(DEMO))


def test_wpl_110_loads_in_pymavlink(plan, tmp_path):
    files = render_outputs(plan)
    path = tmp_path / "demo.waypoints"
    path.write_bytes(files["demo-facade.waypoints"])
    loader = mavwp.MAVWPLoader()
    n = loader.load(str(path))
    items = plan.mavlink_items("ardupilot")
    assert n == len(items)
    for k, it in enumerate(items):
        w = loader.wp(k)
        assert w.command == it.command
        assert w.x == pytest.approx(it.lat, abs=1e-7) and w.y == pytest.approx(it.lon, abs=1e-7)
        assert w.z == pytest.approx(it.z, abs=1e-6)


def test_qgc_plan_holds_the_items(plan):
    doc = json.loads(qgc_plan_json(plan, "px4"))
    assert doc["fileType"] == "Plan" and doc["mission"]["firmwareType"] == 12
    items = doc["mission"]["items"]
    raw = plan.mavlink_items("px4")
    assert [i["command"] for i in items] == [r.command for r in raw]
    nav = [i for i in items if i["command"] == 16]
    wps = [w for w in plan.waypoints if w.kind in ("scan", "transit")]
    for item, wp in zip(nav, wps, strict=True):
        lat, lon, alt = item["params"][4:7]
        assert (lat, lon) == (pytest.approx(wp.lat, abs=1e-7), pytest.approx(wp.lon, abs=1e-7))
        assert alt == pytest.approx(wp.rel_alt_m, abs=1e-6) and item["frame"] == 3
    assert doc["mission"]["plannedHomePosition"][:2] == [plan.home.lat, plan.home.lon]
    ap = json.loads(qgc_plan_json(plan, "ardupilot"))
    assert ap["mission"]["firmwareType"] == 3 and ap["mission"]["items"][0]["command"] == 22


def test_geojson_kml_and_raw_items(plan):
    files = render_outputs(plan)
    gj = json.loads(files["demo-facade.geojson"])
    path = next(f for f in gj["features"] if f["properties"].get("name") == "scan path")
    assert len(path["geometry"]["coordinates"]) == len(plan.waypoints)
    pts = [f for f in gj["features"] if f["geometry"]["type"] == "Point"]
    assert all(abs(p["properties"]["standoff_m"] - 4.0) < 0.05 for p in pts if p["properties"]["kind"] == "scan")
    root = ET.fromstring(files["demo-facade.kml"])
    coords = [e.text for e in root.iter() if e.tag.endswith("coordinates")]
    assert len(coords) >= 2 + len(plan.waypoints)
    raw = json.loads(files["mavlink_items_px4.json"])["mission_items"]
    assert raw[0]["command"] == 22 and raw[0]["param4"] is None  # NaN yaw stored as null
    assert files["demo-facade-path.png"].startswith(b"\x89PNG")
    mavsdk_items = json.loads(files["mavsdk_mission.json"])["mission_items"]
    assert all(not math.isnan(i["latitude_deg"]) for i in mavsdk_items)


def test_cli_plan_writes_everything(tmp_path, capsys):
    assert main(["plan", str(DEMO), "--out", str(tmp_path / "out")]) == 0
    out = capsys.readouterr().out
    assert "GSD 1.43 mm/px" in out and "keyframes" in out and "flight time" in out
    names = {p.name for p in (tmp_path / "out").iterdir()}
    assert {"demo-facade.plan", "demo-facade.waypoints", "demo-facade.kml", "demo-facade.geojson"} <= names
    assert {"mavsdk_mission.json", "mavlink_items_px4.json", "summary.json", "demo-facade-path.png"} <= names
    assert not [n for n in names if n.startswith(".plan-")]  # no staging leftovers


def test_cli_bad_mission_exits_nonzero_and_writes_nothing(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text(DEMO.read_text().replace("overlap: 0.80", "overlap: 1.5"))
    out = tmp_path / "out"
    proc = subprocess.run(
        [sys.executable, "-m", "companion.cli", "plan", str(bad), "--out", str(out)], capture_output=True, text=True
    )
    assert proc.returncode == 2
    assert "overlap" in proc.stderr and "fix:" in proc.stderr
    assert not out.exists() or not any(out.iterdir())


def test_cli_keeps_existing_outputs_when_a_new_plan_fails(tmp_path):
    out = tmp_path / "out"
    assert main(["plan", str(DEMO), "--out", str(out)]) == 0
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    bad = tmp_path / "bad.yaml"
    bad.write_text(DEMO.read_text().replace("max_alt_m: 40.0", "max_alt_m: 5.0"))
    assert main(["plan", str(bad), "--out", str(out)]) == 2
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before


def test_exported_positions_carry_no_float_noise(plan):
    """Positions to 1e-8 degree and heights to the mm (issue 29: 37.56649999999999 in the exports)."""
    files = render_outputs(plan)
    items = json.loads(files["mavsdk_mission.json"])["mission_items"]
    values = [it[k] for it in items for k in ("latitude_deg", "longitude_deg", "relative_altitude_m")]
    assert all(v == round(v, 8) for v in values[0::3] + values[1::3]) and all(v == round(v, 3) for v in values[2::3])
    assert all(len(repr(v).split(".")[-1]) <= 8 for v in values), values
    text = files["demo-facade.waypoints"].decode()
    assert "37.56649999" not in text and "37.56638000\t126.97815000" in text  # home, as the mission gives it

"""Bad mission input: each gets a CompanionError naming the field and the fix."""

from __future__ import annotations

import copy
from pathlib import Path

import pytest
import yaml

from companion.errors import CompanionError
from companion.mission import load_mission, parse_mission, plan_scan

DEMO = Path(__file__).resolve().parents[1] / "missions" / "demo-facade.yaml"


@pytest.fixture
def demo() -> dict:
    return yaml.safe_load(DEMO.read_text())


def _error(data: dict) -> CompanionError:
    with pytest.raises(CompanionError) as exc:
        plan_scan(parse_mission(data, "m.yaml"))
    return exc.value


def test_examples_load_and_plan():
    for path in sorted(DEMO.parent.glob("*.yaml")):
        plan = plan_scan(load_mission(path))
        assert plan.scan_legs, path


def test_unknown_key_suggests_the_right_name(demo):
    demo["standof_m"] = demo.pop("standoff_m")
    err = _error(demo)
    assert "standof_m" in err.problem and "did you mean 'standoff_m'" in err.problem
    assert "missing field 'standoff_m'" in err.problem


def test_nested_unknown_key(demo):
    demo["camera"]["hfov"] = 60
    err = _error(demo)
    assert "camera.hfov" in err.problem and "hfov_deg" in err.problem


@pytest.mark.parametrize("value", [1.0, 0.0, 1.2, -0.3, 0.3, 0.99])
def test_impossible_or_out_of_range_overlap(demo, value):
    demo["overlap"] = value
    err = _error(demo)
    assert "overlap" in err.problem and err.fix and "0.50 and 0.95" in err.fix


@pytest.mark.parametrize("field,value", [("lat", 91.0), ("lat", float("nan")), ("lon", -181.0)])
def test_invalid_lat_lon(demo, field, value):
    demo["facade"]["start"][field] = value
    err = _error(demo)
    assert f"facade.start.{field}" in err.problem


def test_zero_length_wall(demo):
    demo["facade"]["end"] = dict(demo["facade"]["start"])
    err = _error(demo)
    assert "zero length" in err.problem and "start" in err.fix


def test_unsafe_standoff_refused_unless_overridden(demo):
    demo["standoff_m"] = 1.0
    err = _error(demo)
    assert "safe minimum" in err.problem and "allow_unsafe_standoff" in err.fix and "(top level)" not in str(err)
    demo["allow_unsafe_standoff"] = True
    demo.pop("takeoff")
    plan = plan_scan(parse_mission(demo))
    assert all(abs(w.out_m - 1.0) < 0.05 for w in plan.waypoints if w.kind == "scan")


@pytest.mark.parametrize(
    "field,value",
    [("hfov_deg", 0.0), ("hfov_deg", 200.0), ("width_px", 10), ("fps", 0), ("exposure_s", 2.0), ("fps", "fast")],
)
def test_camera_values_out_of_range(demo, field, value):
    demo["camera"][field] = value
    err = _error(demo)
    assert f"camera.{field}" in err.problem and "camera" in err.fix


def test_missing_fields(demo):
    del demo["facade"]["height_m"]
    del demo["camera"]
    err = _error(demo)
    assert "missing field 'facade.height_m'" in err.problem and "missing field 'camera'" in err.problem


def test_path_leaving_the_geofence(demo):
    demo["geofence"]["max_alt_m"] = 10.0
    err = _error(demo)
    assert "geofence" in err.problem and "max_alt_m" in err.fix
    demo["geofence"] = {"max_alt_m": 100.0, "max_distance_m": 15.0}
    err = _error(demo)
    assert "max_distance_m" in err.problem


def test_takeoff_behind_the_wall_is_refused(demo):
    demo["takeoff"] = {"lat": 37.56660, "lon": 126.97815}  # north of the wall: the building side
    err = _error(demo)
    assert "behind the wall" in err.problem


def test_malformed_yaml_and_missing_file(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: x\nfacade: [unclosed\n")
    with pytest.raises(CompanionError, match="not valid YAML"):
        load_mission(bad)
    with pytest.raises(CompanionError, match="does not exist"):
        load_mission(tmp_path / "nope.yaml")
    (tmp_path / "list.yaml").write_text("- 1\n- 2\n")
    with pytest.raises(CompanionError, match="YAML mapping"):
        load_mission(tmp_path / "list.yaml")


def test_footprint_face_orientation_matches_explicit_ends(demo):
    """A face of a CCW footprint and the same face of the CW ring give the same outward side."""
    ring = [[126.97800, 37.56650], [126.97830, 37.56650], [126.97830, 37.56670], [126.97800, 37.56670]]
    for coords, face in ((ring, 0), (list(reversed(ring)), 2)):
        d = copy.deepcopy(demo)
        d["facade"] = {
            "footprint": {"coordinates": coords, "face": face},
            "ground_alt_amsl_m": 30.0,
            "height_m": 12.0,
        }
        plan = plan_scan(parse_mission(d))
        ref = plan_scan(parse_mission(demo))
        assert plan.frame.length_m == pytest.approx(ref.frame.length_m, abs=1e-6)
        assert plan.frame.yaw_facing_wall_deg == pytest.approx(ref.frame.yaw_facing_wall_deg, abs=1e-6)


def test_footprint_geojson_file_and_bad_face(tmp_path, demo):
    ring = [[126.97800, 37.56650], [126.97830, 37.56650], [126.97830, 37.56670], [126.97800, 37.56670]]
    gj = {"type": "Feature", "geometry": {"type": "Polygon", "coordinates": [ring + [ring[0]]]}}
    (tmp_path / "b.geojson").write_text(yaml.safe_dump(gj))  # JSON is YAML, but write real JSON:
    import json

    (tmp_path / "b.geojson").write_text(json.dumps(gj))
    demo["facade"] = {"footprint": {"geojson": "b.geojson", "face": 7}, "ground_alt_amsl_m": 30.0, "height_m": 12.0}
    (tmp_path / "m.yaml").write_text(yaml.safe_dump(demo))
    with pytest.raises(CompanionError, match="face=7"):
        plan_scan(load_mission(tmp_path / "m.yaml"))
    demo["facade"]["footprint"]["face"] = 0
    (tmp_path / "m.yaml").write_text(yaml.safe_dump(demo))
    assert plan_scan(load_mission(tmp_path / "m.yaml")).frame.length_m == pytest.approx(26.45, abs=0.1)


def test_depth_model_is_resolved_next_to_the_mission_and_used_by_the_chain(tmp_path, demo):
    from companion.capture.tagging import FrameTagger
    from companion.capture.telemetry import ClockMap, TelemetryBuffer
    from companion.depth.session import DEFAULT_MODEL
    from companion.onboard.setup import build_chain

    (tmp_path / "models").mkdir()
    chosen = tmp_path / "models" / "my-depth.onnx"
    chosen.write_bytes(DEFAULT_MODEL.read_bytes())
    path = tmp_path / "m.yaml"
    path.write_text(yaml.safe_dump({**demo, "depth_model": "models/my-depth.onnx"}))
    mission = load_mission(path)
    assert Path(mission.depth_model) == chosen.resolve()
    tagger = FrameTagger(TelemetryBuffer(), ClockMap(0.0))
    chain = build_chain(tmp_path / "spool", tagger, mission=mission)
    assert chain.masker.session.info.path == chosen.resolve()
    # a command's --model wins over the mission's choice
    chain = build_chain(tmp_path / "spool2", tagger, mission=mission, model=DEFAULT_MODEL)
    assert chain.masker.session.info.path == DEFAULT_MODEL


def test_missing_depth_model_names_the_field(tmp_path, demo):
    path = tmp_path / "m.yaml"
    path.write_text(yaml.safe_dump({**demo, "depth_model": "nope.onnx"}))
    with pytest.raises(CompanionError) as exc:
        load_mission(path)
    assert "depth_model" in exc.value.problem and "nope.onnx" in exc.value.problem
    assert "relative to the mission file" in exc.value.fix


def test_min_distance_is_optional_and_must_be_below_the_standoff(demo):
    assert parse_mission(demo).min_distance_m is None
    demo["min_distance_m"] = 3.0
    assert parse_mission(demo).min_distance_m == 3.0
    demo["min_distance_m"] = 3.9  # standoff 4: within the tolerance of it
    err = _error(demo)
    assert "min_distance_m must be below standoff_m" in err.problem and "min_distance_m below the standoff" in err.fix

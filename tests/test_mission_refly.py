"""Re-fly missions from a stitched map's uncovered areas: coverage with the planned overlap, nothing far away,
the planner's takeoff/transit/landing, exports written; clear messages for nothing to re-fly and wrong folders."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from companion.cli import main
from companion.errors import CompanionError
from companion.mission import load_mission, plan_scan
from companion.mission.planner import scan_extent
from companion.mission.refly import overlap_margins, plan_refly, refly_to_dir
from companion.stitch.output import WallAnchor

DEMO = Path(__file__).resolve().parents[1] / "missions" / "demo-facade.yaml"

# Two holes far apart on the 26.5 m x 12 m demo wall: a missing window high on the left, a band low on the right.
TWO_AREAS = [
    {"along_min_m": 3.0, "along_max_m": 4.2, "up_min_m": 8.0, "up_max_m": 9.0, "area_m2": 1.2},
    {"along_min_m": 19.5, "along_max_m": 22.0, "up_min_m": 3.0, "up_max_m": 3.6, "area_m2": 1.5},
]


def _write_map(d: Path, areas: list[dict], *, mission=None, rectified: bool = True, georef: bool = True) -> Path:
    """A map folder as `companion stitch` writes it: report.json (areas in wall metres) and map_georef.json."""
    d.mkdir(parents=True, exist_ok=True)
    report = {"coverage_fraction": 0.9, "map": {"rectified_to_facade": rectified}, "uncovered_areas_m": areas}
    (d / "report.json").write_text(json.dumps(report))
    if georef:
        plan = plan_scan(mission or load_mission(DEMO))
        wall = WallAnchor.from_facade(plan.frame, plan.mission.facade.height_m).as_dict()
        (d / "map_georef.json").write_text(json.dumps({"scale_known": True, "wall": wall}))
    return d


def _camera_footprints(plan, step_m: float = 0.05) -> list[tuple[float, float, float, float]]:
    """(along0, along1, up0, up1) of every frame the camera takes along the scan legs, sampled every ``step_m``."""
    fw, fh = plan.footprint.width_m, plan.footprint.height_m
    out = []
    for i, j in plan.scan_legs:
        p = np.array([plan.waypoints[i].along_m, plan.waypoints[i].up_m])
        q = np.array([plan.waypoints[j].along_m, plan.waypoints[j].up_m])
        n = max(1, int(np.ceil(np.linalg.norm(q - p) / step_m)))
        for t in np.linspace(0.0, 1.0, n + 1):
            a, u = p + t * (q - p)
            out.append((a - fw / 2, a + fw / 2, u - fh / 2, u + fh / 2))
    return out


@pytest.mark.parametrize("pattern", ["vertical", "horizontal"])
def test_two_areas_covered_with_the_planned_overlap_and_nothing_far(tmp_path, pattern):
    mission = load_mission(DEMO).model_copy(update={"pattern": pattern})
    full = plan_scan(mission)
    refly = plan_refly(mission, _write_map(tmp_path / "map", TWO_AREAS, mission=mission))
    plan = refly.plan
    assert plan is not None and len(refly.groups) == 2
    ma, mu = overlap_margins(mission)
    fp = plan.footprint
    if pattern == "vertical":  # across strips: side overlap; along a strip: the keyframe overlap
        assert (ma, mu) == pytest.approx((fp.width_m * mission.side_overlap, fp.height_m * mission.overlap))
    else:
        assert (ma, mu) == pytest.approx((fp.width_m * mission.overlap, fp.height_m * mission.side_overlap))
    frames = _camera_footprints(plan)
    tol = 1e-6
    for area in TWO_AREAS:
        # every point of the area grown by the overlap margins (within the scannable wall) is in some frame: the
        # frames at the area's edges keep showing `overlap` of their footprint of the existing map
        ext = scan_extent(mission, plan.frame.length_m)
        pa = np.linspace(
            max(area["along_min_m"] - ma, ext.along_min_m) + tol,
            min(area["along_max_m"] + ma, ext.along_max_m) - tol,
            40,
        )
        pu = np.linspace(
            max(area["up_min_m"] - mu, ext.up_min_m) + tol, min(area["up_max_m"] + mu, ext.up_max_m) - tol, 40
        )
        for a in pa:
            for u in pu:
                assert any(f[0] <= a <= f[1] and f[2] <= u <= f[3] for f in frames), (a, u)
    # nothing far: every frame lies inside one area grown by the margins
    for f in frames:
        assert any(
            f[0] >= a["along_min_m"] - ma - tol
            and f[1] <= a["along_max_m"] + ma + tol
            and f[2] >= a["up_min_m"] - mu - tol
            and f[3] <= a["up_max_m"] + mu + tol
            for a in TWO_AREAS
        ), f
    # the planner's rules: scan at the standoff, same takeoff/landing, entrance and exit altitudes as the full plan
    assert all(abs(w.out_m - mission.standoff_m) < 1e-9 for w in plan.waypoints if w.kind == "scan")
    for k in (0, -1, -2):
        assert (plan.waypoints[k].kind, plan.waypoints[k].lat, plan.waypoints[k].lon, plan.waypoints[k].rel_alt_m) == (
            full.waypoints[k].kind,
            full.waypoints[k].lat,
            full.waypoints[k].lon,
            full.waypoints[k].rel_alt_m,
        )
    assert plan.waypoints[1].rel_alt_m == full.waypoints[1].rel_alt_m
    assert plan.estimates.scan_speed_m_s == full.estimates.scan_speed_m_s
    assert plan.estimates.path_length_m < 0.5 * full.estimates.path_length_m  # short: only the holes


def test_exports_written_like_any_plan(tmp_path):
    map_dir = _write_map(tmp_path / "map", TWO_AREAS)
    out = tmp_path / "refly"
    refly, written = refly_to_dir(DEMO, map_dir, out)
    names = {p.name for p in written}
    stem = "demo-facade-refly"
    assert names == {
        "mavsdk_mission.json",
        "mavlink_items_px4.json",
        "mavlink_items_ardupilot.json",
        f"{stem}.plan",
        f"{stem}-ardupilot.plan",
        f"{stem}.waypoints",
        f"{stem}.kml",
        f"{stem}.geojson",
        "summary.json",
        f"{stem}-path.png",
    }
    assert all((out / n).stat().st_size > 0 for n in names)
    # the exports are of the re-fly path: the mavsdk items are its waypoints (takeoff and landing are mavsdk's own)
    items = json.loads((out / "mavsdk_mission.json").read_text())["mission_items"]
    flown = [w for w in refly.plan.waypoints if w.kind not in ("takeoff", "land")]
    assert [(i["latitude_deg"], i["longitude_deg"], i["relative_altitude_m"]) for i in items] == [
        (w.lat, w.lon, w.rel_alt_m) for w in flown
    ]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["mission"] == stem and summary["waypoints"] == len(refly.plan.waypoints)


def test_nearby_areas_are_flown_as_one_group(tmp_path):
    areas = [
        {"along_min_m": 10.0, "along_max_m": 10.8, "up_min_m": 6.0, "up_max_m": 6.5, "area_m2": 0.4},
        {"along_min_m": 12.0, "along_max_m": 12.5, "up_min_m": 7.0, "up_max_m": 8.0, "area_m2": 0.5},
    ]
    refly = plan_refly(load_mission(DEMO), _write_map(tmp_path / "map", areas))
    assert len(refly.groups) == 1 and len(refly.groups[0].areas) == 2


def test_nothing_to_refly_is_a_message_and_exit_0_without_files(tmp_path, capsys):
    map_dir = _write_map(tmp_path / "map", [])
    out = tmp_path / "out"
    assert main(["plan", str(DEMO), "--refly", str(map_dir), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "nothing to re-fly" in printed and "no mission written" in printed
    assert not out.exists()


def test_area_below_the_bottom_clearance_is_left_out_with_the_reason(tmp_path):
    mission = load_mission(DEMO).model_copy(
        update={"margins": load_mission(DEMO).margins.model_copy(update={"bottom_clearance_m": 3.0})}
    )
    area = [{"along_min_m": 5.0, "along_max_m": 6.0, "up_min_m": 0.0, "up_max_m": 0.5, "area_m2": 0.5}]
    refly = plan_refly(mission, _write_map(tmp_path / "map", area))
    assert refly.plan is None and "nothing to re-fly" in refly.message
    assert len(refly.skipped) == 1 and "bottom_clearance" in refly.skipped[0]


def test_folder_without_report_names_the_file_and_the_fix(tmp_path, capsys):
    (tmp_path / "notamap").mkdir()
    with pytest.raises(CompanionError) as exc:
        plan_refly(load_mission(DEMO), tmp_path / "notamap")
    assert "report.json" in exc.value.problem and "companion stitch" in exc.value.fix
    assert main(["plan", str(DEMO), "--refly", str(tmp_path / "notamap"), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "report.json" in err and "fix:" in err
    assert not (tmp_path / "o").exists()


def test_map_without_wall_metres_or_of_another_wall_is_refused(tmp_path):
    with pytest.raises(CompanionError, match="not rectified"):
        plan_refly(load_mission(DEMO), _write_map(tmp_path / "a", TWO_AREAS, rectified=False))
    other = load_mission(DEMO)
    facade = other.facade.model_copy(
        update={"start": other.facade.start.model_copy(update={"lat": other.facade.start.lat + 0.0001})}
    )
    with pytest.raises(CompanionError, match="another wall"):
        plan_refly(
            load_mission(DEMO),
            _write_map(tmp_path / "b", TWO_AREAS, mission=other.model_copy(update={"facade": facade})),
        )


def test_map_without_georef_is_planned_with_a_note(tmp_path):
    refly = plan_refly(load_mission(DEMO), _write_map(tmp_path / "m", TWO_AREAS, georef=False))
    assert refly.plan is not None and any("map_georef.json" in n for n in refly.notes)


def test_refly_of_a_real_stitch_covers_its_hole(missing_patch_map, tmp_path):
    """End to end: a synthetic spool whose keyframes all miss one wall patch, stitched by `companion stitch`
    (tests/conftest.py ``missing_patch_map``, shared with tests/test_stitch_worker.py), re-flown by `companion plan
    --refly`: the re-fly frames cover the patch the map lacks."""
    from tests.hole_wall import HOLE as hole  # along0, along1, up0, up1: no keyframe shows it (flown at 2 m)

    _, truth, map_dir = missing_patch_map
    frame = truth["frame"]
    end_lat, end_lon, _ = frame.facade_to_geodetic(frame.length_m, 0.0, 0.0)
    mission = {
        "name": "synthetic-wall",
        "facade": {
            "start": {"lat": frame.origin.lat, "lon": frame.origin.lon},
            "end": {"lat": float(end_lat), "lon": float(end_lon)},
            "ground_alt_amsl_m": frame.origin.alt_amsl_m,
            "height_m": 4.0,
        },
        "standoff_m": 4.0,
        "overlap": 0.6,
        "camera": {"width_px": 640, "height_px": 360, "hfov_deg": 70.0, "fps": 30, "exposure_s": 0.002},
    }
    path = tmp_path / "wall.yaml"
    path.write_text(json.dumps(mission))  # JSON is YAML
    out = tmp_path / "refly"
    assert main(["plan", str(path), "--refly", str(map_dir), "--out", str(out)]) == 0
    refly, _ = refly_to_dir(path, map_dir, tmp_path / "again")
    assert (out / "synthetic-wall-refly.plan").is_file() and (out / "mavsdk_mission.json").is_file()
    frames = _camera_footprints(refly.plan)
    for a in np.linspace(hole[0], hole[1], 9):
        for u in np.linspace(hole[2], hole[3], 9):
            assert any(f[0] <= a <= f[1] and f[2] <= u <= f[3] for f in frames), (a, u)
    assert refly.plan.estimates.path_length_m < plan_scan(load_mission(path)).estimates.path_length_m


def test_map_edge_sliver_is_left_out_unless_asked_for(tmp_path):
    sliver = [{"along_min_m": 26.49, "along_max_m": 26.51, "up_min_m": 0.0, "up_max_m": 12.0, "area_m2": 0.24}]
    map_dir = _write_map(tmp_path / "map", [*TWO_AREAS[:1], *sliver])
    refly = plan_refly(load_mission(DEMO), map_dir)
    assert len(refly.groups) == 1 and refly.groups[0].areas[0].along_min_m == 3.0
    assert len(refly.skipped) == 1 and "2.0 cm thin" in refly.skipped[0]
    assert len(plan_refly(load_mission(DEMO), map_dir, min_size_m=0.0, min_area_m2=0.0).groups) == 2


def test_seam_sliver_and_small_patch_are_reported_not_flown(tmp_path, capsys):
    # the case: a seam 0.1 m wide down the wall (0.75 m2) gave two full-height strips 0.13 m apart
    seam = {"along_min_m": 10.0, "along_max_m": 10.1, "up_min_m": 2.0, "up_max_m": 9.5, "area_m2": 0.75}
    patch = {"along_min_m": 15.0, "along_max_m": 15.4, "up_min_m": 5.0, "up_max_m": 5.4, "area_m2": 0.16}
    map_dir = _write_map(tmp_path / "map", [seam, patch])
    refly = plan_refly(load_mission(DEMO), map_dir)
    assert refly.plan is None and "nothing to re-fly" in refly.message
    assert refly.skipped == (
        "along 10.00..10.10 m, up 2.00..9.50 m: only 10.0 cm thin, under the 20 cm minimum (a sliver)",
        "along 15.00..15.40 m, up 5.00..5.40 m: only 0.16 m2, under the 0.25 m2 minimum",
    )
    flown = plan_refly(load_mission(DEMO), map_dir, min_size_m=0.0, min_area_m2=0.0)
    assert flown.plan is not None and not flown.skipped  # asked for: flown
    out = tmp_path / "out"
    assert main(["plan", str(DEMO), "--refly", str(map_dir), "--out", str(out), "--refly-min-size-m", "0.05",
                 "--refly-min-area-m2", "0.1"]) == 0
    printed = capsys.readouterr().out
    assert "re-fly of 2 uncovered area(s)" in printed and out.exists()


def test_printed_metres_have_no_negative_zero_and_a_mm_clip_is_no_note(tmp_path, capsys):
    extent = scan_extent(load_mission(DEMO), plan_scan(load_mission(DEMO)).frame.length_m)
    top = extent.up_max_m
    areas = [
        {"along_min_m": -2.004, "along_max_m": 1.0, "up_min_m": 12.0, "up_max_m": top + 0.004, "area_m2": 6.0},
        {"along_min_m": 20.0, "along_max_m": 21.0, "up_min_m": 12.0, "up_max_m": top + 0.5, "area_m2": 2.5},
        {"along_min_m": -0.004, "along_max_m": 0.05, "up_min_m": 0.0, "up_max_m": 3.0, "area_m2": 0.16},
    ]
    map_dir = _write_map(tmp_path / "map", areas)
    refly = plan_refly(load_mission(DEMO), map_dir)
    assert len(refly.notes) == 1 and refly.notes[0].startswith("along 20.00..21.00 m"), refly.notes  # 4 mm: said not
    assert refly.skipped[0].startswith("along 0.00..0.05 m"), refly.skipped
    assert main(["plan", str(DEMO), "--refly", str(map_dir), "--out", str(tmp_path / "out")]) == 0
    printed = capsys.readouterr().out
    assert "-0.00" not in printed and "along 0.00..0.05 m" in printed, printed

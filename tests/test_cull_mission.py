"""`companion cull` as the README shows it (issue 29): the mission is found in a recording or the cull is refused
with the fix; a map without scale never speaks in metres (no world file, areas in pixels, the reason and the fix),
and a re-fly of it names the same fix instead of blaming the telemetry."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import exifread
import pytest

from companion.cli import main
from companion.spool.layout import MANIFEST, META

SMALL_WALL = Path(__file__).parent / "data" / "small-wall.yaml"


@pytest.fixture
def recording(small_recording) -> Path:
    return small_recording  # conftest.py: small-wall, 24 frames of 320 px


def test_a_recording_culls_with_its_own_mission(recording, tmp_path, capsys):
    spool = tmp_path / "spool"
    assert main(["cull", str(recording / "frames"), "--telemetry", str(recording / "telemetry.jsonl"),
                 "--out", str(spool), "--no-mask"]) == 0
    assert f"mission: {SMALL_WALL.resolve()}" in capsys.readouterr().err
    meta = json.loads((spool / META).read_text())
    assert meta["mission"] == "small-wall" and meta["standoff_m"] == 4.0
    first = json.loads((spool / MANIFEST).read_text().splitlines()[0])["image"]
    with open(spool / first, "rb") as fh:
        tags = exifread.process_file(fh, details=False)
    assert "EXIF FocalLength" in tags and "Image Make" in tags  # the camera ODM and COLMAP need


def test_frames_without_a_mission_are_refused_with_the_fix(recording, tmp_path, capsys):
    frames = tmp_path / "frames"  # the same frames, out of their recording: nothing says which wall they show
    shutil.copytree(recording / "frames", frames)
    spool = tmp_path / "spool"
    code = main(["cull", str(frames), "--telemetry", str(recording / "telemetry.jsonl"), "--out", str(spool),
                 "--no-mask"])
    err = capsys.readouterr().err
    assert code == 2 and "Traceback" not in err
    assert "error: no mission for" in err and "no scale" in err and "fix: pass --mission FILE" in err
    assert not spool.exists()


def test_a_map_without_scale_speaks_in_pixels_and_says_why(recording, tmp_path, capsys):
    spool, map_dir = tmp_path / "spool", tmp_path / "map"
    assert main(["cull", str(recording / "frames"), "--telemetry", str(recording / "telemetry.jsonl"),
                 "--out", str(spool), "--no-mask", "--no-mission"]) == 0
    assert not (spool / META).exists()
    capsys.readouterr()
    assert main(["stitch", str(spool), "--out", str(map_dir), "--quiet"]) == 0
    out = capsys.readouterr().out
    assert "the map has no scale" in out and "--mission FILE" in out
    assert " m2" not in out and " m, up" not in out, out  # no plane units printed as metres
    report = json.loads((map_dir / "report.json").read_text())
    assert report["map"]["mm_per_px"] is None and report["map"]["along_m"] is None
    assert report["uncovered_areas_m"] is None and report["uncovered_areas_px"], report["uncovered_areas_px"]
    assert "culled without a mission" in report["scale_unknown"]["why"]
    assert not (map_dir / "map.pgw").exists()  # no world file claiming metres
    assert main(["plan", str(SMALL_WALL), "--refly", str(map_dir), "--out", str(tmp_path / "refly")]) == 2
    err = capsys.readouterr().err
    assert "has no scale" in err and "fix: cull the flight again with --mission FILE" in err
    assert not (tmp_path / "refly").exists()

"""The facade map opens at true scale in GDAL: world file + CRS in wall metres, alpha for uncovered, anchor sidecar.

Distances are checked against the synthetic wall's texture, whose metres are known exactly: two texture patches
are found in the map, and GDAL's own geotransform (gdalinfo) turns their map pixels into wall metres.
gdalinfo is Debian's gdal-bin: a missing gdalinfo fails with the install command.
"""

from __future__ import annotations

import json
import math
import shutil
import subprocess
from pathlib import Path

import cv2
import numpy as np
import pytest

from companion.spool.layout import META
from companion.stitch import load_input
from companion.stitch.output import WallAnchor, write_georeferencing
from tests.hole_wall import HOLE, WALL, map_copy


def gdal(tool: str, *args: str) -> str:
    exe = shutil.which(tool)
    if exe is None:
        pytest.fail(f"{tool} is not installed: apt-get install -y gdal-bin (scripts/bootstrap.sh)")
    return subprocess.run([exe, *args], capture_output=True, text=True, check=True).stdout


@pytest.fixture(scope="module")
def spool(hole_wall_spool):
    """tests/hole_wall.py's spool: stitched once per session (tests/conftest.py)."""
    return hole_wall_spool


@pytest.fixture(scope="module")
def mapped(spool, hole_wall_map, tmp_path_factory):
    d, _ = spool
    inp = load_input(d)
    res = map_copy(hole_wall_map, tmp_path_factory.mktemp("out") / "map")  # its own folder to georeference again
    files = write_georeferencing(res, inp, name="synthetic wall")
    return res, inp, files


def _find(map_bgr: np.ndarray, texture: np.ndarray, along_m: float, up_m: float, m_per_px: float) -> np.ndarray:
    """Map pixel (x, y) of the texture point (along, up), found by matching a patch of the texture around it."""
    st = WALL.texture_mm_per_px / 1000.0
    half = int(0.25 / st)  # a 0.5 m patch
    cx, cy = int(round(along_m / st)), int(round((WALL.height_m - up_m) / st))
    patch = texture[cy - half : cy + half, cx - half : cx + half]
    k = st / m_per_px
    patch = cv2.resize(patch, None, fx=k, fy=k, interpolation=cv2.INTER_AREA if k < 1 else cv2.INTER_LINEAR)
    score = cv2.matchTemplate(map_bgr, patch, cv2.TM_CCOEFF_NORMED)
    _, best, _, (x, y) = cv2.minMaxLoc(score)
    assert best > 0.8
    # patch centre: texture pixel cx sits at cx * st (pixel_centre 0); in the resized patch at half * k
    return np.array([x + half * k - 0.5 * (k - 1), y + half * k - 0.5 * (k - 1)])


def test_gdal_reads_the_map_in_wall_metres(spool, mapped):
    _, truth = spool
    res, _, files = mapped
    info = json.loads(gdal("gdalinfo", "-json", files["map"]))
    assert info["size"] == [res.grid.width, res.grid.height]
    a, b, _, d, _, f = info["geoTransform"]
    assert b == pytest.approx(res.grid.m_per_px) and f == pytest.approx(-res.grid.m_per_px)
    assert 'LENGTHUNIT["metre",1' in info["coordinateSystem"]["wkt"]
    assert [band["colorInterpretation"] for band in info["bands"]] == ["Red", "Green", "Blue", "Alpha"]
    bgra = cv2.imread(files["map"], cv2.IMREAD_UNCHANGED)
    pts_m = []
    for along, up in ((1.2, 1.0), (6.8, 3.1)):
        x, y = _find(bgra[..., :3], truth["texture"], along, up, b)
        # GDAL: the geotransform maps the pixel's corner coordinates; its centre is at +0.5
        m = np.array([a + (x + 0.5) * b, d + (y + 0.5) * f])
        assert m == pytest.approx([along, up], abs=0.01)  # where GDAL says it is = where it is on the wall
        pts_m.append(m)
    true_len = math.hypot(6.8 - 1.2, 3.1 - 1.0)
    assert np.linalg.norm(pts_m[1] - pts_m[0]) == pytest.approx(true_len, rel=0.002)


def test_uncovered_is_transparent_and_covered_opaque(mapped):
    res, _, files = mapped
    bgra = cv2.imread(files["map"], cv2.IMREAD_UNCHANGED)
    assert bgra.shape[2] == 4
    assert np.array_equal(bgra[..., 3], res.coverage)
    g = res.grid
    x0, y0 = g.to_px(np.array([HOLE[0] + 0.1, HOLE[3] - 0.1])).astype(int)
    x1, y1 = g.to_px(np.array([HOLE[1] - 0.1, HOLE[2] + 0.1])).astype(int)
    # inside the facade (the grid also grows past it by the map's placement uncertainty, where nothing is drawn)
    f0 = np.floor(g.to_px(np.array([0.0, WALL.height_m]))).astype(int)
    f1 = np.ceil(g.to_px(np.array([WALL.length_m, 0.0]))).astype(int)
    facade = bgra[max(f0[1], 0):f1[1], max(f0[0], 0):f1[0], 3]
    assert np.all(bgra[y0:y1, x0:x1, 3] == 0) and (facade == 255).mean() > 0.9


def test_sidecar_anchors_the_wall_and_the_keyframes(spool, mapped):
    d, truth = spool
    res, inp, files = mapped
    doc = json.loads(Path(files["georef"]).read_text())
    wall = doc["wall"]
    meta = json.loads((d / META).read_text())["facade"]
    assert wall["start"] == {"lat": pytest.approx(meta["start"]["lat"]), "lon": pytest.approx(meta["start"]["lon"])}
    assert wall["end"]["lat"] == pytest.approx(meta["end"]["lat"], abs=1e-9)
    assert wall["end"]["lon"] == pytest.approx(meta["end"]["lon"], abs=1e-9)
    assert wall["ground_alt_amsl_m"] == meta["ground_alt_amsl_m"] and wall["length_m"] == pytest.approx(8.0, abs=1e-3)
    # a west -> east wall is flown from the south: it faces south; the map's +x runs east
    assert wall["face_azimuth_deg"] == pytest.approx(180.0, abs=1e-3)
    assert wall["along_azimuth_deg"] == pytest.approx(90.0, abs=1e-3)
    assert doc["scale_known"] and doc["mm_per_px"] == pytest.approx(res.mm_per_px, rel=1e-6)
    assert doc["files"] == {"map": "map.png", "world_file": "map.pgw", "crs": "map.png.aux.xml"}
    # footprints: each keyframe's wall area per telemetry, as wide as the camera sees at the standoff
    fps = doc["keyframes"]
    assert len(fps) == len(inp.keyframes)
    width_m = 2 * 4.0 * math.tan(math.radians(35.0))  # standoff 4 m, hfov 70 deg (synthetic.make_spool)
    for fp in fps:
        (a0, u0), (a1, _), (_, u2), _ = fp["corners_along_up_m"]
        assert a1 - a0 == pytest.approx(width_m, rel=0.02) and u0 > u2
    # the footprints' centres move along the wall like the views
    centres = [np.mean(np.array(fp["corners_along_up_m"]), axis=0) for fp in fps]
    assert centres[0][0] < centres[-1][0]


def test_tiled_map_is_one_georeferenced_mosaic(spool, mapped, hole_wall_tiled, tmp_path):
    d, _ = spool
    res, _, files = mapped
    inp = load_input(d)
    # the same spool stitched with tile_px=128, max_in_memory_px=1000 (tests/conftest.py), georeferenced again here
    tiled = map_copy(hole_wall_tiled, tmp_path / "tiled")
    tfiles = write_georeferencing(tiled, inp)
    info = json.loads(gdal("gdalinfo", "-json", tfiles["map_vrt"]))
    assert info["size"] == [tiled.grid.width, tiled.grid.height]
    assert info["geoTransform"][1] == pytest.approx(tiled.grid.m_per_px)
    assert [band["colorInterpretation"] for band in info["bands"]] == ["Red", "Green", "Blue", "Alpha"]
    # the same wall point reads the same colour through the mosaic as in the in-memory map
    bgra = cv2.imread(files["map"], cv2.IMREAD_UNCHANGED)
    for along, up in ((2.0, 1.0), (5.5, 3.0)):
        out = gdal("gdallocationinfo", "-valonly", "-geoloc", tfiles["map_vrt"], str(along), str(up)).split()
        x, y = res.grid.to_px(np.array([along, up])).round().astype(int)
        assert [int(v) for v in out] == [*bgra[y, x, 2::-1].tolist(), int(bgra[y, x, 3])]


def test_wall_anchor_faces_away_from_the_building():
    from companion.geo import FacadeFrame, GeoPoint

    # a north -> south wall (start north): flown from the west, it faces west
    frame = FacadeFrame.from_wall(GeoPoint(37.5010, 127.0, 25.0), GeoPoint(37.5000, 127.0, 25.0))
    anchor = WallAnchor.from_facade(frame, 54.0)
    assert anchor.face_azimuth_deg == pytest.approx(270.0, abs=1e-3)
    assert anchor.along_azimuth_deg == pytest.approx(180.0, abs=1e-3)
    assert anchor.length_m == pytest.approx(111.0, rel=0.01)

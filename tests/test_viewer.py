"""The inspector's viewer beside a stitched map, checked in a real browser (headless Chromium via Playwright).

A simulator wall whose texture is known in metres is stitched; the page is opened from file:// like a double-click
in a file manager: its tiles must draw the map where the map is, a click on the wall must open the photo of the
keyframe that shows it, and a distance measured between two texture landmarks found on the screen (as an
inspector would find two marks) must read the true wall distance within 2 %. Chromium is Debian's `chromium`,
Playwright comes with the dev extra; scripts/bootstrap.sh installs both, and a missing one fails with the fix.
"""

from __future__ import annotations

import json
import math
import re
import shutil
import threading
import urllib.request
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import cv2
import numpy as np
import pytest

from companion.cli import main
from companion.stitch.output import UncoveredArea, tiles_vrt
from companion.stitch.render import MapGrid
from companion.stitch.unscaled import area_px
from companion.viewer.page import ASSETS, PAGE, write_viewer
from companion.viewer.serve import make_server
from companion.viewer.tiles import MapReader, halve, halve_weighted, max_zoom_for
from tests.hole_wall import HOLE, WALL

LANDMARKS = ((1.2, 1.0), (6.8, 3.1))  # texture points (along, up) in metres; 5.98 m apart


@pytest.fixture(scope="module")
def mapped(hole_wall_spool, hole_wall_map):
    """tests/hole_wall.py's map, stitched once per session (tests/conftest.py), with the viewer the stitch wrote;
    read-only: a test that writes a viewer copies the folder first."""
    spool, truth = hole_wall_spool
    return hole_wall_map.out_dir, hole_wall_map, truth, spool


def _data(out: Path) -> dict:
    text = (out / ASSETS / "data.js").read_text()
    return json.loads(text[text.index("=") + 1 :].rstrip().rstrip(";"))


def test_stitch_writes_a_self_contained_viewer(mapped):
    out, res, _, _ = mapped
    assert res.files["viewer"] == str(out / PAGE)
    page = (out / PAGE).read_text()
    # everything the page loads is in the folder: relative paths, no network at run time
    refs = re.findall(r'(?:src|href)="([^"]+)"', page)
    assert refs and all(not re.match(r"[a-z]+:", r) and (out / r).is_file() for r in refs)
    for own in ("viewer.js", "data.js"):
        assert "http:" not in (out / ASSETS / own).read_text() and "https:" not in (out / ASSETS / own).read_text()
    lib = out / ASSETS / "leaflet"
    assert "BSD 2-Clause" in (lib / "LICENSE").read_text() and (lib / "VERSION").read_text().startswith("leaflet 1.9.4")
    data = _data(out)
    georef = json.loads((out / "map_georef.json").read_text())
    assert data["frame"]["units"] == "m"
    assert [data["frame"]["left"], data["frame"]["top"]] == [georef["geotransform"][0], georef["geotransform"][3]]
    assert data["tiles"]["max_zoom"] == max_zoom_for(res.grid.width, res.grid.height)
    # the re-fly and relief areas are the report's (the hole every keyframe shows and masks out is relief, not
    # a re-fly area); every footprint's photo is linked into the folder
    report = json.loads((out / "report.json").read_text())
    assert report["files"]["viewer"] == str(out / PAGE)  # written before the report: a finished report, a viewer
    assert [a["along_min_m"] for a in data["refly"]] == [a["along_min_m"] for a in report["uncovered_areas_m"]]
    assert [a["along_min_m"] for a in data["relief"]] == [a["along_min_m"] for a in report["relief_areas_m"]]
    assert any(a["along_min_m"] < HOLE[0] + 0.1 and a["along_max_m"] > HOLE[1] - 0.1 for a in data["relief"])
    assert not any(a["along_min_m"] < HOLE[0] + 0.1 and a["along_max_m"] > HOLE[1] - 0.1 for a in data["refly"])
    assert len(data["keyframes"]) == len(georef["keyframes"]) > 0
    for kf in data["keyframes"]:
        assert (out / kf["image"]).is_file()


def test_full_resolution_tiles_are_the_map_and_coarser_levels_halve_it(mapped):
    out, res, _, _ = mapped
    data = _data(out)
    z, t = data["tiles"]["max_zoom"], data["tiles"]["size"]
    bgra = cv2.imread(str(out / "map.png"), cv2.IMREAD_UNCHANGED)
    tiles = out / ASSETS / "tiles"
    for tx in range(-(-res.grid.width // t)):
        for ty in range(-(-res.grid.height // t)):
            tile = cv2.imread(str(tiles / str(z) / str(tx) / f"{ty}.png"), cv2.IMREAD_UNCHANGED)
            assert tile.shape == (t, t, 4)  # edge tiles padded, never stretched
            crop = bgra[ty * t : (ty + 1) * t, tx * t : (tx + 1) * t]
            assert np.array_equal(tile[: crop.shape[0], : crop.shape[1]], crop)
            assert not tile[crop.shape[0] :, :, 3].any() and not tile[:, crop.shape[1] :, 3].any()
    top = cv2.imread(str(tiles / "0" / "0" / "0.png"), cv2.IMREAD_UNCHANGED)
    f = 2**z
    small = cv2.resize(bgra, (-(-res.grid.width // f), -(-res.grid.height // f)), interpolation=cv2.INTER_AREA)
    covered = top[: small.shape[0], : small.shape[1], 3] == 255
    diff = np.abs(top[: small.shape[0], : small.shape[1], :3].astype(int) - small[..., :3].astype(int))
    assert np.median(diff[covered]) <= 2


def test_halving_does_not_darken_the_coverage_edge():
    block = np.zeros((4, 4, 4), np.uint8)
    block[:, :3] = (200, 150, 100, 255)  # one transparent column of black pixels on the right
    out = halve(block)
    assert out[0, 1, 3] == 128 and tuple(out[0, 1, :3]) == (200, 150, 100)
    assert tuple(out[0, 0]) == (200, 150, 100, 255)


def test_halving_wholly_covered_or_blank_blocks_takes_the_byte_path_with_the_same_pixels():
    rng = np.random.default_rng(3)
    for _ in range(20):
        block = rng.integers(0, 256, (512, 512, 4), dtype=np.uint8)
        block[..., 3] = 255  # wholly covered: the plain 2x2 average, rounded as the weighted path rounds
        assert np.array_equal(halve(block), halve_weighted(block))
    blank = np.zeros((512, 512, 4), np.uint8)
    assert np.array_equal(halve(blank), halve_weighted(blank)) and not halve(blank).any()
    edge = rng.integers(0, 256, (512, 512, 4), dtype=np.uint8)
    edge[:, :100, 3] = 0  # partly covered: the weighted path itself
    assert np.array_equal(halve(edge), halve_weighted(edge))


def test_a_tiled_map_reads_like_the_in_memory_one(mapped, tmp_path):
    out, res, _, _ = mapped
    bgra = cv2.imread(str(out / "map.png"), cv2.IMREAD_UNCHANGED)
    (tmp_path / "tiles").mkdir()
    tiles = []
    for y0 in range(0, bgra.shape[0], 300):
        for x0 in range(0, bgra.shape[1], 300):
            part = bgra[y0 : y0 + 300, x0 : x0 + 300]
            name = f"tiles/tile_y{y0:07d}_x{x0:07d}.png"
            cv2.imwrite(str(tmp_path / name), part)
            tiles.append((name, x0, y0, part.shape[1], part.shape[0]))
    grid = MapGrid(0.0, 4.0, res.grid.m_per_px, bgra.shape[1], bgra.shape[0])
    (tmp_path / "map.vrt").write_text(tiles_vrt(grid, tiles, None))
    for preload in (False, True):  # tiles decoded as read, or a band's tiles decoded on a pool first
        reader = MapReader.open(tmp_path)
        assert (reader.width, reader.height) == (bgra.shape[1], bgra.shape[0])
        with ThreadPoolExecutor(2) as pool:
            for y0 in range(-100, bgra.shape[0], 256):
                if preload:
                    reader.preload(y0, 256, pool)
                for x0 in range(-100, bgra.shape[1], 256):
                    want = np.zeros((256, 256, 4), np.uint8)
                    ya, xa = max(0, y0), max(0, x0)
                    src = bgra[ya : y0 + 256, xa : x0 + 256]
                    want[ya - y0 : ya - y0 + src.shape[0], xa - x0 : xa - x0 + src.shape[1]] = src
                    assert np.array_equal(reader.read(x0, y0, 256, 256), want)


def test_rewriting_without_the_spool_keeps_the_photos(mapped, tmp_path):
    out, _, _, _ = mapped
    copy = tmp_path / "map"
    shutil.copytree(out, copy, ignore=shutil.ignore_patterns("cache"))
    before = {k["index"]: k["image"] for k in _data(copy)["keyframes"]}
    write_viewer(copy)
    assert {k["index"]: k["image"] for k in _data(copy)["keyframes"]} == before
    assert all((copy / p).is_file() for p in before.values())
    assert not (copy / f".{ASSETS}.old").exists() and not (copy / f".{ASSETS}.tmp").exists()


def test_view_serves_the_folder_over_http(mapped):
    out, _, _, _ = mapped
    server = make_server(out, "127.0.0.1", 0)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        base = f"http://127.0.0.1:{server.server_address[1]}/"
        with urllib.request.urlopen(base + PAGE, timeout=30) as r:
            assert r.status == 200 and b"leaflet.js" in r.read()
        with urllib.request.urlopen(base + f"{ASSETS}/tiles/0/0/0.png", timeout=30) as r:
            assert r.read()[:8] == b"\x89PNG\r\n\x1a\n"
    finally:
        server.shutdown()
        server.server_close()
        thread.join(timeout=30)


def test_view_links_the_photos_of_a_spool_into_a_folder_that_lacks_them(mapped, tmp_path, capsys):
    out, _, _, spool = mapped
    copy = tmp_path / "map"
    shutil.copytree(out, copy, ignore=shutil.ignore_patterns("cache", ASSETS, PAGE))
    assert main(["view", str(copy), "--no-serve"]) == 0  # no viewer yet: written, without photos
    said = capsys.readouterr().out
    assert "--spool" in said and (copy / PAGE).resolve().as_uri() in said
    assert all(k["image"] is None for k in _data(copy)["keyframes"])
    assert main(["view", str(copy), "--spool", str(spool), "--no-serve"]) == 0
    assert "--spool" not in capsys.readouterr().out
    assert all((copy / k["image"]).is_file() for k in _data(copy)["keyframes"])


def test_view_of_a_folder_without_a_map_is_a_clear_error(tmp_path, capsys):
    assert main(["view", str(tmp_path), "--no-serve"]) == 2
    err = capsys.readouterr().err
    assert "map_georef.json is missing" in err and "fix:" in err
    assert not (tmp_path / PAGE).exists()


# --- in the browser ---------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def browser():
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        pytest.fail("playwright is not installed: pip install -e '.[dev]' (scripts/bootstrap.sh)")
    exe = shutil.which("chromium") or shutil.which("chromium-browser")
    if exe is None:
        pytest.fail("chromium is not installed: apt-get install -y chromium (scripts/bootstrap.sh)")
    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=exe, args=["--no-sandbox"])
        yield b
        b.close()


@pytest.fixture
def page(browser, mapped):
    out = mapped[0]
    pg = browser.new_page(viewport={"width": 1600, "height": 1000})
    errors: list[str] = []
    pg.on("pageerror", lambda e: errors.append(str(e)))
    pg.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
    pg.on("requestfailed", lambda r: errors.append(f"failed to load {r.url}"))
    pg.goto((out / PAGE).resolve().as_uri())
    _wait_tiles(pg)
    yield pg
    pg.close()
    assert errors == []


def _wait_tiles(pg) -> None:
    pg.wait_for_function("window.companionViewer && window.companionViewer.tilesLoaded", timeout=60_000)


def _screen(pg) -> np.ndarray:
    return cv2.imdecode(np.frombuffer(pg.screenshot(), np.uint8), cv2.IMREAD_COLOR)


def _find_on_screen(screen: np.ndarray, texture: np.ndarray, along: float, up: float, m_per_screen_px: float):
    """Screen (x, y) of the texture point (along, up): a 0.5 m patch of the true texture, found on the screenshot."""
    st = WALL.texture_mm_per_px / 1000.0
    half = int(0.25 / st)
    cx, cy = int(round(along / st)), int(round((WALL.height_m - up) / st))
    k = st / m_per_screen_px
    patch = cv2.resize(
        texture[cy - half : cy + half, cx - half : cx + half], None, fx=k, fy=k, interpolation=cv2.INTER_AREA
    )
    score = cv2.matchTemplate(screen, patch, cv2.TM_CCOEFF_NORMED)
    _, best, _, (x, y) = cv2.minMaxLoc(score)
    assert best > 0.8, f"landmark ({along}, {up}) m not found on the screen (best match {best:.2f})"
    # the patch centre (texture pixel cx) sits half * k - (k - 1) / 2 pixels into the resized patch; a screen
    # pixel's centre is at +0.5 in CSS pixels
    return x + half * k - 0.5 * (k - 1) + 0.5, y + half * k - 0.5 * (k - 1) + 0.5


def _hide(pg, label: str) -> None:
    pg.get_by_label(label).uncheck()


def test_page_from_file_draws_the_map_tiles(page, mapped):
    out, res, truth, _ = mapped
    loaded = page.evaluate(
        "Array.from(document.querySelectorAll('img.leaflet-tile')).filter(i => i.complete && i.naturalWidth === 256)"
        ".length"
    )
    assert loaded >= 4  # the 915 x 458 px map at full resolution: a 4 x 2 tile grid
    _hide(page, "keyframe footprints")
    _hide(page, "re-fly areas")
    zoom = page.evaluate("companionViewer.map.getZoom()")
    data = _data(out)
    m_per_screen_px = res.grid.m_per_px * 2 ** (data["tiles"]["max_zoom"] - zoom)
    screen = _screen(page)
    for along, up in LANDMARKS:  # the true wall texture is on the screen: the tiles drew the map
        _find_on_screen(screen, truth["texture"], along, up, m_per_screen_px)


def test_the_info_panel_leaves_the_whole_map_in_view(page):
    """The first view fits the map beside the info panel, not under it (issue 29: it hid the wall's right end and
    its re-fly areas)."""
    right_px, panel_left = page.evaluate(
        "() => { const v = companionViewer, b = v.bounds, m = v.map.getContainer().getBoundingClientRect();"
        " const p = v.map.latLngToContainerPoint([b.getNorth(), b.getEast()]);"
        " return [p.x, document.querySelector('.viewer-info').getBoundingClientRect().left - m.left]; }")
    assert right_px <= panel_left, (right_px, panel_left)


def test_click_on_the_wall_opens_the_keyframe_that_shows_it(page, mapped):
    out = mapped[0]
    kf = _data(out)["keyframes"][len(_data(out)["keyframes"]) // 2]
    centre = np.mean(np.array(kf["corners"]), axis=0)
    x, y = page.evaluate(
        "([a, u]) => { const p = companionViewer.map.latLngToContainerPoint([u, a]); return [p.x, p.y]; }",
        centre.tolist(),
    )
    box = page.locator("#map").bounding_box()
    page.mouse.click(box["x"] + x, box["y"] + y)
    popup = page.locator(".kf-popup")
    popup.wait_for(timeout=30_000)
    assert popup.get_attribute("data-keyframe") == str(kf["index"])
    img = popup.locator("img.kf-image")
    img.wait_for(timeout=30_000)
    page.wait_for_function("document.querySelector('img.kf-image').complete", timeout=30_000)
    assert img.evaluate("i => [i.naturalWidth, i.naturalHeight]") == [640, 360]  # the original keyframe
    assert img.get_attribute("src") == kf["image"]


@pytest.mark.parametrize("zoom_out", [0, 1])
def test_measured_distance_between_two_landmarks_is_the_wall_distance(page, mapped, zoom_out):
    out, res, truth, _ = mapped
    _hide(page, "keyframe footprints")
    _hide(page, "re-fly areas")
    for _ in range(zoom_out):
        page.locator(".leaflet-control-zoom-out").click()
        page.wait_for_timeout(500)  # the zoom animation
        _wait_tiles(page)
    zoom = page.evaluate("companionViewer.map.getZoom()")
    assert zoom == _data(out)["tiles"]["max_zoom"] - zoom_out
    m_per_screen_px = res.grid.m_per_px * 2**zoom_out
    screen = _screen(page)
    points = [_find_on_screen(screen, truth["texture"], a, u, m_per_screen_px) for a, u in LANDMARKS]
    page.locator("#measure-button").click()
    for x, y in points:
        page.mouse.click(x, y)
    text = page.locator("#measure-total").inner_text()
    measured_mm = float(re.search(r"total: ([0-9.]+) mm", text).group(1))
    true_mm = 1000 * math.hypot(LANDMARKS[1][0] - LANDMARKS[0][0], LANDMARKS[1][1] - LANDMARKS[0][1])
    assert measured_mm == pytest.approx(true_mm, rel=0.02)
    print(f"zoom -{zoom_out}: measured {measured_mm:.0f} mm, true {true_mm:.0f} mm")


def test_a_map_of_unknown_scale_is_shown_in_pixels(tmp_path):
    """Stitched without telemetry: no geotransform, no footprints; the re-fly areas land on their map pixels."""
    s, along0, up_top, w, h = 0.01, -2.0, 3.0, 600, 300  # plane units per pixel, the map's corner, size
    bgra = np.full((h, w, 4), 200, np.uint8)
    bgra[100:150, 200:300] = 0  # the hole
    cv2.imwrite(str(tmp_path / "map.png"), bgra)
    georef = {"scale_known": False, "geotransform": None, "size_px": [w, h], "keyframes": []}
    (tmp_path / "map_georef.json").write_text(json.dumps(georef))
    hole = area_px(UncoveredArea(along0 + 200 * s, along0 + 300 * s, up_top - 150 * s, up_top - 100 * s, 0.5),
                   MapGrid(along0, up_top, s, w, h))
    assert hole == {"x_min_px": 200, "x_max_px": 300, "y_min_px": 100, "y_max_px": 150, "area_px2": 5000}
    why = "the spool has no spool.json"
    report = {
        "coverage_fraction": 0.97, "uncovered_areas_m": None, "uncovered_areas_px": [hole],
        "scale_unknown": {"why": why, "fix": "cull with --mission"},
        "map": {"width_px": w, "height_px": h, "along_m": None, "up_m": None},
    }
    (tmp_path / "report.json").write_text(json.dumps(report))
    write_viewer(tmp_path)
    data = _data(tmp_path)
    assert data["frame"]["units"] == "px" and data["mm_per_px"] is None and data["keyframes"] == []
    left, right, bottom, top = data["refly"][0]["rect"]  # page units: x right, y up (= minus the map row)
    assert [left, right, -top, -bottom] == pytest.approx([200, 300, 100, 150])
    assert data["scale_note"] == why  # the panel says why there is no scale, not "no telemetry"


def test_the_map_the_stitcher_holds_reads_like_its_map_png(mapped):
    """The stitcher hands the viewer its map in memory (BGR + coverage, no BGRA copy, no decode of map.png): the
    same BGRA regions as map.png, inside the map, across its edge and outside it (and the stitch's own viewer,
    made so, has map.png's tiles: test_full_resolution_tiles_are_the_map_and_coarser_levels_halve_it)."""
    out = mapped[0]
    png = cv2.imread(str(out / "map.png"), cv2.IMREAD_UNCHANGED)
    bgr, alpha = np.ascontiguousarray(png[..., :3]), np.ascontiguousarray(png[..., 3])
    held, read = MapReader.in_memory(bgr, alpha), MapReader.open(out)
    h, w = png.shape[:2]
    assert (held.width, held.height) == (read.width, read.height) == (w, h)
    for x0, y0, rw, rh in ((0, 0, w, h), (w - 100, h - 50, 256, 256), (-30, 10, 64, 64), (w + 5, 0, 16, 16)):
        assert np.array_equal(held.read(x0, y0, rw, rh), read.read(x0, y0, rw, rh))

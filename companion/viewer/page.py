"""Writes the inspector's viewer next to a stitched map: ``viewer.html`` + ``viewer/`` (no server needed).

Everything the page shows comes from the map folder's own documented files (docs/OUTPUTS.md): the map
(``map.png`` or ``map.vrt`` over tiles) becomes a tile pyramid; ``map_georef.json`` gives the scale, the
geotransform in wall metres and the keyframe footprints; ``report.json`` the coverage and the re-fly areas. The
keyframe images are linked (or copied) into the folder, so the map folder alone is what an inspector needs: it
opens from a file manager, a USB stick or ``companion view``. Leaflet (vendored, ``static/leaflet/VERSION``) draws
it; wall metres are its coordinates (a Leaflet CRS whose units are metres), so a distance on the page is a
distance on the wall.
"""

from __future__ import annotations

import html
import json
import math
import os
import shutil
from collections.abc import Mapping
from importlib import resources
from importlib.resources.abc import Traversable
from pathlib import Path

import cv2
import numpy as np

from companion.errors import CompanionError
from companion.files import write_atomic
from companion.viewer.tiles import MapReader, PyramidInfo, level_image, write_pyramid

PAGE = "viewer.html"
ASSETS = "viewer"  # folder beside the page: library, tiles, keyframe images, data
OVERLAY_MAX_PX = 2048  # the coverage overlay is one small image: the pyramid level at most this wide

_HTML = """<!DOCTYPE html>
<html lang="en">
<head>
<meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<title>{title}</title>
<link rel="stylesheet" href="{assets}/leaflet/leaflet.css">
<link rel="stylesheet" href="{assets}/viewer.css">
</head>
<body>
<div id="map"></div>
<script src="{assets}/leaflet/leaflet.js"></script>
<script src="{assets}/data.js"></script>
<script src="{assets}/viewer.js"></script>
</body>
</html>
"""


def _read_json(path: Path) -> dict:
    try:
        return json.loads(path.read_text())
    except FileNotFoundError:
        raise CompanionError(
            f"{path} is missing: {path.parent} is not a finished map folder",
            "give the --out folder of a finished `companion stitch` (it writes map_georef.json and report.json)",
        ) from None
    except json.JSONDecodeError as exc:
        raise CompanionError(f"{path} is not valid JSON ({exc})", "run `companion stitch` again") from exc


def _copy_static(src: Traversable, dst: Path) -> None:
    dst.mkdir(parents=True, exist_ok=True)
    for item in src.iterdir():
        if item.is_dir():
            _copy_static(item, dst / item.name)
        elif not item.name.startswith("."):
            (dst / item.name).write_bytes(item.read_bytes())


def _link_or_copy(src: Path, dst: Path) -> None:
    try:
        os.link(src, dst)
    except OSError:  # another file system, or links not allowed
        shutil.copy2(src, dst)


def _frame(georef: dict, report: dict) -> dict:
    """Page coordinates: wall metres when the scale is known, else map pixels (y up); the map's top-left corner."""
    w, h = georef["size_px"]
    if georef.get("scale_known") and georef.get("geotransform"):
        left, s, _, top, _, _ = georef["geotransform"]
        return {"units": "m", "unit_per_px": s, "left": left, "top": top, "width_px": w, "height_px": h}
    return {"units": "px", "unit_per_px": 1.0, "left": 0.0, "top": 0.0, "width_px": w, "height_px": h}


def _refly_areas(report: dict, frame: dict, key: str = "uncovered_areas") -> list[dict]:
    """The report's uncovered areas (or another list of wall rectangles, ``key``: the relief areas) as page
    rectangles [left, right, bottom, top] in page units: wall metres, or map pixels (y up) for a map without scale,
    whose report lists them in pixels (``companion.stitch.unscaled``)."""
    if frame["units"] == "m":
        areas = report.get(f"{key}_m") or []
        return [{**a, "rect": [a["along_min_m"], a["along_max_m"], a["up_min_m"], a["up_max_m"]]} for a in areas]
    areas = report.get(f"{key}_px") or []
    return [{**a, "rect": [a["x_min_px"], a["x_max_px"], -a["y_max_px"], -a["y_min_px"]]} for a in areas]


def _coverage_overlay(tiles_dir: Path, info: PyramidInfo, path: Path) -> None:
    """Uncovered wall tinted red, covered transparent: one image over the whole map, from a small pyramid level."""
    down = max(0, math.ceil(math.log2(max(info.width_px, info.height_px) / OVERLAY_MAX_PX)))
    alpha = level_image(tiles_dir, info, max(0, info.max_zoom - down))[..., 3]
    tint = np.zeros((*alpha.shape, 4), np.uint8)
    uncovered = alpha < 128
    tint[uncovered] = (40, 40, 230, 110)  # BGRA
    if not cv2.imwrite(str(path), tint):
        raise CompanionError(f"cannot write {path}", "check free disk space and permissions of the map folder")


def viewer_data(
    georef: dict, report: dict, info: PyramidInfo, images: Mapping[int, str], title: str, frame: dict
) -> dict:
    """Everything viewer.js draws, as one JSON document (the page reads it as a script: file:// forbids fetch)."""
    return {
        "title": title,
        "frame": frame,
        "mm_per_px": georef.get("mm_per_px"),
        "tiles": {"url": info.url, "size": info.tile_px, "max_zoom": info.max_zoom},
        "coverage": {"fraction": report.get("coverage_fraction"), "overlay": f"{ASSETS}/coverage.png"},
        "refly": _refly_areas(report, frame),
        "relief": _refly_areas(report, frame, "relief_areas"),
        "scale_note": (report.get("scale_unknown") or {}).get("why"),
        "keyframes": [
            {"index": k["index"], "image": images.get(k["index"]), "corners": k["corners_along_up_m"]}
            for k in georef.get("keyframes", [])
        ],
        "keyframes_used": len(report.get("keyframes_used", [])),
        "wall": georef.get("wall"),
    }


def write_viewer(
    map_dir: str | Path, keyframe_images: Mapping[int | str, Path] | None = None, *, report: dict | None = None,
    image: tuple[np.ndarray, np.ndarray] | None = None,
) -> str:
    """Writes ``viewer.html`` and ``viewer/`` into a finished map folder; returns the page's path.

    ``keyframe_images`` (keyframe index -> image file) are linked into the folder so a click on a footprint
    shows the original photo; without them (None) the photos of the viewer being replaced are kept, and the page
    still shows the footprints. ``report`` is the stitch report (default: the folder's ``report.json``; the
    stitcher passes it before writing that file, so a finished report means a finished folder, viewer included).
    ``image``: the map's (BGR, coverage) when the stitcher still holds it (the map is not decoded again from
    map.png: a 60 MP map's second copy was 240 MB).
    The old viewer is replaced only once the new one is complete.
    """
    out = Path(map_dir)
    if keyframe_images is None:  # rewriting a viewer without the spool keeps the photos it already has
        keyframe_images = {p.name: p for p in (out / ASSETS / "keyframes").glob("*")}
    georef = _read_json(out / "map_georef.json")
    report = report if report is not None else _read_json(out / "report.json")
    reader = MapReader.in_memory(*image) if image is not None else MapReader.open(out)
    tmp, old = out / f".{ASSETS}.tmp", out / f".{ASSETS}.old"
    for stale in (tmp, old):
        shutil.rmtree(stale, ignore_errors=True)
    _copy_static(resources.files("companion.viewer") / "static", tmp)
    info = write_pyramid(reader, tmp / "tiles", url_prefix=f"{ASSETS}/tiles/")
    _coverage_overlay(tmp / "tiles", info, tmp / "coverage.png")
    images: dict[int, str] = {}
    by_name = {k["image"]: k["index"] for k in georef.get("keyframes", [])}
    wanted = set(by_name.values())
    for key, src in keyframe_images.items():
        src = Path(src)
        index = by_name.get(key) if isinstance(key, str) else key  # an index, or an image name (old viewer)
        if index in wanted and src.exists() and index not in images:
            (tmp / "keyframes").mkdir(exist_ok=True)
            _link_or_copy(src, tmp / "keyframes" / src.name)
            images[index] = f"{ASSETS}/keyframes/{src.name}"
    title = f"facade map: {out.resolve().name}"
    data = viewer_data(georef, report, info, images, title, _frame(georef, report))
    (tmp / "data.js").write_text(f"window.COMPANION_VIEWER = {json.dumps(data, indent=1)};\n")
    final = out / ASSETS
    if final.exists():
        final.rename(old)
    tmp.rename(final)
    shutil.rmtree(old, ignore_errors=True)
    page = out / PAGE
    write_atomic(page, _HTML.format(title=html.escape(title), assets=ASSETS))
    return str(page)

"""What the worker hands the engineer: coverage analysis (where to re-fly), a scale bar, the preview, and the
georeferencing that makes the map open at true scale in GDAL/QGIS/CAD."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from companion.errors import CompanionError
from companion.files import atomic_path, write_atomic
from companion.stitch.render import MapGrid
from companion.wall_footprint import corner_footprint, facade_from_enu


@dataclass(frozen=True)
class UncoveredArea:
    """An axis-aligned box on the wall (metres) that no keyframe shows: a re-fly target."""

    along_min_m: float
    along_max_m: float
    up_min_m: float
    up_max_m: float
    area_m2: float

    def as_dict(self) -> dict:
        return {k: round(v, 3) for k, v in self.__dict__.items()}


def uncovered_areas(
    coverage: np.ndarray,
    grid: MapGrid,
    region_px: tuple[int, int, int, int],
    *,
    cell_m: float = 0.1,
    min_area_m2: float = 0.02,
) -> list[UncoveredArea]:
    """Uncovered parts of ``region_px`` (x0, y0, x1, y1 in ``coverage`` pixels) as wall rectangles in metres.

    ``coverage`` (0/255) spans the whole map, possibly downscaled. The region is cut into ``cell_m`` cells; a
    cell at least half uncovered is a hole; holes are merged greedily into maximal rectangles (a thin ring of
    missing edge and a missing window do not become one useless box covering the whole wall).
    """
    sx = grid.width / coverage.shape[1]
    x0, y0, x1, y1 = region_px
    cell_px = max(1, int(round(cell_m / (grid.m_per_px * sx))))
    nx, ny = -(-(x1 - x0) // cell_px), -(-(y1 - y0) // cell_px)
    sub = (coverage[y0:y1, x0:x1] == 0).astype(np.float32)
    pad = np.zeros((ny * cell_px, nx * cell_px), np.float32)
    pad[: sub.shape[0], : sub.shape[1]] = sub
    frac = pad.reshape(ny, cell_px, nx, cell_px).mean(axis=(1, 3))
    # cells cut by the region edge count only their inside part
    inside = np.zeros_like(pad)
    inside[: sub.shape[0], : sub.shape[1]] = 1.0
    frac = frac / np.maximum(inside.reshape(ny, cell_px, nx, cell_px).mean(axis=(1, 3)), 1e-9)
    hole = frac >= 0.5
    used = np.zeros_like(hole)
    out = []
    for r in range(ny):
        for c in range(nx):
            if not hole[r, c] or used[r, c]:
                continue
            c1 = c
            while c1 + 1 < nx and hole[r, c1 + 1] and not used[r, c1 + 1]:
                c1 += 1
            r1 = r
            while r1 + 1 < ny and np.all(hole[r1 + 1, c : c1 + 1] & ~used[r1 + 1, c : c1 + 1]):
                r1 += 1
            used[r : r1 + 1, c : c1 + 1] = True
            px0 = np.array([(x0 + c * cell_px) * sx, (y0 + r * cell_px) * sx])
            px1 = np.array([min(x1, x0 + (c1 + 1) * cell_px) * sx, min(y1, y0 + (r1 + 1) * cell_px) * sx])
            a0, up1 = grid.to_plane(px0)
            a1, up0 = grid.to_plane(px1)
            area = float((a1 - a0) * (up1 - up0))
            if area >= min_area_m2:
                out.append(UncoveredArea(float(a0), float(a1), float(up0), float(up1), area))
    return sorted(out, key=lambda u: (u.along_min_m, -u.up_max_m))


def nice_length_m(max_m: float) -> float:
    """Largest 1/2/5 x 10^k metres not above ``max_m``."""
    if max_m <= 0:
        return 0.0
    e = math.floor(math.log10(max_m))
    for f in (5, 2, 1):
        if f * 10**e <= max_m:
            return f * 10**e
    return 10 ** (e - 1)


def draw_scale_bar(image: np.ndarray, m_per_px: float | None, *, label_unit: str = "m") -> np.ndarray:
    """Appends a white strip under the map with a scale bar (the map pixels themselves stay untouched)."""
    h, w = image.shape[:2]
    strip_h = max(40, h // 20)
    strip = np.full((strip_h, w, 3), 255, np.uint8)
    font_scale = strip_h / 60.0
    if m_per_px:
        length_m = nice_length_m(0.3 * w * m_per_px)
        bar_px = int(round(length_m / m_per_px))
        x0, y = int(0.03 * w), strip_h // 2
        thick = max(2, strip_h // 8)
        cv2.rectangle(strip, (x0, y - thick), (x0 + bar_px, y + thick), (0, 0, 0), -1)
        for k in range(1, 5):  # alternating ticks every fifth
            if k % 2:
                xa, xb = x0 + bar_px * k // 5, x0 + bar_px * (k + 1) // 5
                cv2.rectangle(strip, (xa, y - thick + 2), (xb, y + thick - 2), (255, 255, 255), -1)
        text = f"{length_m:g} m   ({m_per_px * 1000:.2f} mm/px)"
        cv2.putText(
            strip,
            text,
            (x0 + bar_px + 15, y + thick),
            cv2.FONT_HERSHEY_SIMPLEX,
            font_scale,
            (0, 0, 0),
            max(1, strip_h // 25),
            cv2.LINE_AA,
        )
    else:
        cv2.putText(
            strip,
            "scale unknown: lengths in map pixels (why: report.json scale_unknown)",
            (10, strip_h // 2 + 5),
            cv2.FONT_HERSHEY_SIMPLEX,
            font_scale,
            (0, 0, 0),
            1,
            cv2.LINE_AA,
        )
    return np.vstack((image, strip))


REFLY_BGR = (0, 0, 255)  # re-fly areas: red
RELIEF_BGR = (255, 160, 0)  # relief (seen, not the wall plane): blue


def annotate_uncovered(preview: np.ndarray, grid: MapGrid, areas: list[UncoveredArea],
                       colour: tuple[int, int, int] = REFLY_BGR) -> np.ndarray:
    """Outlines areas (re-fly areas in red by default) on a (possibly downscaled) preview of the map."""
    out = preview.copy()
    s = preview.shape[1] / grid.width
    for a in areas:
        p0 = grid.to_px(np.array([a.along_min_m, a.up_max_m])) * s
        p1 = grid.to_px(np.array([a.along_max_m, a.up_min_m])) * s
        cv2.rectangle(
            out,
            tuple(int(round(v)) for v in p0),
            tuple(int(round(v)) for v in p1),
            colour,
            max(1, preview.shape[1] // 800),
        )
    return out


# --- a map that opens at true scale ------------------------------------------------------------------------------
#
# The map is an image of the wall plane: x = metres along the wall from its start, y = metres above the wall base
# (docs/ARCHITECTURE.md, the facade frame). A world file gives GDAL, QGIS and CAD tools the pixel size and origin
# in those metres; the PAM sidecar (map.png.aux.xml, or the SRS inside map.vrt) names that plane as an engineering
# CRS in metres, so lengths measured on the map are wall metres. Uncovered map pixels have alpha 0 in every
# output mode (map.png is BGRA; tiles are BGRA). map_georef.json anchors the plane on the Earth (docs/OUTPUTS.md).

GEOREF_JSON = "map_georef.json"


@dataclass(frozen=True)
class WallAnchor:
    """Where the map's plane is on the Earth: the wall base ends, its ground altitude and the way it faces."""

    start_lat: float
    start_lon: float
    end_lat: float
    end_lon: float
    ground_alt_amsl_m: float
    height_m: float
    length_m: float
    face_azimuth_deg: float  # direction the mapped face looks (wall -> drone), degrees clockwise from north
    along_azimuth_deg: float  # direction of the map's +x (start -> end), degrees clockwise from north

    @classmethod
    def from_facade(cls, frame, height_m: float) -> WallAnchor:
        """From a ``companion.geo.FacadeFrame`` and the wall height."""
        end_lat, end_lon, _ = frame.facade_to_geodetic(frame.length_m, 0.0, 0.0)
        de, dn = frame.along_enu
        oe, on = frame.out_enu
        return cls(
            start_lat=frame.origin.lat,
            start_lon=frame.origin.lon,
            end_lat=float(end_lat),
            end_lon=float(end_lon),
            ground_alt_amsl_m=frame.origin.alt_amsl_m,
            height_m=float(height_m),
            length_m=frame.length_m,
            face_azimuth_deg=math.degrees(math.atan2(oe, on)) % 360.0,
            along_azimuth_deg=math.degrees(math.atan2(de, dn)) % 360.0,
        )

    def as_dict(self) -> dict:
        return {
            "start": {"lat": round(self.start_lat, 9), "lon": round(self.start_lon, 9)},
            "end": {"lat": round(self.end_lat, 9), "lon": round(self.end_lon, 9)},
            "ground_alt_amsl_m": round(self.ground_alt_amsl_m, 3),
            "height_m": round(self.height_m, 3),
            "length_m": round(self.length_m, 4),
            "face_azimuth_deg": round(self.face_azimuth_deg, 4),
            "along_azimuth_deg": round(self.along_azimuth_deg, 4),
        }


@dataclass(frozen=True)
class KeyframeFootprint:
    """The wall area a keyframe shows, as its image corners projected from the telemetry pose onto the wall."""

    index: int
    image: str
    corners_m: tuple[tuple[float, float], ...]  # (along, up) of the top-left, top-right, bottom-right, bottom-left

    def as_dict(self) -> dict:
        return {
            "index": self.index,
            "image": self.image,
            "corners_along_up_m": [[round(a, 4), round(u, 4)] for a, u in self.corners_m],
            "source": "telemetry pose",
        }


def geotransform(grid: MapGrid) -> tuple[float, float, float, float, float, float]:
    """GDAL geotransform (top-left corner of the top-left pixel; map pixel centres sit on integer coordinates)."""
    s = grid.m_per_px
    return (grid.along0_m - s / 2.0, s, 0.0, grid.up_top_m + s / 2.0, 0.0, -s)


def world_file_text(grid: MapGrid) -> str:
    """ESRI world file: pixel size x, rotations, pixel size y (negative), centre of the top-left pixel."""
    s = grid.m_per_px
    return "\n".join(f"{v:.10f}" for v in (s, 0.0, 0.0, -s, grid.along0_m, grid.up_top_m)) + "\n"


def facade_crs_wkt(name: str) -> str:
    """An engineering CRS for the wall plane: x along the wall, y up, metres (shown as east/north by GIS tools)."""
    return (
        f'LOCAL_CS["facade plane: {name}",LOCAL_DATUM["wall base start",0],'
        'UNIT["metre",1,AUTHORITY["EPSG","9001"]],'
        'AXIS["along the wall from its start",EAST],AXIS["height above the wall base",NORTH]]'
    )


def _xml(text: str) -> str:
    return text.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;").replace('"', "&quot;")


def _write_text(path: Path, text: str) -> str:
    return str(write_atomic(path, text))


def tiles_vrt(grid: MapGrid, tiles: list[tuple[str, int, int, int, int]], wkt: str | None) -> str:
    """A GDAL VRT mosaic of the PNG tiles ``(relative path, x0, y0, w, h)`` (with alpha) as one RGBA map."""
    gt = ", ".join(f"{v:.12g}" for v in geotransform(grid))
    srs = f"  <SRS>{_xml(wkt)}</SRS>\n  <GeoTransform>{gt}</GeoTransform>\n" if wkt else ""
    bands = []
    # OpenCV's BGRA arrays are stored as RGBA in the PNG files: file band k is map band k
    for band, (src_band, interp) in enumerate(((1, "Red"), (2, "Green"), (3, "Blue"), (4, "Alpha")), start=1):
        sources = "".join(
            f'    <SimpleSource><SourceFilename relativeToVRT="1">{_xml(p)}</SourceFilename>'
            f"<SourceBand>{src_band}</SourceBand>"
            f'<SrcRect xOff="0" yOff="0" xSize="{w}" ySize="{h}"/>'
            f'<DstRect xOff="{x0}" yOff="{y0}" xSize="{w}" ySize="{h}"/></SimpleSource>\n'
            for p, x0, y0, w, h in tiles
        )
        bands.append(
            f'  <VRTRasterBand dataType="Byte" band="{band}">\n'
            f"    <ColorInterp>{interp}</ColorInterp>\n{sources}  </VRTRasterBand>\n"
        )
    return f'<VRTDataset rasterXSize="{grid.width}" rasterYSize="{grid.height}">\n{srs}{"".join(bands)}</VRTDataset>\n'


def png_size(path: Path) -> tuple[int, int] | None:
    """(width, height) from a PNG's header (its first 24 bytes), None when the file is not a PNG: the mosaic
    needs only the tiles' sizes, and decoding 160 MP of tiles to learn them took seconds."""
    try:
        with open(path, "rb") as f:
            head = f.read(24)
    except OSError:
        return None
    if len(head) < 24 or head[:8] != b"\x89PNG\r\n\x1a\n" or head[12:16] != b"IHDR":
        return None
    return int.from_bytes(head[16:20], "big"), int.from_bytes(head[20:24], "big")


def keyframe_footprints(inp) -> list[KeyframeFootprint]:
    """Footprints of the keyframes of a ``StitchInput`` that have a pose, on the wall plane (out = 0)."""
    if inp.camera is None or inp.facade is None:
        return []
    frame = inp.facade.frame
    rotate = facade_from_enu(frame)
    out = []
    for kf in inp.keyframes:
        if kf.pose is None:
            continue
        centre = np.array([float(v) for v in frame.geodetic_to_facade(kf.pose.lat, kf.pose.lon, kf.pose.alt_amsl_m)])
        corners = corner_footprint(
            inp.camera.K, inp.camera.width, inp.camera.height, centre, rotate @ kf.pose.R_enu_from_cam
        )
        if corners is None:  # a corner ray that never reaches the wall
            continue
        pts = tuple((float(a), float(u)) for a, u in corners)
        out.append(KeyframeFootprint(kf.index, kf.image_path.name, pts))
    return out


def write_georeferencing(result, inp, *, name: str | None = None) -> dict[str, str]:
    """Makes a finished map (``worker.StitchResult`` of ``inp``) open at true scale; returns the files written.

    * map.png rewritten as BGRA with alpha = coverage (uncovered = transparent, as in the tiles);
    * map.pgw (world file) + map.png.aux.xml (CRS), or map.vrt over the tiles for maps too big for memory;
    * map_georef.json: the wall's geographic anchor, the scale, the extent and the keyframe footprints.

    Georeferencing needs a map rectified to the facade from telemetry (known scale); otherwise only the alpha
    convention and a sidecar saying the scale is unknown are written.
    """
    out = Path(result.out_dir)
    grid = result.grid
    files: dict[str, str] = {}
    rectified = bool(result.report.get("map", {}).get("rectified_to_facade")) and result.mm_per_px is not None
    wall = WallAnchor.from_facade(inp.facade.frame, inp.facade.height_m) if inp.facade is not None else None
    wkt = facade_crs_wkt(name or out.name) if rectified and wall is not None else None
    if result.map_image is not None and result.coverage is not None:
        bgra = np.dstack((result.map_image, result.coverage))
        with atomic_path(out / "map.png") as tmp:
            if not cv2.imwrite(str(tmp), bgra):
                raise CompanionError(f"cannot write {out / 'map.png'}",
                                     "check free disk space and permissions of --out")
        files["map"] = str(out / "map.png")
        if wkt:
            files["world_file"] = _write_text(out / "map.pgw", world_file_text(grid))
            files["crs"] = _write_text(
                out / "map.png.aux.xml", f"<PAMDataset>\n  <SRS>{_xml(wkt)}</SRS>\n</PAMDataset>\n"
            )
    elif result.files.get("tiles"):
        tiles = []
        for p in sorted(Path(result.files["tiles"]).glob("tile_y*_x*.png")):
            y0, x0 = int(p.stem.split("_")[1][1:]), int(p.stem.split("_")[2][1:])
            size = png_size(p)
            if size is None:
                continue
            tiles.append((str(p.relative_to(out)), x0, y0, *size))
        files["map_vrt"] = _write_text(out / "map.vrt", tiles_vrt(grid, tiles, wkt))
    footprints = keyframe_footprints(inp) if rectified else []
    doc = {
        "plane": "x = metres along the wall from its start (map right), y = metres above the wall base (map up)",
        "scale_known": rectified,
        "mm_per_px": round(grid.m_per_px * 1000.0, 6) if rectified else None,
        "geotransform": list(geotransform(grid)) if rectified else None,
        "extent_m": {
            "along": [grid.along0_m - grid.m_per_px / 2, grid.along0_m + (grid.width - 0.5) * grid.m_per_px],
            "up": [grid.up_top_m - (grid.height - 0.5) * grid.m_per_px, grid.up_top_m + grid.m_per_px / 2],
        }
        if rectified
        else None,
        "size_px": [grid.width, grid.height],
        "uncovered": "alpha 0 (map.png is BGRA with alpha = coverage; tiles likewise)",
        "wall": wall.as_dict() if wall is not None else None,
        "keyframes": [f.as_dict() for f in footprints],
        "files": {k: Path(v).name for k, v in files.items()},
    }
    files["georef"] = _write_text(out / GEOREF_JSON, json.dumps(doc, indent=1))
    return files

"""The map as an XYZ tile pyramid, so a browser pans and zooms a map of any size by loading only what it shows.

Level ``max_zoom`` is the map at full resolution (one map pixel per tile pixel); each level above halves it, up
to level 0 where the whole map fits in one tile. Tile ``z/x/y.png`` covers level-z pixels
``[x * size, (x + 1) * size) x [y * size, (y + 1) * size)``, the origin at the map's top-left corner, which is
what Leaflet's tile layer asks for. Tiles are BGRA PNGs like the map: alpha = coverage, so uncovered wall stays
transparent at every level (edge tiles are padded with transparent pixels, never stretched).

The full-resolution level is cut from a :class:`MapReader` (``map.png`` in memory, or the stitcher's own tiles
behind ``map.vrt`` one at a time); every coarser level is made from the four tiles under it already on disk,
so memory stays bounded by a row of stitcher tiles whatever the map's size.
"""

from __future__ import annotations

import math
import os
import xml.etree.ElementTree as ET
from collections.abc import Iterator
from concurrent.futures import Executor, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from companion.errors import CompanionError

TILE_PX = 256
BLOCK_LEVELS = 2  # write_pyramid cuts the map in blocks of 2**BLOCK_LEVELS tiles a side (1024 px: a stitcher tile)


@dataclass(frozen=True)
class PyramidInfo:
    """What the page needs to ask for tiles: their size, the full-resolution level and the URL pattern."""

    tile_px: int
    max_zoom: int
    width_px: int
    height_px: int
    url: str  # relative to the page, with {z}/{x}/{y}
    tiles_written: int


@dataclass(frozen=True)
class _SourceTile:
    path: Path
    x0: int
    y0: int
    width: int
    height: int


class MapReader:
    """Reads BGRA regions of a stitched map: ``map.png`` (one image) or ``map.vrt`` (the stitcher's tiles)."""

    def __init__(
        self, width: int, height: int, image: np.ndarray | None = None, tiles: list[_SourceTile] | None = None,
        planes: tuple[np.ndarray, np.ndarray] | None = None,
    ):
        self.width = width
        self.height = height
        self._image = image
        self._planes = planes  # (BGR, alpha): the stitcher's map still in memory, read without a BGRA copy
        self._tiles = tiles or []
        self._cache: dict[_SourceTile, np.ndarray] = {}

    @classmethod
    def in_memory(cls, bgr: np.ndarray, alpha: np.ndarray) -> MapReader:
        """The map the stitcher holds (BGR + coverage as alpha): no second copy of it decoded from map.png."""
        return cls(bgr.shape[1], bgr.shape[0], planes=(bgr, alpha))

    @classmethod
    def open(cls, map_dir: Path) -> MapReader:
        """The map of a ``companion stitch --out`` folder; a clear error when it holds neither form."""
        png, vrt = map_dir / "map.png", map_dir / "map.vrt"
        if png.exists():
            img = cv2.imread(str(png), cv2.IMREAD_UNCHANGED)
            if img is None:
                raise CompanionError(f"cannot read {png}", "run `companion stitch` again to rewrite the map")
            if img.ndim == 2:
                img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGRA)
            elif img.shape[2] == 3:  # a map from before the alpha convention: everything drawn counts as covered
                img = np.dstack((img, np.where(img.max(axis=2) > 0, 255, 0).astype(np.uint8)))
            return cls(img.shape[1], img.shape[0], image=img)
        if vrt.exists():
            return cls._from_vrt(vrt)
        raise CompanionError(
            f"{map_dir} holds no map (neither map.png nor map.vrt)",
            "give the --out folder of `companion stitch`, or stitch the spool first",
        )

    @classmethod
    def _from_vrt(cls, vrt: Path) -> MapReader:
        try:
            root = ET.parse(vrt).getroot()
            width, height = int(root.attrib["rasterXSize"]), int(root.attrib["rasterYSize"])
            band = root.find("VRTRasterBand")
            tiles = []
            for src in band.findall("SimpleSource") if band is not None else []:
                dst = src.find("DstRect").attrib
                name = src.find("SourceFilename").text or ""
                tiles.append(
                    _SourceTile(
                        vrt.parent / name,
                        int(dst["xOff"]),
                        int(dst["yOff"]),
                        int(dst["xSize"]),
                        int(dst["ySize"]),
                    )
                )
        except (ET.ParseError, KeyError, AttributeError, ValueError) as exc:
            raise CompanionError(
                f"{vrt} is not a map mosaic the stitcher wrote ({exc})", "run `companion stitch` again"
            ) from exc
        return cls(width, height, tiles=tiles)

    def read(self, x0: int, y0: int, w: int, h: int) -> np.ndarray:
        """BGRA pixels of the map region; outside the map (and any hole between source tiles) is transparent."""
        out = np.zeros((h, w, 4), np.uint8)
        xa, ya, xb, yb = max(0, x0), max(0, y0), min(self.width, x0 + w), min(self.height, y0 + h)
        if xb <= xa or yb <= ya:
            return out
        if self._image is not None:
            out[ya - y0 : yb - y0, xa - x0 : xb - x0] = self._image[ya:yb, xa:xb]
            return out
        if self._planes is not None:
            bgr, alpha = self._planes
            out[ya - y0 : yb - y0, xa - x0 : xb - x0, :3] = bgr[ya:yb, xa:xb]
            out[ya - y0 : yb - y0, xa - x0 : xb - x0, 3] = alpha[ya:yb, xa:xb]
            return out
        # source tiles above this band are no longer needed: the pyramid cuts the map row by row
        for done in [t for t in self._cache if t.y0 + t.height <= y0]:
            del self._cache[done]
        for t in self._tiles:
            ta, tb = max(xa, t.x0), min(xb, t.x0 + t.width)
            tc, td = max(ya, t.y0), min(yb, t.y0 + t.height)
            if tb <= ta or td <= tc:
                continue
            img = self._load(t)
            out[tc - y0 : td - y0, ta - x0 : tb - x0] = img[tc - t.y0 : td - t.y0, ta - t.x0 : tb - t.x0]
        return out

    def _load(self, t: _SourceTile) -> np.ndarray:
        img = self._cache.get(t)
        if img is None:
            img = self._cache[t] = _decode_source(t)
        return img

    def preload(self, y0: int, h: int, pool: Executor) -> None:
        """Decodes the source tiles the band of rows [y0, y0 + h) reads, side by side on ``pool`` (PNG decoding
        runs in OpenCV without the GIL); ``read`` then finds them decoded. A map in memory needs nothing."""
        for done in [t for t in self._cache if t.y0 + t.height <= y0]:
            del self._cache[done]  # bands above are cut: at most one row of source tiles held, as by ``read``
        band = [t for t in self._tiles if t.y0 < y0 + h and t.y0 + t.height > y0 and t not in self._cache]
        for t, img in zip(band, pool.map(_decode_source, band), strict=True):
            self._cache[t] = img


def _decode_source(t: _SourceTile) -> np.ndarray:
    img = cv2.imread(str(t.path), cv2.IMREAD_UNCHANGED)
    if img is None or img.shape[:2] != (t.height, t.width) or img.ndim != 3 or img.shape[2] != 4:
        raise CompanionError(
            f"map tile {t.path} is missing or not the {t.width}x{t.height} BGRA tile map.vrt names",
            "run `companion stitch` again to rewrite the tiles",
        )
    return img


def max_zoom_for(width: int, height: int, tile_px: int = TILE_PX) -> int:
    """The level at which the map is at full resolution: level 0 fits in one tile."""
    return max(0, math.ceil(math.log2(max(width, height, 1) / tile_px)))


def _level_size(width: int, height: int, levels_down: int) -> tuple[int, int]:
    f = 2**levels_down
    return -(-width // f), -(-height // f)


def halve(block: np.ndarray) -> np.ndarray:
    """2x2 average of a BGRA block, weighted by alpha: uncovered (transparent) pixels do not darken the edges.

    Most blocks of a map are wholly covered or wholly uncovered: there the weighted average is the plain 2x2
    average (``cv2.resize`` INTER_AREA on the bytes, rounded half up like the float path) or zero, without the
    float work (tested equal to the weighted path pixel for pixel)."""
    h, w = block.shape[0] // 2, block.shape[1] // 2
    alpha_min, alpha_max, _, _ = cv2.minMaxLoc(cv2.extractChannel(block, 3))
    if alpha_max == 0:
        return np.zeros((h, w, 4), np.uint8)
    if alpha_min == 255 and block.shape[0] == 2 * h and block.shape[1] == 2 * w:
        return cv2.resize(block, (w, h), interpolation=cv2.INTER_AREA)
    return halve_weighted(block)


def halve_weighted(block: np.ndarray) -> np.ndarray:
    """:func:`halve` in float: every pixel's colour weighted by its alpha."""
    h, w = block.shape[0] // 2, block.shape[1] // 2
    alpha = block[..., 3].astype(np.float32)
    weighted = block[..., :3].astype(np.float32) * (alpha[..., None] / 255.0)
    a = cv2.resize(alpha, (w, h), interpolation=cv2.INTER_AREA)
    c = cv2.resize(weighted, (w, h), interpolation=cv2.INTER_AREA)
    colour = np.where(a[..., None] > 0, c * (255.0 / np.maximum(a, 1e-6))[..., None], 0.0)
    return np.dstack((np.clip(colour + 0.5, 0, 255), np.clip(a + 0.5, 0, 255))).astype(np.uint8)


def _tiles_of_level(w: int, h: int, tile_px: int) -> Iterator[tuple[int, int]]:
    for ty in range(-(-h // tile_px)):
        for tx in range(-(-w // tile_px)):
            yield tx, ty


def _write_png(path: Path, img: np.ndarray) -> None:
    if not cv2.imwrite(str(path), img):
        raise CompanionError(f"cannot write {path}", "check free disk space and permissions of the map folder")


class _TileWriter:
    """Writes pyramid tiles and remembers which hold any pixel. A map's pyramid is mostly blank tiles (the
    wall not flown yet, the margin around it): a blank tile is the same PNG every time, encoded once and its
    bytes written, and a coarser tile reads only the children that are not blank."""

    def __init__(self, tiles_dir: Path, tile_px: int):
        self.tiles_dir, self.tile_px = tiles_dir, tile_px
        _, png = cv2.imencode(".png", np.zeros((tile_px, tile_px, 4), np.uint8))
        self._blank_png = png.tobytes()
        self.drawn: set[tuple[int, int, int]] = set()  # (z, x, y) of the tiles with a non-zero byte

    def path(self, z: int, tx: int, ty: int) -> Path:
        return self.tiles_dir / str(z) / str(tx) / f"{ty}.png"

    def write(self, z: int, tx: int, ty: int, img: np.ndarray) -> None:
        path = self.path(z, tx, ty)
        if cv2.countNonZero(img.reshape(img.shape[0], -1)) == 0:
            try:
                path.write_bytes(self._blank_png)
            except OSError as exc:
                raise CompanionError(
                    f"cannot write {path} ({exc})", "check free disk space and permissions of the map folder"
                ) from exc
            return
        _write_png(path, img)
        self.drawn.add((z, tx, ty))

    def coarser(self, z: int, tx: int, ty: int) -> None:
        """Tile (tx, ty) of level z from the four level z + 1 tiles under it, already on disk."""
        t = self.tile_px
        block = np.zeros((2 * t, 2 * t, 4), np.uint8)
        for dx in (0, 1):
            for dy in (0, 1):
                if (z + 1, 2 * tx + dx, 2 * ty + dy) in self.drawn:
                    child = cv2.imread(str(self.path(z + 1, 2 * tx + dx, 2 * ty + dy)), cv2.IMREAD_UNCHANGED)
                    block[dy * t : (dy + 1) * t, dx * t : (dx + 1) * t] = child
        self.path(z, tx, ty).parent.mkdir(parents=True, exist_ok=True)
        self.write(z, tx, ty, halve(block))


def write_pyramid(reader: MapReader, tiles_dir: Path, *, url_prefix: str, tile_px: int = TILE_PX) -> PyramidInfo:
    """Writes ``tiles_dir/z/x/y.png`` for every level; returns what the page needs to load them.

    The map is cut in blocks of ``BLOCK_TILES`` x ``BLOCK_TILES`` full-resolution tiles (1024 px: one stitcher
    tile); each block gives its tiles at full resolution and, halved in memory, the levels below down to one
    tile, so those levels are never read back from their PNGs (halving is local to each 2 x 2 pixels: the same
    tiles as halving level by level from disk, tested). The coarser levels are made from the tiles on disk."""
    zmax = max_zoom_for(reader.width, reader.height, tile_px)
    tiles = _TileWriter(tiles_dir, tile_px)
    levels_in_block = min(zmax, BLOCK_LEVELS)  # levels below full resolution made from each block
    side = tile_px << levels_in_block  # the block, in map pixels
    grids = [_level_size(reader.width, reader.height, k) for k in range(levels_in_block + 1)]
    grids = [(-(-w // tile_px), -(-h // tile_px)) for w, h in grids]  # tiles per row and column, level zmax - k
    count = sum(nx * ny for nx, ny in grids)

    def cut(bx: int, by: int, block: np.ndarray) -> None:
        for k in range(levels_in_block + 1):
            if k:
                block = halve(block)
            n = 1 << (levels_in_block - k)  # tiles across the block at level zmax - k
            nx, ny = grids[k]
            for dy in range(n):
                for dx in range(n):
                    tx, ty = bx * n + dx, by * n + dy
                    if tx < nx and ty < ny:
                        tiles.path(zmax - k, tx, ty).parent.mkdir(parents=True, exist_ok=True)
                        part = block[dy * tile_px : (dy + 1) * tile_px, dx * tile_px : (dx + 1) * tile_px]
                        tiles.write(zmax - k, tx, ty, np.ascontiguousarray(part))

    # PNG encoding and decoding (and a coarser tile's four reads) run in OpenCV without the GIL: one block or tile
    # per thread, a level finished before the next reads it
    workers = max(1, len(os.sched_getaffinity(0)))
    with ThreadPoolExecutor(workers) as pool:
        written = []
        for by in range(-(-reader.height // side)):
            reader.preload(by * side, side, pool)  # a new band of blocks: its source tiles decoded on every thread
            for bx in range(-(-reader.width // side)):
                block = reader.read(bx * side, by * side, side, side)
                written.append(pool.submit(cut, bx, by, block))
                if len(written) > 2 * workers:  # bounded memory: wait for the oldest
                    written.pop(0).result()
        for f in written:
            f.result()
        for z in range(zmax - levels_in_block - 1, -1, -1):
            w, h = _level_size(reader.width, reader.height, zmax - z)
            jobs = [pool.submit(tiles.coarser, z, tx, ty) for tx, ty in _tiles_of_level(w, h, tile_px)]
            for f in jobs:
                f.result()
            count += len(jobs)
    return PyramidInfo(tile_px, zmax, reader.width, reader.height, url_prefix + "{z}/{x}/{y}.png", count)


def level_image(tiles_dir: Path, info: PyramidInfo, zoom: int) -> np.ndarray:
    """One pyramid level as a single BGRA image (for the small coverage overlay), cropped to the map."""
    w, h = _level_size(info.width_px, info.height_px, info.max_zoom - zoom)
    t = info.tile_px
    out = np.zeros((-(-h // t) * t, -(-w // t) * t, 4), np.uint8)
    for tx, ty in _tiles_of_level(w, h, t):
        img = cv2.imread(str(tiles_dir / str(zoom) / str(tx) / f"{ty}.png"), cv2.IMREAD_UNCHANGED)
        if img is not None:
            out[ty * t : (ty + 1) * t, tx * t : (tx + 1) * t] = img
    return out[:h, :w]

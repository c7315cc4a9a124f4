"""The face's map as a Cloud Optimized GeoTIFF in the wall's metric frame, for QGIS/GDAL and tile servers.

Why: ``map.png`` + world file opens in GDAL but has no overviews (a large face is slow to pan) and a tiled face is
a VRT of hundreds of PNGs; a COG is one file, internally tiled, with overviews, that GDAL, QGIS and HTTP range
readers open at any zoom. It is converted by GDAL's COG driver from what the stitcher wrote (the PNG with its
world file and CRS, or the VRT of the tiles), so its pixels, alpha (coverage), pixel size (the report's mm/px)
and wall-metre CRS are the map's own; GDAL streams the conversion block by block (memory bounded by its cache,
not by the map's size).

Two steps, not one: the COG driver reads its source block by block, twice (the full-resolution level, then again
for the overviews), and a PNG (``map.png``, or each tile behind ``map.vrt``) can only be decoded from its start:
every 512 px block re-decoded its PNG from the top (a 31 MP ``map.png``: 84 s on one thread). So the map is first
copied in one sequential pass into a tiled, lightly compressed GeoTIFF beside it (``.map_cog_src.tif``, removed
after), and the COG is made from that (the same 31 MP map: 2.5 + 3.7 s).
"""

from __future__ import annotations

from pathlib import Path

from companion.errors import CompanionError
from companion.files import atomic_path

COG_NAME = "map_cog.tif"
CACHE_MB = 256  # GDAL's block cache (the staged GeoTIFF is tiled: any map size streams through it)
STAGE_ROWS = 512  # map.png is copied into the staged GeoTIFF this many rows at a time


def write_cog(face_dir: Path, files: dict[str, str], threads: int = 0) -> Path | None:
    """``face_dir/map_cog.tif`` from the face's map (``files``: the stitcher's file list); None when the map has
    no georeferencing (scale unknown: nothing to put it in metres). ``threads`` compress blocks side by side (0:
    every core; on a worker, its own threads: compression was 3x the stitch's time single-threaded)."""
    source = files.get("map_vrt") or (files.get("map") if files.get("world_file") else None)
    if source is None:
        return None
    try:
        import rasterio
        import rasterio.shutil
    except ImportError:
        raise CompanionError("rasterio is not installed: the map cannot be written as a COG",
                             "pip install 'rasterio>=1.4', or run the site with --no-cog") from None
    out = face_dir / COG_NAME
    staged = face_dir / ".map_cog_src.tif"
    num_threads = str(threads) if threads > 0 else "ALL_CPUS"
    try:
        with rasterio.Env(GDAL_CACHEMAX=CACHE_MB):
            if Path(source).suffix == ".png":
                _stage_png(rasterio, Path(source), staged)
            else:
                _stage(rasterio.shutil, str(source), str(staged), num_threads)
        with rasterio.Env(GDAL_CACHEMAX=CACHE_MB), atomic_path(out) as tmp:
            rasterio.shutil.copy(str(staged), str(tmp), driver="COG", compress="DEFLATE", blocksize=512,
                                 overviews="AUTO", resampling="average", num_threads=num_threads)
    finally:
        staged.unlink(missing_ok=True)
    return out


def _stage_png(rasterio, png: Path, staged: Path) -> None:
    """``map.png`` (a map small enough to have been held in memory: at most ``max_in_memory_px``) decoded once by
    OpenCV and written into the staged GeoTIFF a band of rows at a time, with the georeferencing GDAL reads
    beside it (world file, CRS). GDAL's own PNG reader, copying to a tiled GeoTIFF, decoded a 57 MP map.png
    again and again (305 s, and 156 s with a cache the size of the map); this takes seconds."""
    import cv2

    with rasterio.open(png) as src:
        transform, crs = src.transform, src.crs
    bgra = cv2.imread(str(png), cv2.IMREAD_UNCHANGED)
    if bgra is None or bgra.ndim != 3 or bgra.shape[2] != 4:
        raise CompanionError(f"cannot read {png} as the BGRA map", "run the stitch again to rewrite the map")
    h, w = bgra.shape[:2]
    ci = rasterio.enums.ColorInterp
    with rasterio.open(staged, "w", driver="GTiff", width=w, height=h, count=4, dtype="uint8", crs=crs,
                       transform=transform, tiled=True, blockxsize=512, blockysize=512, compress="ZSTD",
                       zstd_level=1, photometric="RGB", alpha="YES") as dst:
        dst.colorinterp = [ci.red, ci.green, ci.blue, ci.alpha]
        for y in range(0, h, STAGE_ROWS):
            rows = bgra[y : y + STAGE_ROWS]
            window = rasterio.windows.Window(0, y, w, rows.shape[0])
            dst.write(cv2.cvtColor(rows, cv2.COLOR_BGRA2RGBA).transpose(2, 0, 1), window=window)


def _stage(shutil, source: str, staged: str, num_threads: str) -> None:
    """The map read once, in order, into a tiled GeoTIFF (ZSTD level 1: a tenth of the raw size at the speed of
    a raw copy; DEFLATE level 1 where GDAL was built without ZSTD)."""
    tiled = {"driver": "GTiff", "tiled": True, "blockxsize": 512, "blockysize": 512, "bigtiff": "IF_SAFER",
             "num_threads": num_threads}
    try:
        shutil.copy(source, staged, compress="ZSTD", zstd_level=1, **tiled)
    except Exception:  # noqa: BLE001 - a GDAL without ZSTD says so only by failing the copy
        shutil.copy(source, staged, compress="DEFLATE", zlevel=1, **tiled)

"""The face's map as a Cloud Optimized GeoTIFF in the wall's metric frame, for QGIS/GDAL and tile servers.

Why: ``map.png`` + world file opens in GDAL but has no overviews (a large face is slow to pan) and a tiled face is
a VRT of hundreds of PNGs; a COG is one file, internally tiled, with overviews, that GDAL, QGIS and HTTP range
readers open at any zoom. It is converted by GDAL's COG driver from what the stitcher wrote (the PNG with its
world file and CRS, or the VRT of the tiles), so its pixels, alpha (coverage), pixel size (the report's mm/px)
and wall-metre CRS are the map's own; GDAL streams the conversion block by block (memory bounded by its cache,
not by the map's size).
"""

from __future__ import annotations

from pathlib import Path

from companion.errors import CompanionError
from companion.files import atomic_path

COG_NAME = "map_cog.tif"


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
    with rasterio.Env(GDAL_CACHEMAX=256), atomic_path(out) as tmp:
        rasterio.shutil.copy(str(source), str(tmp), driver="COG", compress="DEFLATE", blocksize=512,
                             overviews="AUTO", resampling="average",
                             num_threads=str(threads) if threads > 0 else "ALL_CPUS")
    return out

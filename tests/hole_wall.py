"""Test helper: the 8 m x 4 m synthetic wall whose patch ``HOLE`` every keyframe masks out (a portal, a recess),
spooled and stitched once per session by tests/conftest.py (``hole_wall_spool``, ``hole_wall_map``,
``hole_wall_tiled``) for the modules that each made and stitched the same spool alike: tests/test_stitch_worker.py,
test_outputs_map.py and test_viewer.py. A stitch of it costs 7-11 s; three modules, two of them also tiled. The same
wall flown at 2 m with the patch in no keyframe (``missing_patch_map``): tests/test_stitch_worker.py and
test_mission_refly.py, 10-16 s a stitch.

The spool and the maps are read-only: a test that writes into a map folder works on its own copy (``map_copy``)."""

from __future__ import annotations

import shutil
from dataclasses import replace
from pathlib import Path

from evaluation.stitch.synthetic import SyntheticWall

WALL = SyntheticWall(length_m=8.0, height_m=4.0)
HOLE = (3.6, 4.4, 1.6, 2.4)  # along0, along1, up0, up1: masked as background in every keyframe


def map_copy(result, dest: Path):
    """``result`` (a ``StitchResult``) with its map folder copied to ``dest``, its files pointing there."""
    shutil.copytree(result.out_dir, dest)
    old = str(result.out_dir)
    files = {k: str(dest) + v[len(old):] if isinstance(v, str) and v.startswith(old) else v
             for k, v in result.files.items()}
    return replace(result, out_dir=Path(dest), files=files)

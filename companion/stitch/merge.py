"""Several spools of one wall as one stitcher input: a face's main flight and its re-flies make one map.

Why: a re-fly (``companion plan --refly``) fills the holes of a face's map; stitched on its own it is a second,
partial map that nobody merges. Merged here, its keyframes join the main flight's in one alignment, so the map
has no holes where the re-fly flew, and one report lists the face's coverage.

Keyframe indices are per spool (each flight counts from 0), so spool number ``k`` (in the order given) has its
indices moved by ``k * INDEX_STRIDE``: keyframe 12 of the second spool is 1000012 in the report, the caches and
the viewer. The first spool's wall geometry is the map's frame; every other spool must be the same wall
(:func:`same_wall`), else the merge is refused.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path

import pymap3d

from companion.errors import CompanionError
from companion.spool.reader import FacadeGeometry, StitchInput, load_spool

INDEX_STRIDE = 1_000_000  # spool k's keyframe i is index k * INDEX_STRIDE + i in the merged input
WALL_TOLERANCE_M = 1.0  # two spools' wall ends this close (and heights) are one wall: a mission's ends, re-typed


@dataclass(frozen=True)
class SpoolPart:
    """Where one spool's keyframes went in a merged input: its path and the first index given to them."""

    path: Path
    index_offset: int
    keyframes: int


def wall_gap_m(a: FacadeGeometry, b: FacadeGeometry) -> float:
    """The largest distance (metres) between the two walls' starts, ends, grounds and heights: 0 for the same
    wall. Ends are compared in ``a``'s local east-north plane (flat over a building's size)."""
    fa, fb = a.frame, b.frame
    o = fa.origin
    e, n, _ = pymap3d.geodetic2enu(fb.origin.lat, fb.origin.lon, o.alt_amsl_m, o.lat, o.lon, o.alt_amsl_m)
    start_b = (float(e), float(n))
    end_a = (fa.along_enu[0] * fa.length_m, fa.along_enu[1] * fa.length_m)
    end_b = (start_b[0] + fb.along_enu[0] * fb.length_m, start_b[1] + fb.along_enu[1] * fb.length_m)
    return max(
        math.hypot(*start_b),
        math.hypot(end_a[0] - end_b[0], end_a[1] - end_b[1]),
        abs(o.alt_amsl_m - fb.origin.alt_amsl_m),
        abs(a.height_m - b.height_m),
    )


def same_wall(a: FacadeGeometry | None, b: FacadeGeometry | None, tolerance_m: float = WALL_TOLERANCE_M) -> bool:
    """True when both spools name the same wall (start, end, ground and height within ``tolerance_m``); a spool
    without a wall is never the same wall as another (nothing says which wall it saw)."""
    return a is not None and b is not None and wall_gap_m(a, b) <= tolerance_m


def merge_spools(paths: list[str | Path]) -> tuple[StitchInput, tuple[SpoolPart, ...]]:
    """One input from the spools of one wall (the first spool's wall and camera), and where each spool's keyframes
    went. Refused, naming the spool: a different wall, or a different camera (one map is one camera mode)."""
    if not paths:
        raise CompanionError("no spool given", "give the face's spool directories (main flight first)")
    inputs = [load_spool(Path(p)) for p in paths]
    first = inputs[0]
    keyframes, skipped, parts = [], [], []
    for k, (path, inp) in enumerate(zip(paths, inputs, strict=True)):
        if k and not same_wall(first.facade, inp.facade):
            raise CompanionError(
                f"spool {path} is not of the wall of {paths[0]} (spool.json 'facade' differs by more than "
                f"{WALL_TOLERANCE_M} m, or one has none)",
                "stitch each wall's spools on their own, or `companion site` them together (it groups by wall)",
            )
        if k and not _same_camera(first, inp):
            raise CompanionError(
                f"spool {path} was taken with another camera mode than {paths[0]} (spool.json 'camera' differs)",
                "stitch the flights of each camera mode on their own",
            )
        offset = k * INDEX_STRIDE
        keyframes += [replace(kf, index=kf.index + offset) for kf in inp.keyframes]
        skipped += [replace(s, index=None if s.index is None else s.index + offset) for s in inp.skipped]
        parts.append(SpoolPart(Path(path), offset, len(inp.keyframes)))
    return replace(first, keyframes=keyframes, skipped=tuple(skipped)), tuple(parts)


def _same_camera(a: StitchInput, b: StitchInput) -> bool:
    if a.camera is None or b.camera is None:
        return a.camera is b.camera
    return (a.camera.width, a.camera.height) == (b.camera.width, b.camera.height) and bool(
        abs(a.camera.K - b.camera.K).max() < 1e-6 * max(1.0, float(a.camera.K[0, 0]))
    )

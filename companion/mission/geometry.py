"""Where the wall is: from start/end points or from a building footprint face, plus 2-D clearance checks."""

from __future__ import annotations

import math

import numpy as np
import pymap3d

from companion.errors import CompanionError
from companion.geo import FacadeFrame, GeoPoint
from companion.mission.spec import Mission
from companion.polygons import signed_area


def wall_frame(mission: Mission) -> FacadeFrame:
    """The facade frame of the mission's wall; a zero-length wall is a mission error, not a maths error."""
    start, end = wall_ends(mission)
    try:
        return FacadeFrame.from_wall(start, end)
    except ValueError:
        raise CompanionError(
            "the wall has zero length: facade.start and facade.end are the same point",
            "give two different wall ends (start = left end, end = right end, seen from the drone)",
        ) from None


def wall_ends(mission: Mission) -> tuple[GeoPoint, GeoPoint]:
    """Wall start (left, seen from the drone) and end at ground altitude."""
    f = mission.facade
    alt = f.ground_alt_amsl_m
    if f.footprint is None:
        return GeoPoint(f.start.lat, f.start.lon, alt), GeoPoint(f.end.lat, f.end.lon, alt)
    ring = _open_ring(f.footprint.coordinates or [])
    if len(ring) < 3:
        raise CompanionError(
            "building footprint needs at least 3 distinct corners", "give the outline as [lon, lat] pairs"
        )
    face = f.footprint.face
    if face >= len(ring):
        raise CompanionError(
            f"facade.footprint.face={face} but the footprint has only {len(ring)} edges",
            f"choose a face index from 0 to {len(ring) - 1} (edge i runs from corner i to corner i+1)",
        )
    a = ring[face]
    b = ring[(face + 1) % len(ring)]
    # Outward side of a counter-clockwise ring is the right-hand side of each edge: exactly our drone side.
    if signed_area(ring) > 0:  # lon/lat are locally proportional to east/north: the sign is preserved
        s, e = a, b
    else:
        s, e = b, a
    return GeoPoint(s[1], s[0], alt), GeoPoint(e[1], e[0], alt)


def footprint_enu(mission: Mission, origin: GeoPoint) -> np.ndarray | None:
    """Footprint corners in ENU metres around ``origin`` (N x 2), or None when no footprint was given."""
    fp = mission.facade.footprint
    if fp is None:
        return None
    ring = _open_ring(fp.coordinates or [])
    pts = [
        pymap3d.geodetic2enu(lat, lon, origin.alt_amsl_m, origin.lat, origin.lon, origin.alt_amsl_m)
        for lon, lat in ring
    ]
    return np.array([(p[0], p[1]) for p in pts])


def _open_ring(coords: list[tuple[float, float]]) -> list[tuple[float, float]]:
    ring = list(coords)
    if len(ring) > 1 and ring[0] == ring[-1]:
        ring = ring[:-1]
    return ring


def point_segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    ab = b - a
    denom = float(ab @ ab)
    t = 0.0 if denom == 0 else min(1.0, max(0.0, float((p - a) @ ab) / denom))
    return float(np.linalg.norm(p - (a + t * ab)))


def _segments_intersect(p1, p2, q1, q2) -> bool:
    def orient(a, b, c):
        return math.copysign(1.0, (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]))

    return orient(p1, p2, q1) != orient(p1, p2, q2) and orient(q1, q2, p1) != orient(q1, q2, p2)


def segment_distance(p1: np.ndarray, p2: np.ndarray, q1: np.ndarray, q2: np.ndarray) -> float:
    """Shortest distance between two 2-D segments."""
    if _segments_intersect(p1, p2, q1, q2):
        return 0.0
    return min(
        point_segment_distance(p1, q1, q2),
        point_segment_distance(p2, q1, q2),
        point_segment_distance(q1, p1, p2),
        point_segment_distance(q2, p1, p2),
    )


def polyline_clearance(path: np.ndarray, obstacle_edges: list[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
    """Per path segment, the horizontal distance to the nearest obstacle edge (path: N x 2)."""
    out = np.full(max(len(path) - 1, 0), np.inf)
    for i in range(len(path) - 1):
        for a, b in obstacle_edges:
            out[i] = min(out[i], segment_distance(path[i], path[i + 1], a, b))
    return out

"""The facade frame: the one coordinate system planner, simulator, gate and stitcher share.

Convention (documented in docs/ARCHITECTURE.md):
  * ``start`` and ``end`` are the two ends of the wall base. ``start`` is the LEFT end as seen by a drone that
    faces the wall, ``end`` the right end.
  * facade coordinates ``(along_m, out_m, up_m)``: ``along_m`` from start towards end, ``out_m`` horizontal
    distance from the wall plane on the drone's side (the drone flies at ``out_m = standoff``), ``up_m`` height
    above the wall base.
  * The drone's side is the outward normal obtained by turning start->end 90 degrees CLOCKWISE seen from above:
    a wall running west->east is flown from the south, looking north.
  * ENU is pymap3d's local East-North-Up with its origin at ``start`` on the ground (``ground_alt_amsl_m``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pymap3d


@dataclass(frozen=True)
class GeoPoint:
    """A WGS-84 position; ``alt_amsl_m`` is metres above mean sea level (as MAVLink reports it)."""

    lat: float
    lon: float
    alt_amsl_m: float = 0.0


@dataclass(frozen=True)
class FacadeFrame:
    """Conversions between geodetic, local ENU and facade coordinates for one wall."""

    origin: GeoPoint  # wall start at ground level
    along_enu: tuple[float, float]  # unit vector start->end, (east, north)
    length_m: float

    @classmethod
    def from_wall(cls, start: GeoPoint, end: GeoPoint) -> FacadeFrame:
        e, n, _ = pymap3d.geodetic2enu(
            end.lat, end.lon, start.alt_amsl_m, start.lat, start.lon, start.alt_amsl_m
        )
        length = math.hypot(e, n)
        if length <= 0.0:
            raise ValueError("wall start and end coincide")
        return cls(origin=start, along_enu=(e / length, n / length), length_m=length)

    @property
    def out_enu(self) -> tuple[float, float]:
        """Unit outward normal (towards the drone): start->end turned 90 degrees clockwise."""
        de, dn = self.along_enu
        return (dn, -de)

    @property
    def yaw_facing_wall_deg(self) -> float:
        """Heading (degrees clockwise from north, 0..360) of a camera looking straight at the wall."""
        oe, on = self.out_enu
        return round(math.degrees(math.atan2(-oe, -on)), 9) % 360.0

    def facade_to_enu(self, along_m, out_m, up_m) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        de, dn = self.along_enu
        oe, on = self.out_enu
        along_m, out_m, up_m = (np.asarray(v, dtype=float) for v in (along_m, out_m, up_m))
        return along_m * de + out_m * oe, along_m * dn + out_m * on, up_m

    def enu_to_facade(self, east_m, north_m, up_m) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        de, dn = self.along_enu
        oe, on = self.out_enu
        east_m, north_m, up_m = (np.asarray(v, dtype=float) for v in (east_m, north_m, up_m))
        return east_m * de + north_m * dn, east_m * oe + north_m * on, up_m

    def facade_to_geodetic(self, along_m, out_m, up_m) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Returns (lat, lon, alt_amsl_m)."""
        e, n, u = self.facade_to_enu(along_m, out_m, up_m)
        o = self.origin
        return pymap3d.enu2geodetic(e, n, u, o.lat, o.lon, o.alt_amsl_m)

    def geodetic_to_facade(self, lat, lon, alt_amsl_m) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        o = self.origin
        e, n, u = pymap3d.geodetic2enu(lat, lon, alt_amsl_m, o.lat, o.lon, o.alt_amsl_m)
        return self.enu_to_facade(e, n, u)

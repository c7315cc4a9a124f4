"""A forward-looking rangefinder that measures the facade wall from the TRUE vehicle position (issue 26).

Why: with a GNSS bias (gnss_bias.py) the estimate says the planned standoff while the vehicle is a metre or two
off; a laser rangefinder pointing along the camera's axis measures what GNSS cannot, the true distance to the wall.
The vehicle process does not otherwise know the wall (only the camera renders it), so the rig hands it the wall as
an option (``--rangefinder-wall``: both ends' latitude/longitude, the base altitude and the height, from the
mission), and the sensor intersects its ray with that wall rectangle.

The sensor is fixed to the body, pointing forward (MAVLink MAV_SENSOR_ROTATION_NONE): its ray leaves the true
position along the vehicle's heading, tilted down by the body's pitch (nose down looks down); roll does not move a
forward axis. A ray that misses the wall rectangle, or meets it outside [min, max], gives no reading, which
DISTANCE_SENSOR says as max_distance + 1 cm (MAVLink's convention). A reading carries Gaussian noise from its own
seeded generator.
"""

from __future__ import annotations

import argparse
import math
from dataclasses import dataclass

import numpy as np
import pymap3d

from companion.geo import GeoPoint

DEFAULT_MAX_M = 40.0
DEFAULT_MIN_M = 0.2
DEFAULT_NOISE_M = 0.02
RATE_HZ = 10.0


@dataclass(frozen=True)
class WallSpec:
    """The facade wall as the command line gives it: base ends (start, end: latitude, longitude, the base's AMSL
    altitude) and height above that base."""

    start: GeoPoint
    end: GeoPoint
    height_m: float

    def option(self) -> str:
        """The ``--rangefinder-wall`` value that parses back to this wall."""
        s, e = self.start, self.end
        return ",".join(repr(float(v)) for v in (s.lat, s.lon, e.lat, e.lon, s.alt_amsl_m, self.height_m))

    @classmethod
    def of_mission(cls, mission) -> WallSpec:
        """The mission's wall (its two ends at ground altitude, from a footprint face too) and height."""
        from companion.mission.geometry import wall_ends

        start, end = wall_ends(mission)
        return cls(start, end, float(mission.facade.height_m))


def parse_wall(text: str) -> WallSpec:
    """``LAT,LON,LAT,LON,BASE_AMSL,HEIGHT`` -> WallSpec (argparse type: a malformed value is a usage error)."""
    try:
        v = [float(p) for p in text.split(",")]
    except ValueError:
        v = []
    ok = (len(v) == 6 and all(math.isfinite(x) for x in v) and -90 <= v[0] <= 90 and -90 <= v[2] <= 90
          and -180 <= v[1] <= 180 and -180 <= v[3] <= 180 and v[5] > 0 and (v[0], v[1]) != (v[2], v[3]))
    if not ok:
        raise argparse.ArgumentTypeError(
            "--rangefinder-wall wants START_LAT,START_LON,END_LAT,END_LON,BASE_ALT_AMSL,HEIGHT (two different "
            f"ends, a positive height; e.g. 37.5665,126.9780,37.5665,126.9784,30,20), got {text!r}")
    return WallSpec(GeoPoint(v[0], v[1], v[4]), GeoPoint(v[2], v[3], v[4]), v[5])


@dataclass(frozen=True)
class WallNed:
    """The wall rectangle in the vehicle's local NED frame (origin: home): base ends (north, east), and its top
    and base as Down coordinates (top < base)."""

    a: tuple[float, float]
    b: tuple[float, float]
    top_down_m: float
    base_down_m: float

    @classmethod
    def from_spec(cls, wall: WallSpec, home: GeoPoint) -> WallNed:
        ends = [pymap3d.geodetic2ned(p.lat, p.lon, p.alt_amsl_m, home.lat, home.lon, home.alt_amsl_m)
                for p in (wall.start, wall.end)]
        base_down = float(ends[0][2])
        return cls((float(ends[0][0]), float(ends[0][1])), (float(ends[1][0]), float(ends[1][1])),
                   base_down - wall.height_m, base_down)

    def ray_distance(self, origin: np.ndarray, direction: np.ndarray) -> float | None:
        """Distance along the unit ``direction`` from ``origin`` (NED) to the wall rectangle; None on a miss."""
        ax, ay = self.a
        ex, ey = self.b[0] - ax, self.b[1] - ay
        dx, dy = float(direction[0]), float(direction[1])
        det = ex * dy - ey * dx  # origin + t d = a + s e, solved in the horizontal plane
        if abs(det) < 1e-12:
            return None  # the ray runs along the wall
        rx, ry = ax - float(origin[0]), ay - float(origin[1])
        t = (ex * ry - ey * rx) / det
        s = (dx * ry - dy * rx) / det
        if t <= 0.0 or not 0.0 <= s <= 1.0:
            return None
        down = float(origin[2]) + t * float(direction[2])
        if not self.top_down_m <= down <= self.base_down_m:
            return None
        return t


def forward_ray(yaw_deg: float, pitch_deg: float) -> np.ndarray:
    """Unit NED direction of the body's forward axis (yaw clockwise from north, pitch nose up positive)."""
    y, p = math.radians(yaw_deg), math.radians(pitch_deg)
    return np.array([math.cos(p) * math.cos(y), math.cos(p) * math.sin(y), -math.sin(p)])


SEES = ("wall", "ground")  # what the sensor labelled forward measures (--rangefinder-sees)


class ForwardRangefinder:
    """Readings of the forward rangefinder: metres, or None (no wall within [min, max] on the ray).

    ``sees="ground"`` reproduces what real ArduCopter SITL's simulated rangefinder did (RNGFND1_TYPE 100 with
    RNGFND1_ORIENT 0, 2026-12-04): DISTANCE_SENSOR said "forward" but the reading was the height above the ground
    along a downward beam (its model uses SIM_SONAR_ROT, down, whatever the orientation parameter says). A sensor
    mounted or configured wrong on a real vehicle does the same; the companion must not take it for the wall."""

    def __init__(self, wall: WallNed | None, rng: np.random.Generator, *, min_m: float = DEFAULT_MIN_M,
                 max_m: float = DEFAULT_MAX_M, noise_m: float = DEFAULT_NOISE_M, sees: str = "wall"):
        if sees not in SEES:
            raise ValueError(f"a rangefinder sees one of {SEES}, not {sees!r}")
        self.wall, self.rng, self.sees = wall, rng, sees
        self.min_m, self.max_m, self.noise_m = min_m, max_m, noise_m

    def measure(self, true_pos_ned: np.ndarray, yaw_deg: float, pitch_deg: float) -> float | None:
        if self.sees == "ground":  # the height (home is on the ground), along a beam tilted with the body
            d = -float(true_pos_ned[2]) / max(math.cos(math.radians(pitch_deg)), 0.1)
            d += self.noise_m * float(self.rng.standard_normal()) if self.noise_m > 0.0 else 0.0
            return d if self.min_m <= d <= self.max_m else None
        if self.wall is None:
            return None
        d = self.wall.ray_distance(true_pos_ned, forward_ray(yaw_deg, pitch_deg))
        if d is None:
            return None
        if self.noise_m > 0.0:
            d += self.noise_m * float(self.rng.standard_normal())
        return d if self.min_m <= d <= self.max_m else None

"""Which frames the keyframe gate judges: frames of the constant-standoff scan, not of the take-off or the landing.

Why (issue 17, measured on the fresh-clone demo's spool, ``bench/keyframe_phases.py``): of 375 keyframes, 74 were
taken during take-off, transit and landing, 9-14 m from the wall where the vehicle climbs and descends facing it
(the planned scan is flown at 4 m). Those frames show the whole wall at three times the scan's ground sample
distance; they are no keyframes of the scan the planner laid out and the stitcher maps at the standoff, and the
gate judged them badly besides (the telemetry's wall motion assumes the planned standoff, so it put true 94 %
overlaps at 80 %, and its prior made the image's own measurement fail: a keyframe every 0.2-0.9 s).

Likewise the transit above the roof: the camera near the standoff but its footprint on the wall plane metres above
the wall and the roof margin the mission asks for (roof and sky only; on the demo the gate kept two such frames on
the telemetry alone, and the first frame of the wall after them was then kept at R 0 %).

The rules here are deliberately loose, so that no frame of the scan is lost to a position error: a frame is off the
scan only when its camera is more than ``max_distance_factor`` times the standoff from the wall plane (twice the
planned GSD and more; at the demo's 4 m, beyond 8 m: a position error that large would have flown the vehicle
into the wall), or when its footprint misses the scan extent (the wall plus the mission's margins) by more than
``extent_tolerance_m``. Frames without a pose, or with a stale one, are judged as before inside an open segment
(the images decide); once the stream has had poses, such a frame never opens a segment (``ScanPhase``).

Those loose rules are too loose to say which frames the scan is made of (issue 17's judged run at 30 fps): a frame
of the transit 7.8 m out at the 18 m transit height (the camera looking level, its footprint's bottom edge at
15.0 m: inside the 1 m tolerance above the 14 m roof margin) became the first keyframe; the frames after it showed
no facade, and the first wall keyframe overlapped it by 0 % (a pair below target). Replayed (bench/flight_replay.py),
opening on the first frame of the roof margin instead only moved the problem: the depth mask kept that frame (roof
edge) and dropped the next 2.8 s of the descent (sky and roof: no facade), so the first wall keyframe was again
kept below target (35 %); on the climb off the last strip over the margin, two pairs were kept at 78-80 % from
telemetry for the same reason. So the scan is the frames that SHOW THE WALL (``ScanPhase``): a segment opens on a
frame whose camera is within ``open_band`` x the standoff of the standoff and whose footprint meets the wall
rectangle (``wall``; no tolerance), stays open while frames show the wall within the loose distance rule, and the
first frame that does not ends it (the gate keeps its last view, as at the end of a stream); a later opening
starts a new segment, not judged against the keyframes before the gap. The planner's expected count judges the
same frames (``companion.mission.keyframe_count``: frames on the standoff showing the wall), so no frame it counts
is put off the scan; the roof-margin frames above the wall that it no longer counts add nothing to the scan
extent, which the strips' top frames cover up to the margin. Without a ``wall`` the scope is the extent, as before.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import StrEnum

import cv2
import numpy as np

from companion.attitude import camera_rotation_enu
from companion.errors import CompanionError
from companion.geo import FacadeFrame
from companion.records import Pose
from companion.wall_footprint import corner_footprint, facade_from_enu

_NOMINAL_WIDTH_PX = 1600.0  # a footprint depends on the lens and the aspect, not the pixel count


@dataclass(frozen=True)
class ScanScope:
    """``frame``: the wall (facade frame); ``standoff_m``: the planned camera-to-wall distance; ``extent``: the
    scan extent on the wall plane (along_min, along_max, up_min, up_max in metres: the wall plus the mission's
    margins) with the lens (``hfov_deg``, ``aspect`` = height / width), or None to judge by distance alone."""

    frame: FacadeFrame
    standoff_m: float
    max_distance_factor: float = 2.0
    extent: tuple[float, float, float, float] | None = None
    hfov_deg: float = 69.0
    aspect: float = 9.0 / 16.0
    extent_tolerance_m: float = 1.0
    open_band: float = 0.5  # a scan segment opens only within this share of the standoff from the standoff
    wall: tuple[float, float, float, float] | None = None  # the wall itself (along, up metres); None: the extent
    # the last pose's footprint: a frame's scope asks for it up to twice (loose extent, then the wall itself)
    _last_footprint: list = field(default_factory=list, init=False, repr=False, compare=False, hash=False)

    def __post_init__(self) -> None:
        if not (self.standoff_m > 0.0 and math.isfinite(self.standoff_m)):
            raise CompanionError(f"standoff_m={self.standoff_m} is not a distance in front of the wall",
                                 "give the planned camera-to-wall distance in metres (e.g. 4.0)")
        if self.extent_tolerance_m < 0.0 or not 1.0 < self.hfov_deg < 179.0:
            raise CompanionError(f"extent_tolerance_m={self.extent_tolerance_m}, hfov_deg={self.hfov_deg} are not a "
                                 "tolerance and a lens", "give a tolerance >= 0 m and the camera's hfov in degrees")
        if not self.max_distance_factor > 1.0:
            raise CompanionError(f"max_distance_factor={self.max_distance_factor} would drop frames of the scan",
                                 "use a factor above 1 (e.g. 2: frames beyond twice the standoff are off the scan)")
        if not 0.0 < self.open_band < self.max_distance_factor - 1.0:
            raise CompanionError(f"open_band={self.open_band} is not a band around the standoff inside the scan",
                                 f"use a share of the standoff in (0, {self.max_distance_factor - 1.0:g}), e.g. 0.5")

    @property
    def max_distance_m(self) -> float:
        return self.max_distance_factor * self.standoff_m

    def distance_m(self, pose: Pose | None) -> float | None:
        """The camera's distance out from the wall plane (None without a usable pose)."""
        if pose is None:
            return None
        values = (pose.lat, pose.lon, pose.alt_amsl_m)
        if not all(math.isfinite(float(v)) for v in values):
            return None
        _, out, _ = self.frame.geodetic_to_facade(*values)
        return float(out)

    def footprint(self, pose: Pose | None) -> np.ndarray | None:
        """The frame's corners on the wall plane, (4, 2) along/up metres (None: no pose, or a corner's ray misses
        the wall plane ahead)."""
        last = self._last_footprint
        if last and last[0] is pose:
            return last[1]
        corners = self._footprint_of(pose)
        last[:] = [pose, corners]
        return corners

    def _footprint_of(self, pose: Pose | None) -> np.ndarray | None:
        if pose is None or not all(math.isfinite(float(v)) for v in (pose.lat, pose.lon, pose.alt_amsl_m,
                                                                        *pose.camera_angles())):
            return None
        centre = np.array([float(v) for v in self.frame.geodetic_to_facade(pose.lat, pose.lon, pose.alt_amsl_m)])
        yaw, pitch, roll = pose.camera_angles()
        rotation = facade_from_enu(self.frame) @ camera_rotation_enu(yaw_deg=yaw, pitch_deg=pitch, roll_deg=roll)
        w, h = _NOMINAL_WIDTH_PX, _NOMINAL_WIDTH_PX * self.aspect
        f = (w / 2.0) / math.tan(math.radians(self.hfov_deg) / 2.0)
        K = np.array([[f, 0.0, w / 2.0], [0.0, f, h / 2.0], [0.0, 0.0, 1.0]])
        return corner_footprint(K, w, h, centre, rotation)

    def wall_unseen(self, pose: Pose | None, seen_from: Pose | None, grid_px: int = 160) -> float | None:
        """The share of the frame taken from ``pose`` that shows the wall (``wall``, else the scan extent) where
        the frame taken from ``seen_from`` does not: by the two footprints on the wall plane, sampled on a grid of
        ``grid_px`` columns. None: nothing to tell it by (no wall nor extent, a pose missing, or a footprint not on
        the wall plane ahead). The gate asks it of a frame it could not measure at a segment's end: one whose wall
        the last keyframe shows loses no wall (``KeyframeGate.wall_unseen``)."""
        region = self.wall or self.extent
        if region is None:
            return None
        corners, seen = self._footprint_of(pose), self._footprint_of(seen_from)
        if corners is None or seen is None:
            return None
        w, h = _NOMINAL_WIDTH_PX, _NOMINAL_WIDTH_PX * self.aspect
        image = np.array([[0.0, 0.0], [w, 0.0], [w, h], [0.0, h]], dtype=np.float32)
        try:
            to_wall = cv2.getPerspectiveTransform(image, corners.astype(np.float32)).astype(np.float64)
            to_seen = cv2.getPerspectiveTransform(seen.astype(np.float32), image).astype(np.float64)
        except cv2.error:
            return None
        nx, ny = grid_px, max(1, round(grid_px * self.aspect))
        xs, ys = np.meshgrid((np.arange(nx) + 0.5) * w / nx, (np.arange(ny) + 0.5) * h / ny)
        pts = np.stack([xs.ravel(), ys.ravel(), np.ones(xs.size)], axis=1) @ to_wall.T
        along, up = pts[:, 0] / pts[:, 2], pts[:, 1] / pts[:, 2]
        a0, a1, u0, u1 = region
        on_wall = (along >= a0) & (along <= a1) & (up >= u0) & (up <= u1)
        q = np.stack([along, up, np.ones(along.size)], axis=1) @ to_seen.T
        ahead = np.sign(np.append(seen.mean(axis=0), 1.0) @ to_seen[2])  # the sign of a point in front of it
        with np.errstate(divide="ignore", invalid="ignore"):
            x, y = q[:, 0] / q[:, 2], q[:, 1] / q[:, 2]
        shown = (np.sign(q[:, 2]) == ahead) & (x >= 0.0) & (x <= w) & (y >= 0.0) & (y <= h)
        return float(np.count_nonzero(on_wall & ~shown)) / float(along.size)

    def misses_extent(self, pose: Pose | None, tolerance_m: float | None = None,
                      region: tuple[float, float, float, float] | None = None) -> bool:
        """True when the frame's footprint lies wholly outside the scan extent (or ``region``) grown by
        ``tolerance_m`` (default: ``extent_tolerance_m``)."""
        region = region or self.extent
        if region is None:
            return False
        corners = self.footprint(pose)
        if corners is None:
            return False
        a0, a1, u0, u1 = region
        tol = self.extent_tolerance_m if tolerance_m is None else tolerance_m
        along, up = corners[:, 0], corners[:, 1]
        return bool(along.max() < a0 - tol or along.min() > a1 + tol or up.max() < u0 - tol or up.min() > u1 + tol)

    def off_scan(self, pose: Pose | None, stale: bool = False) -> bool:
        """True when the frame was taken too far from the wall, or shows none of the scan extent, to be a frame of
        the scan."""
        if stale:
            return False
        distance = self.distance_m(pose)
        if distance is not None and abs(distance) > self.max_distance_m:
            return True
        return self.misses_extent(pose)

    def shows_wall(self, pose: Pose | None, stale: bool = False) -> bool:
        """True when the frame's footprint meets the wall itself (no tolerance); True without a ``wall`` or a
        usable pose (nothing to tell it by: the images decide)."""
        if stale or self.wall is None:
            return True
        return not self.misses_extent(pose, tolerance_m=0.0, region=self.wall)

    def opens_scan(self, pose: Pose | None, stale: bool = False) -> bool:
        """True when the frame may open a scan segment: its camera within ``open_band`` x the standoff of the
        standoff and its footprint on the wall itself (``wall``, else the scan extent; no tolerance). Frames
        without a usable pose open it (the images decide) only in a stream that has had none: ``ScanPhase``
        keeps them from opening one once poses came."""
        if stale:
            return True
        distance = self.distance_m(pose)
        if distance is None:
            return True
        if abs(distance - self.standoff_m) > self.open_band * self.standoff_m:
            return False
        return not self.misses_extent(pose, tolerance_m=0.0, region=self.wall)


class ScopeStep(StrEnum):
    """What ``ScanPhase.step`` made of a frame."""

    OPENS = "opens"  # the first frame of a scan segment: judged
    SCAN = "scan"  # a frame of an open segment: judged
    LEAVES = "leaves"  # the first frame off the scan after a segment: not judged, the segment ends here
    OFF = "off"  # not a frame of the scan (take-off, transit, landing, before the scan opens): not judged

    @property
    def judged(self) -> bool:
        return self in (ScopeStep.OPENS, ScopeStep.SCAN)


class ScanPhase:
    """The scope over a stream of frames: a segment opens on a frame showing the wall from near the standoff
    (``opens_scan``) and stays open while frames show the wall within the loose rules (``off_scan``,
    ``shows_wall``); see the module docstring."""

    def __init__(self, scope: ScanScope):
        self.scope = scope
        self.is_open = False
        self.openings = 0  # scan segments opened so far
        self.seen_pose = False  # a frame with a usable pose came: the stream has telemetry

    def step(self, pose: Pose | None, stale: bool = False) -> ScopeStep:
        posed = not stale and self.scope.distance_m(pose) is not None
        self.seen_pose = self.seen_pose or posed
        if self.is_open:
            if self.scope.off_scan(pose, stale) or not self.scope.shows_wall(pose, stale):
                self.is_open = False
                return ScopeStep.LEAVES
            return ScopeStep.SCAN
        if not posed and self.seen_pose:
            # No pose in a stream that has them (a telemetry gap: test_onboard_sitl on a loaded machine, the
            # autopilot's positions a second apart): nothing says this frame shows the wall from the standoff, and
            # opening on it let the images alone spool keyframes without a pose. The next posed frame decides.
            return ScopeStep.OFF
        if self.scope.off_scan(pose, stale) or not self.scope.opens_scan(pose, stale):
            return ScopeStep.OFF
        self.is_open = True
        self.openings += 1
        return ScopeStep.OPENS

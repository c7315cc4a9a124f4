"""A photo's pose from its own tags, and the wall bound it gives with a mission (``companion mask --mission``).

What is read, and why these tags: the EXIF GPS position (every drone writes it), the XMP ``drone-dji`` tags DJI
writes and companion's keyframes copy (companion/spool/exif.py): ``GimbalYawDegree`` / ``GimbalPitchDegree`` /
``GimbalRollDegree`` (0 = horizontal, -90 = nadir) and ``RelativeAltitude`` (barometric, above take-off), else
Pix4D's ``Camera:Yaw/Pitch/Roll`` (pitch 90 = horizontal) that companion writes for every make; the focal length
from EXIF ``FocalLength`` x ``FocalPlaneXResolution`` (exact in companion's keyframes) or the 35 mm equivalent. A
photo without a position or a camera heading has no pose: it is masked by the network alone, as before.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from companion.attitude import camera_rotation_enu
from companion.depth.wall_bound import CameraView, PoseUncertainty, WallExtent, wall_bound
from companion.errors import CompanionError
from companion.geo import FacadeFrame
from companion.spool.exif import read_xmp

GNSS_VERTICAL_SIGMA_M = 3.0  # a photo with no barometric relative altitude: its GPS altitude is this uncertain
_TAG = re.compile(r"(drone-dji|Camera):(\w+)\s*=\s*\"([^\"]*)\"|<(drone-dji|Camera):(\w+)>([^<]*)</")
_FOCAL_PLANE_UNIT_MM = {2: 25.4, 3: 10.0, 4: 1.0, 5: 0.001}  # EXIF FocalPlaneResolutionUnit -> mm per unit


@dataclass(frozen=True)
class PhotoPose:
    """Where a photo was taken and where its camera looked, as its tags say."""

    lat: float
    lon: float
    alt_amsl_m: float
    relative_alt_m: float | None  # barometric height above take-off (DJI RelativeAltitude), None when not written
    yaw_deg: float  # camera heading, clockwise from north
    pitch_deg: float  # camera tilt up from horizontal
    roll_deg: float
    focal_px: float | None  # at the photo's stored width; None when the tags give no focal length


@dataclass(frozen=True)
class MissionWall:
    """What the bound needs from a mission: the facade frame, the wall's size, the ground heights, the camera."""

    frame: FacadeFrame
    extent: WallExtent
    ground_alt_amsl_m: float  # the wall's base
    takeoff_ground_alt_amsl_m: float  # where relative altitude counts from
    hfov_deg: float  # the mission camera's, for photos whose tags give no focal length

    @classmethod
    def from_mission(cls, mission) -> MissionWall:
        from companion.mission.geometry import wall_frame

        frame = wall_frame(mission)
        ground = mission.facade.ground_alt_amsl_m
        takeoff = getattr(mission, "takeoff", None)
        takeoff_ground = takeoff.ground_alt_amsl_m if takeoff is not None and \
            takeoff.ground_alt_amsl_m is not None else ground
        return cls(frame, WallExtent(frame.length_m, mission.facade.height_m), ground, takeoff_ground,
                   mission.camera.hfov_deg)


def _xmp_tags(data: bytes) -> dict[str, str]:
    xmp = read_xmp(data) or ""
    tags: dict[str, str] = {}
    for m in _TAG.finditer(xmp):
        ns, name, value = (m.group(1), m.group(2), m.group(3)) if m.group(1) else (m.group(4), m.group(5), m.group(6))
        tags[f"{ns}:{name}"] = value.strip()
    return tags


def _number(value) -> float | None:
    try:
        out = float(value)
    except (TypeError, ValueError, ZeroDivisionError):
        return None
    return out if math.isfinite(out) else None


def _gps(exif) -> tuple[float, float, float] | None:
    """(lat, lon, alt) from the EXIF GPS IFD, signed by its N/S, E/W and altitude-ref tags."""
    gps = exif.get_ifd(0x8825)
    try:
        lat = sum(float(v) / 60 ** k for k, v in enumerate(gps[2])) * (-1 if gps.get(1) in ("S", b"S") else 1)
        lon = sum(float(v) / 60 ** k for k, v in enumerate(gps[4])) * (-1 if gps.get(3) in ("W", b"W") else 1)
    except (KeyError, TypeError, ValueError, ZeroDivisionError):
        return None
    alt = _number(gps.get(6)) or 0.0
    return lat, lon, -alt if gps.get(5) in (1, b"\x01") else alt


def _focal_px(exif, width: int) -> float | None:
    """Focal length in pixels at ``width``: FocalLength x FocalPlaneXResolution, else the 35 mm equivalent."""
    ifd = exif.get_ifd(0x8769)
    focal_mm, per_unit = _number(ifd.get(0x920A)), _number(ifd.get(0xA20E))
    unit = _FOCAL_PLANE_UNIT_MM.get(int(ifd.get(0xA210, 2) or 2))
    stored = _number(ifd.get(0xA002))
    if focal_mm and per_unit and unit and stored:
        return focal_mm * per_unit / unit * width / stored
    eq35 = _number(ifd.get(0xA405))
    return eq35 / 36.0 * width if eq35 else None


def read_photo_pose(path: str | Path) -> PhotoPose | None:
    """The pose a photo's tags give; None without a GPS position or a camera heading (the photo has no pose)."""
    from PIL import Image, UnidentifiedImageError

    data = Path(path).read_bytes()
    try:
        with Image.open(path) as im:
            exif, width = im.getexif(), im.width
    except (UnidentifiedImageError, OSError):
        return None
    if exif.get(0x0112, 1) not in (0, 1):  # turned by its Orientation tag: the intrinsics would need turning too
        return None
    tags = _xmp_tags(data)
    position = _gps(exif)
    lat, lon = _number(tags.get("drone-dji:GpsLatitude")), _number(tags.get("drone-dji:GpsLongitude"))
    alt = _number(tags.get("drone-dji:AbsoluteAltitude"))
    if position is not None:
        lat, lon = position[0], position[1]
        alt = alt if alt is not None else position[2]
    yaw, pitch = _number(tags.get("drone-dji:GimbalYawDegree")), _number(tags.get("drone-dji:GimbalPitchDegree"))
    roll = _number(tags.get("drone-dji:GimbalRollDegree"))
    if yaw is None or pitch is None:  # Pix4D's: pitch 90 = horizontal
        yaw, pitch = _number(tags.get("Camera:Yaw")), _number(tags.get("Camera:Pitch"))
        pitch, roll = (None if pitch is None else pitch - 90.0), _number(tags.get("Camera:Roll"))
    if lat is None or lon is None or yaw is None or pitch is None:
        return None
    return PhotoPose(lat, lon, alt or 0.0, _number(tags.get("drone-dji:RelativeAltitude")), yaw % 360.0, pitch,
                     roll or 0.0, _focal_px(exif, width))


def camera_view(pose: PhotoPose, wall: MissionWall, width: int, height: int) -> CameraView:
    """The photo's camera in the wall's facade frame; the height above the wall's base from the barometric
    relative altitude (plus take-off ground minus wall ground) when written, else from the GPS altitude."""
    focal = pose.focal_px or (width / 2.0) / math.tan(math.radians(wall.hfov_deg) / 2.0)
    K = np.array([[focal, 0.0, width / 2.0], [0.0, focal, height / 2.0], [0.0, 0.0, 1.0]])
    along, out, _ = wall.frame.geodetic_to_facade(pose.lat, pose.lon, wall.ground_alt_amsl_m)
    if pose.relative_alt_m is not None:
        up = pose.relative_alt_m + wall.takeoff_ground_alt_amsl_m - wall.ground_alt_amsl_m
    else:
        up = pose.alt_amsl_m - wall.ground_alt_amsl_m
    from companion.wall_footprint import facade_from_enu

    R = facade_from_enu(wall.frame) @ camera_rotation_enu(pose.yaw_deg, pose.pitch_deg, pose.roll_deg)
    return CameraView(K, width, height, np.array([float(along), float(out), float(up)]), R)


def photo_bound(path: str | Path, shape: tuple[int, ...], wall: MissionWall,
                uncertainty: PoseUncertainty | None = None) -> np.ndarray | None:
    """The wall bound of one photo (``shape``: the decoded image's), or None when it has no pose or nothing is
    cut. A photo without barometric relative altitude gets the GNSS vertical uncertainty."""
    pose = read_photo_pose(path)
    if pose is None:
        return None
    u = uncertainty or PoseUncertainty()
    if pose.relative_alt_m is None:
        u = replace(u, vertical_m=max(u.vertical_m, GNSS_VERTICAL_SIGMA_M))
    return wall_bound(camera_view(pose, wall, int(shape[1]), int(shape[0])), wall.extent, u)


def checked_mission_wall(path: str | Path) -> MissionWall:
    """The mission file's wall, for ``--mission`` (its errors name the field to fix)."""
    from companion.mission.spec import load_mission

    try:
        return MissionWall.from_mission(load_mission(path))
    except CompanionError:
        raise
    except (ValueError, AttributeError) as exc:  # pragma: no cover - the spec validates the fields used here
        raise CompanionError(f"mission {path}: {exc}", "check facade.start/end, height_m and camera") from exc

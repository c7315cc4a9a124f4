"""Pinhole camera model and true camera poses: the geometry every rendered pixel and every truth figure uses.

Conventions: world = local ENU (metres, origin at the wall start on the ground, see companion.geo). Camera axes
are OpenCV's: x right, y down, z forward. ``R_world_from_cam`` maps camera-axis vectors to ENU vectors. Depth is
z-depth (distance along the optical axis), the quantity a monocular depth network estimates.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from companion.attitude import camera_rotation_enu
from companion.errors import CompanionError


@dataclass(frozen=True)
class CameraModel:
    """Intrinsics of an ideal pinhole camera (no distortion): size in pixels and horizontal field of view."""

    width: int = 3840
    height: int = 2160
    hfov_deg: float = 69.0

    def __post_init__(self):
        if self.width < 16 or self.height < 16:
            raise CompanionError(
                f"camera size {self.width}x{self.height} px is too small", "use at least 16x16 pixels"
            )
        if not 1.0 < self.hfov_deg < 179.0:
            raise CompanionError(
                f"camera hfov_deg={self.hfov_deg} is outside (1, 179)", "give the horizontal field of view in degrees"
            )

    @property
    def fx(self) -> float:
        return (self.width / 2.0) / math.tan(math.radians(self.hfov_deg) / 2.0)

    @property
    def K(self) -> np.ndarray:
        """3x3 intrinsic matrix; square pixels, principal point at the image centre (pixel centres at +0.5)."""
        f = self.fx
        return np.array([[f, 0.0, self.width / 2.0], [0.0, f, self.height / 2.0], [0.0, 0.0, 1.0]])

    @property
    def vfov_deg(self) -> float:
        return math.degrees(2.0 * math.atan((self.height / 2.0) / self.fx))

    def scaled(self, width_px: int) -> CameraModel:
        """Same lens and aspect ratio at a working resolution ``width_px`` wide."""
        if width_px < 16:
            raise CompanionError(f"width_px={width_px} is too small", "use a working width of at least 16 px")
        height = max(16, int(round(self.height * width_px / self.width)))
        return CameraModel(width=int(width_px), height=height, hfov_deg=self.hfov_deg)


@dataclass(frozen=True)
class TruePose:
    """Exact camera pose at one capture instant (ground truth; only sim/ and evaluations read it)."""

    position_enu: np.ndarray  # camera centre, metres
    R_world_from_cam: np.ndarray  # 3x3
    yaw_deg: float
    pitch_deg: float
    roll_deg: float
    lat: float = math.nan
    lon: float = math.nan
    alt_amsl_m: float = math.nan
    velocity_enu_m_s: np.ndarray = field(default_factory=lambda: np.zeros(3))
    angular_rate_cam_rad_s: np.ndarray = field(default_factory=lambda: np.zeros(3))

    @classmethod
    def from_angles(cls, position_enu, yaw_deg: float, pitch_deg: float, roll_deg: float = 0.0, **kw) -> TruePose:
        R = camera_rotation_enu(yaw_deg=yaw_deg, pitch_deg=pitch_deg, roll_deg=roll_deg)
        return cls(np.asarray(position_enu, dtype=float), R, float(yaw_deg), float(pitch_deg), float(roll_deg), **kw)

    def to_json(self) -> dict:
        return {
            "position_enu": [float(v) for v in self.position_enu],
            "R_world_from_cam": [[float(v) for v in row] for row in self.R_world_from_cam],
            "yaw_deg": self.yaw_deg,
            "pitch_deg": self.pitch_deg,
            "roll_deg": self.roll_deg,
            "lat": self.lat,
            "lon": self.lon,
            "alt_amsl_m": self.alt_amsl_m,
            "velocity_enu_m_s": [float(v) for v in self.velocity_enu_m_s],
            "angular_rate_cam_rad_s": [float(v) for v in self.angular_rate_cam_rad_s],
        }

    @classmethod
    def from_json(cls, d: dict) -> TruePose:
        return cls(
            position_enu=np.asarray(d["position_enu"], dtype=float),
            R_world_from_cam=np.asarray(d["R_world_from_cam"], dtype=float),
            yaw_deg=float(d["yaw_deg"]),
            pitch_deg=float(d["pitch_deg"]),
            roll_deg=float(d["roll_deg"]),
            lat=float(d.get("lat", math.nan)),
            lon=float(d.get("lon", math.nan)),
            alt_amsl_m=float(d.get("alt_amsl_m", math.nan)),
            velocity_enu_m_s=np.asarray(d.get("velocity_enu_m_s", (0, 0, 0)), dtype=float),
            angular_rate_cam_rad_s=np.asarray(d.get("angular_rate_cam_rad_s", (0, 0, 0)), dtype=float),
        )


def project(K: np.ndarray, pose: TruePose, points_enu: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World points (N,3) -> pixel coordinates (N,2) and z-depth (N,). Points behind the camera get depth <= 0."""
    p = np.atleast_2d(np.asarray(points_enu, dtype=float))
    cam = (p - pose.position_enu) @ pose.R_world_from_cam  # rows: R^T (p - c)
    z = cam[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = (cam[:, :2] / z[:, None]) * np.array([K[0, 0], K[1, 1]]) + np.array([K[0, 2], K[1, 2]])
    return uv, z


def unproject(K: np.ndarray, pose: TruePose, uv: np.ndarray, depth: np.ndarray) -> np.ndarray:
    """Pixels (N,2) with z-depth (N,) -> world points (N,3)."""
    uv = np.atleast_2d(np.asarray(uv, dtype=float))
    rays = pixel_rays_cam(K, uv)
    cam = rays * np.asarray(depth, dtype=float).reshape(-1, 1)
    return cam @ pose.R_world_from_cam.T + pose.position_enu


def pixel_rays_cam(K: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Camera-frame ray directions with z = 1 (so a ray parameter t is the z-depth)."""
    uv = np.atleast_2d(np.asarray(uv, dtype=float))
    x = (uv[:, 0] - K[0, 2]) / K[0, 0]
    y = (uv[:, 1] - K[1, 2]) / K[1, 1]
    return np.column_stack([x, y, np.ones_like(x)])

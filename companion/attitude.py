"""Attitude maths, in one place for the planner, the gate, the stitcher and the simulator.

Conventions (docs/ARCHITECTURE.md, "The facade frame"): angles in degrees; yaw clockwise from north, pitch up
positive, roll right side down positive (aerospace ZYX Euler angles: yaw, then pitch, then roll about the new
forward axis). World vectors are ENU. Camera axes are OpenCV's: x right, y down, z forward (the optical axis).
Every function takes the angles by name in the order yaw, pitch, roll, which callers are asked to pass as keywords
where a mix-up would be silent.
"""

from __future__ import annotations

import math

import numpy as np


def camera_rotation_enu(yaw_deg: float, pitch_deg: float, roll_deg: float = 0.0) -> np.ndarray:
    """R_enu_from_cam: 3x3 rotation taking camera axes (x right, y down, z forward) to ENU vectors, for a camera
    looking along heading ``yaw_deg``, tilted up by ``pitch_deg`` and rolled by ``roll_deg``."""
    psi, th, phi = (math.radians(v) for v in (yaw_deg, pitch_deg, roll_deg))
    forward = np.array([math.sin(psi) * math.cos(th), math.cos(psi) * math.cos(th), math.sin(th)])
    right_level = np.array([math.cos(psi), -math.sin(psi), 0.0])
    down_level = _cross(forward, right_level)
    # roll turns the image clockwise as seen by the camera: the right axis tilts towards down
    right = math.cos(phi) * right_level + math.sin(phi) * down_level
    down = _cross(forward, right)
    return np.column_stack([right, down, forward])


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a x b of two 3-vectors, written out: ``np.cross`` costs about 0.1 ms a call in axis handling, and the
    onboard chain turns two poses into camera rotations on every frame (the tracker's telemetry prior)."""
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def angles_from_rotation(R_enu_from_cam: np.ndarray) -> tuple[float, float, float]:
    """Inverse of :func:`camera_rotation_enu`: (yaw, pitch, roll) in degrees, yaw in [0, 360)."""
    right, _, forward = (np.asarray(R_enu_from_cam, dtype=float)[:, i] for i in range(3))
    pitch = math.degrees(math.asin(max(-1.0, min(1.0, float(forward[2])))))
    yaw = math.degrees(math.atan2(float(forward[0]), float(forward[1]))) % 360.0
    psi = math.radians(yaw)
    right_level = np.array([math.cos(psi), -math.sin(psi), 0.0])
    down_level = np.cross(forward, right_level)
    roll = math.degrees(math.atan2(float(right @ down_level), float(right @ right_level)))
    return yaw, pitch, roll


def euler_to_quat(*, yaw_deg: float, pitch_deg: float, roll_deg: float) -> np.ndarray:
    """ZYX Euler angles -> unit quaternion (w, x, y, z) of the body-to-NED rotation (MAVLink's ``q``)."""
    r, p, y = (math.radians(v) / 2.0 for v in (roll_deg, pitch_deg, yaw_deg))
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    return np.array(
        [
            cr * cp * cy + sr * sp * sy,
            sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy,
        ]
    )


def quat_to_euler(q) -> tuple[float, float, float]:
    """Unit quaternion (w, x, y, z), body to NED -> (roll, pitch, yaw) in degrees, yaw in [0, 360).

    Returned roll-first, the order MAVLink's ATTITUDE message and mavsdk's EulerAngle use."""
    w, x, y, z = (float(v) for v in q)
    roll = math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2 * (w * y - z * x))))
    yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return math.degrees(roll), math.degrees(pitch), math.degrees(yaw) % 360.0


def slerp(q0: np.ndarray, q1: np.ndarray, t: float) -> np.ndarray:
    """Spherical interpolation between unit quaternions, the short way round."""
    dot = float(np.dot(q0, q1))
    if dot < 0.0:
        q1, dot = -q1, -dot
    if dot > 0.9995:
        q = q0 + t * (q1 - q0)
        return q / np.linalg.norm(q)
    theta = math.acos(dot)
    return (math.sin((1 - t) * theta) * q0 + math.sin(t * theta) * q1) / math.sin(theta)


def gimbal_camera_angles(
    vehicle_yaw_deg: float, gimbal_pitch_deg: float | None, gimbal_yaw_deg: float | None
) -> tuple[float, float, float]:
    """(yaw, pitch, roll) of a camera on a stabilised gimbal: heading = vehicle yaw + gimbal yaw (relative to the
    vehicle), pitch = gimbal pitch, no roll. An unknown (None) gimbal angle is taken as the planner's default,
    level and facing forward: the one place that assumption is made."""
    yaw = (vehicle_yaw_deg + (gimbal_yaw_deg or 0.0)) % 360.0
    return yaw, gimbal_pitch_deg or 0.0, 0.0

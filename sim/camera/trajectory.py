"""Fast kinematic flight along the planner's scan path: camera poses at the camera's frame rate without SITL.

The vehicle flies the scan waypoints in order with a trapezoidal speed profile (limited acceleration), holds
where the plan says, and wobbles a little like a real multirotor in light wind (smooth position, yaw and
attitude noise by seed). The gimbal is stabilised in pitch and roll (as on the paper's Mavic 2), so the camera
looks where the plan points it plus a small residual error.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from companion.attitude import camera_rotation_enu
from companion.errors import CompanionError
from companion.geo import FacadeFrame
from sim.camera.model import TruePose
from sim.camera.noise import value_noise


@dataclass(frozen=True)
class PathPoint:
    along_m: float
    out_m: float
    up_m: float
    yaw_deg: float
    speed_m_s: float  # speed of the leg arriving here
    hold_s: float = 0.0


@dataclass(frozen=True)
class Wobble:
    """Amplitudes of the flight's small random motion (1-sigma-ish), by seed."""

    position_m: float = 0.03
    yaw_deg: float = 0.4
    pitch_deg: float = 0.3
    roll_deg: float = 0.3
    period_s: float = 1.5


@dataclass(frozen=True)
class _Segment:
    t0: float
    p0: np.ndarray
    p1: np.ndarray
    yaw0: float
    yaw1: float
    duration: float
    v: float
    accel: float
    hold: bool


def scan_path(plan) -> list[PathPoint]:
    """The part of a companion.mission ScanPlan that the camera records: first to last scan waypoint."""
    if not plan.scan_legs:
        raise CompanionError("the plan has no scan legs", "check the mission: the planner produced no strips")
    i0, i1 = plan.scan_legs[0][0], plan.scan_legs[-1][1]
    return [
        PathPoint(w.along_m, w.out_m, w.up_m, w.yaw_deg, w.speed_m_s, getattr(w, "hold_s", 0.0))
        for w in plan.waypoints[i0 : i1 + 1]
    ]


class KinematicFlight:
    """Poses of the camera along a path at any time; ``duration_s`` is the time to fly the whole path."""

    def __init__(self, frame: FacadeFrame, path: list[PathPoint], *, gimbal_pitch_deg: float = 0.0,
                 accel_m_s2: float = 0.8, seed: int = 0, wobble: Wobble | None = None):
        if len(path) < 2:
            raise CompanionError("a flight path needs at least two points", "give the scan waypoints of a plan")
        if accel_m_s2 <= 0:
            raise CompanionError(f"accel_m_s2={accel_m_s2} must be positive", "use e.g. 0.8 m/s^2")
        self.frame = frame
        self.gimbal_pitch_deg = gimbal_pitch_deg
        self.seed = seed
        self.wobble = wobble if wobble is not None else Wobble()
        self.segments: list[_Segment] = []
        t = 0.0
        for a, b in zip(path[:-1], path[1:], strict=True):
            p0 = np.array([a.along_m, a.out_m, a.up_m])
            p1 = np.array([b.along_m, b.out_m, b.up_m])
            if a.hold_s > 0:
                self.segments.append(_Segment(t, p0, p0, a.yaw_deg, a.yaw_deg, a.hold_s, 0.0, accel_m_s2, True))
                t += a.hold_s
            d = float(np.linalg.norm(p1 - p0))
            v = max(b.speed_m_s, 0.05)
            if d < 1e-9:
                continue
            dur = d / v + v / accel_m_s2 if d >= v * v / accel_m_s2 else 2 * math.sqrt(d / accel_m_s2)
            self.segments.append(_Segment(t, p0, p1, a.yaw_deg, b.yaw_deg, dur, v, accel_m_s2, False))
            t += dur
        self.duration_s = t
        self._starts = np.array([s.t0 for s in self.segments])

    def _nominal(self, t: float) -> tuple[np.ndarray, np.ndarray, float]:
        """Position, velocity (facade coords) and yaw on the path without wobble."""
        t = min(max(t, 0.0), self.duration_s)
        k = int(np.searchsorted(self._starts, t, side="right") - 1)
        s = self.segments[max(k, 0)]
        tau = min(t - s.t0, s.duration)
        if s.hold:
            return s.p0.copy(), np.zeros(3), s.yaw0
        d = float(np.linalg.norm(s.p1 - s.p0))
        a, v = s.accel, s.v
        if d >= v * v / a:  # trapezoid
            ta = v / a
            if tau < ta:
                dist, speed = 0.5 * a * tau * tau, a * tau
            elif tau < s.duration - ta:
                dist, speed = 0.5 * a * ta * ta + v * (tau - ta), v
            else:
                r = s.duration - tau
                dist, speed = d - 0.5 * a * r * r, a * r
        else:  # triangle
            th = s.duration / 2
            if tau < th:
                dist, speed = 0.5 * a * tau * tau, a * tau
            else:
                r = s.duration - tau
                dist, speed = d - 0.5 * a * r * r, a * r
        u = (s.p1 - s.p0) / d
        frac = dist / d
        dyaw = (s.yaw1 - s.yaw0 + 180.0) % 360.0 - 180.0
        return s.p0 + u * dist, u * speed, s.yaw0 + dyaw * frac

    def _noise(self, t: float, channel: int) -> float:
        w = self.wobble
        return float(value_noise(np.array([t]), np.array([channel * 17.0]), w.period_s, self.seed * 131 + 5)[0]) * 2 - 1

    def _attitude(self, t: float) -> tuple[np.ndarray, np.ndarray, float, float, float]:
        w = self.wobble
        p, v, yaw = self._nominal(t)
        p = p + w.position_m * np.array([self._noise(t, 0), self._noise(t, 1), self._noise(t, 2)])
        yaw = (yaw + w.yaw_deg * self._noise(t, 3)) % 360.0
        pitch = self.gimbal_pitch_deg + w.pitch_deg * self._noise(t, 4)
        roll = w.roll_deg * self._noise(t, 5)
        return p, v, yaw, pitch, roll

    def pose(self, t: float) -> TruePose:
        """The camera's true pose at flight time ``t`` seconds."""
        p, _, yaw, pitch, roll = self._attitude(t)
        h = 1e-3
        p2, _, yaw2, pitch2, roll2 = self._attitude(t + h)
        vel_f = (p2 - p) / h
        R = camera_rotation_enu(yaw_deg=yaw, pitch_deg=pitch, roll_deg=roll)
        R2 = camera_rotation_enu(yaw_deg=yaw2, pitch_deg=pitch2, roll_deg=roll2)
        W = (R2 @ R.T - np.eye(3)) / h  # skew matrix of the world angular velocity
        w_world = np.array([W[2, 1], W[0, 2], W[1, 0]])
        e, n, u = self.frame.facade_to_enu(*p)
        ve, vn, vu = self.frame.facade_to_enu(vel_f[0], vel_f[1], 0.0)
        lat, lon, alt = self.frame.facade_to_geodetic(*p)
        return TruePose(
            position_enu=np.array([float(e), float(n), float(u)]),
            R_world_from_cam=R,
            yaw_deg=float(yaw),
            pitch_deg=float(pitch),
            roll_deg=float(roll),
            lat=float(lat),
            lon=float(lon),
            alt_amsl_m=float(alt),
            velocity_enu_m_s=np.array([float(ve), float(vn), float(vel_f[2])]),
            angular_rate_cam_rad_s=R.T @ w_world,
        )

    def times(self, fps: float, *, stride: int = 1, max_frames: int | None = None) -> Iterator[tuple[int, float]]:
        """(camera frame number, time) of every ``stride``-th frame at ``fps`` along the flight."""
        if fps <= 0 or stride < 1:
            raise CompanionError(f"fps={fps}, stride={stride} are invalid", "use fps > 0 and stride >= 1")
        n_total = int(math.floor(self.duration_s * fps)) + 1
        ks = range(0, n_total, stride)
        if max_frames is not None:
            ks = ks[:max_frames]
        for k in ks:
            yield k, k / fps

"""Multirotor point-mass model with a cascaded guidance/velocity controller.

Why this shape: the facade scan cares about how well the vehicle holds the straight line between waypoints
(standoff error), so the model is a point mass with the limits a real multirotor position controller enforces
(horizontal speed, climb/descent rate, acceleration, yaw rate) and a cross-track term like PX4's line following.
Positions are local NED metres from home; all functions are pure apart from ``Multirotor.step``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

GRAVITY = 9.80665


@dataclass(frozen=True)
class Limits:
    """Flight envelope and controller gains (defaults: PX4 multicopter defaults, e.g. MPC_XY_P, MPC_XY_VEL_*)."""

    max_speed_h_m_s: float = 12.0
    max_climb_m_s: float = 3.0
    max_descent_m_s: float = 1.5
    max_accel_m_s2: float = 4.0
    max_yaw_rate_deg_s: float = 60.0
    cross_track_gain: float = 1.0  # 1/s: velocity towards the line per metre off it (MPC_XY_P ~ 0.95)
    hold_gain: float = 1.0  # 1/s: velocity towards a hold point per metre away
    vel_gain_xy: float = 1.8  # 1/s: MPC_XY_VEL_P_ACC
    vel_int_xy: float = 0.4  # 1/s^2: MPC_XY_VEL_I_ACC (cancels drag and steady wind)
    vel_gain_z: float = 4.0  # MPC_Z_VEL_P_ACC
    vel_int_z: float = 2.0  # MPC_Z_VEL_I_ACC
    tilt_lag_s: float = 0.15  # attitude loop: thrust direction follows the command with this time constant
    drag_per_m: float = 0.05  # 1/m: quadratic air drag, a = -k |v_air| v_air (about 1.25 m/s^2 at 5 m/s)


@dataclass
class VehicleState:
    pos: np.ndarray = field(default_factory=lambda: np.zeros(3))  # NED metres from home
    vel: np.ndarray = field(default_factory=lambda: np.zeros(3))  # NED m/s
    yaw_deg: float = 0.0  # clockwise from north
    roll_deg: float = 0.0
    pitch_deg: float = 0.0
    on_ground: bool = True


def limit_velocity(v: np.ndarray, limits: Limits, cruise_m_s: float | None = None) -> np.ndarray:
    """Scale ``v`` uniformly (keeps the direction, so the vehicle stays on its line) into the envelope."""
    v = np.asarray(v, dtype=float)
    max_h = limits.max_speed_h_m_s if cruise_m_s is None else min(cruise_m_s, limits.max_speed_h_m_s)
    scale = 1.0
    vh = math.hypot(v[0], v[1])
    if vh > max_h:
        scale = min(scale, max_h / vh)
    if v[2] < 0 and -v[2] > limits.max_climb_m_s:
        scale = min(scale, limits.max_climb_m_s / -v[2])
    if v[2] > 0 and v[2] > limits.max_descent_m_s:
        scale = min(scale, limits.max_descent_m_s / v[2])
    return v * scale


def _path_speed_limit(u: np.ndarray, limits: Limits, cruise_m_s: float) -> float:
    """Fastest speed along unit direction ``u``: the cruise speed limits the horizontal part only, the climb and
    descent limits the vertical part (as both PX4 and ArduCopter apply their speeds), so a vertical leg flies at the
    climb/descent speed whatever the cruise speed."""
    s = math.inf
    uh = math.hypot(u[0], u[1])
    if uh > 1e-9:
        s = min(s, min(cruise_m_s, limits.max_speed_h_m_s) / uh)
    if u[2] < -1e-9:
        s = min(s, limits.max_climb_m_s / -u[2])
    if u[2] > 1e-9:
        s = min(s, limits.max_descent_m_s / u[2])
    return s


def track_line(pos, a, b, cruise_m_s: float, limits: Limits) -> np.ndarray:
    """Velocity command that flies the straight line a->b, pulling back onto it (cross-track) and braking so the
    vehicle could stop at b."""
    pos, a, b = (np.asarray(x, dtype=float) for x in (pos, a, b))
    d = b - a
    length = float(np.linalg.norm(d))
    if length < 1e-6:
        return hold_point(pos, b, limits, cruise_m_s)
    u = d / length
    s = float(np.dot(pos - a, u))
    closest = a + min(max(s, 0.0), length) * u
    cross = pos - closest
    to_go = max(length - s, 0.0)
    brake = 0.5 * limits.max_accel_m_s2
    speed = min(_path_speed_limit(u, limits, cruise_m_s), math.sqrt(2.0 * brake * to_go))
    if s > length:  # overshot: come back to b
        return hold_point(pos, b, limits, cruise_m_s)
    v = speed * u - limits.cross_track_gain * cross
    return limit_velocity(v, limits, cruise_m_s)


def hold_point(pos, target, limits: Limits, cruise_m_s: float | None = None) -> np.ndarray:
    """Velocity command that brings the vehicle to ``target`` and keeps it there."""
    err = np.asarray(target, dtype=float) - np.asarray(pos, dtype=float)
    dist = float(np.linalg.norm(err))
    if dist < 1e-9:
        return np.zeros(3)
    # P control, but never faster than a speed we can brake from before the target.
    speed = min(limits.hold_gain * dist, math.sqrt(limits.max_accel_m_s2 * dist))
    return limit_velocity(err / dist * speed, limits, cruise_m_s)


def wrap_deg(angle: float) -> float:
    """Angle in (-180, 180]."""
    a = (angle + 180.0) % 360.0 - 180.0
    return 180.0 if a == -180.0 else a


class Multirotor:
    """Integrates the point mass under a velocity command, wind and the acceleration/yaw-rate limits."""

    def __init__(self, limits: Limits | None = None, state: VehicleState | None = None):
        self.limits = limits or Limits()
        self.state = state or VehicleState()
        self._vel_int = np.zeros(3)
        self._v_cmd_prev: np.ndarray | None = None
        self.thrust_accel = np.zeros(3)  # acceleration the tilted thrust delivers (lags the command)
        lim = self.limits
        self._kp = np.array([lim.vel_gain_xy, lim.vel_gain_xy, lim.vel_gain_z])
        self._ki = np.array([lim.vel_int_xy, lim.vel_int_xy, lim.vel_int_z])

    def _reset_on_ground(self) -> None:
        st = self.state
        st.vel[:] = 0.0
        self._vel_int[:] = 0.0
        self.thrust_accel[:] = 0.0
        self._v_cmd_prev = None
        st.roll_deg = st.pitch_deg = 0.0

    def step(self, dt: float, v_cmd, yaw_target_deg: float | None, wind_ned=(0.0, 0.0, 0.0), motors_on=True):
        """Advance ``dt`` seconds. With motors off (disarmed) or no climb command the vehicle sits on the ground."""
        st, lim = self.state, self.limits
        v_cmd = np.asarray(v_cmd, dtype=float)
        if not motors_on or (st.on_ground and v_cmd[2] >= 0.0):
            self._reset_on_ground()
            return
        wind = np.asarray(wind_ned, dtype=float)
        err = v_cmd - st.vel
        # PI velocity controller; the integral (bounded: anti-windup) supplies the drag and wind compensation.
        self._vel_int = np.clip(self._vel_int + err * dt, -lim.max_accel_m_s2 / np.maximum(self._ki, 1e-6),
                                lim.max_accel_m_s2 / np.maximum(self._ki, 1e-6))
        # Feed-forward of the setpoint's own acceleration, as PX4's trajectory generator provides.
        ff = np.zeros(3) if self._v_cmd_prev is None or dt <= 0 else (v_cmd - self._v_cmd_prev) / dt
        self._v_cmd_prev = v_cmd.copy()
        a_cmd = self._kp * err + self._ki * self._vel_int + np.clip(ff, -lim.max_accel_m_s2, lim.max_accel_m_s2)
        norm = float(np.linalg.norm(a_cmd))
        if norm > lim.max_accel_m_s2:
            a_cmd *= lim.max_accel_m_s2 / norm
        alpha = dt / (lim.tilt_lag_s + dt) if lim.tilt_lag_s > 0 else 1.0
        self.thrust_accel = self.thrust_accel + alpha * (a_cmd - self.thrust_accel)
        v_air = st.vel - wind
        accel = self.thrust_accel - lim.drag_per_m * float(np.linalg.norm(v_air)) * v_air
        st.vel = st.vel + accel * dt
        st.pos = st.pos + st.vel * dt
        st.on_ground = False
        if st.pos[2] >= 0.0 and st.vel[2] >= 0.0:  # touched the ground (down positive)
            st.pos[2] = 0.0
            st.on_ground = True
            self._reset_on_ground()
        # Tilt follows the thrust needed for the horizontal acceleration it delivers.
        yaw = math.radians(st.yaw_deg)
        a = self.thrust_accel
        a_fwd = a[0] * math.cos(yaw) + a[1] * math.sin(yaw)
        a_right = -a[0] * math.sin(yaw) + a[1] * math.cos(yaw)
        st.pitch_deg = -math.degrees(math.atan2(a_fwd, GRAVITY))
        st.roll_deg = math.degrees(math.atan2(a_right, GRAVITY))
        if yaw_target_deg is not None and math.isfinite(yaw_target_deg):
            diff = wrap_deg(yaw_target_deg - st.yaw_deg)
            max_step = lim.max_yaw_rate_deg_s * dt
            st.yaw_deg = (st.yaw_deg + max(-max_step, min(max_step, diff))) % 360.0

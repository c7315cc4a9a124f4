"""Guidance tasks: what the vehicle is doing right now (hold, climb, fly a line, land, return home).

Modes and mission items are both built from these, so takeoff, RTL and land behave the same whether they were
commanded directly or reached in a mission. Each task turns the navigation position into a velocity command.
"""

from __future__ import annotations

import math

import numpy as np

from sim.vehicle.model import hold_point, track_line, wrap_deg


class Task:
    done = False
    reached = False  # for waypoints: position (and heading) reached, hold may still be running
    yaw_deg: float | None = None

    def command(self, nav: np.ndarray, on_ground: bool, dt: float, ctx) -> np.ndarray:
        raise NotImplementedError


class Hold(Task):
    def __init__(self, point, yaw_deg: float | None = None):
        self.point = np.array(point, dtype=float)
        self.yaw_deg = yaw_deg

    def command(self, nav, on_ground, dt, ctx):
        if on_ground:
            return np.zeros(3)
        return hold_point(nav, self.point, ctx.limits, ctx.cruise_m_s)


class Climb(Task):
    """Vertical climb (takeoff) to ``down_m`` over the xy where it started."""

    def __init__(self, point_xy, down_m: float, yaw_deg: float | None = None, tolerance_m: float = 0.3):
        self.point = np.array([point_xy[0], point_xy[1], down_m], dtype=float)
        self.yaw_deg = yaw_deg
        self.tolerance_m = tolerance_m

    def command(self, nav, on_ground, dt, ctx):
        if abs(nav[2] - self.point[2]) < self.tolerance_m:
            self.done = self.reached = True
        return hold_point(nav, self.point, ctx.limits, ctx.cruise_m_s)


class Line(Task):
    """Fly the straight line a->b; reached inside ``radius`` with the heading within 10 degrees, done after hold.

    ``alt_radius_m``: reached when within ``radius`` horizontally and ``alt_radius_m`` vertically, as PX4 accepts a
    multicopter waypoint (``MissionBlock::is_mission_item_reached``: acceptance radius in xy, NAV_MC_ALT_RAD in z);
    None: inside ``radius`` in 3D."""

    def __init__(self, a, b, radius_m: float, hold_s: float = 0.0, yaw_deg: float | None = None,
                 alt_radius_m: float | None = None):
        self.a = np.array(a, dtype=float)
        self.b = np.array(b, dtype=float)
        self.radius_m = radius_m
        self.alt_radius_m = alt_radius_m
        self.hold_s = hold_s
        self.yaw_deg = yaw_deg
        self._held = 0.0

    def _inside(self, nav) -> bool:
        if self.alt_radius_m is None:
            return float(np.linalg.norm(nav - self.b)) <= self.radius_m
        return (float(np.linalg.norm(nav[:2] - self.b[:2])) <= self.radius_m
                and abs(float(nav[2] - self.b[2])) <= self.alt_radius_m)

    def command(self, nav, on_ground, dt, ctx):
        if not self.reached and self._inside(nav):
            heading_ok = self.yaw_deg is None or abs(wrap_deg(self.yaw_deg - ctx.yaw_deg)) < 10.0
            self.reached = heading_ok
        if self.reached:
            self._held += dt
            if self._held >= self.hold_s:
                self.done = True
            return hold_point(nav, self.b, ctx.limits, ctx.cruise_m_s)
        # climb/descent at the autopilot's current auto speeds (a context without them: the envelope's)
        return track_line(nav, self.a, self.b, ctx.cruise_m_s, getattr(ctx, "auto_limits", ctx.limits))


class Land(Task):
    """Go over ``xy`` (if given) at the current height, then descend at the land speed until touchdown."""

    def __init__(self, xy=None, yaw_deg: float | None = None):
        self.xy = None if xy is None else np.array(xy, dtype=float)
        self.yaw_deg = yaw_deg
        self._approach: Line | None = None

    def command(self, nav, on_ground, dt, ctx):
        if on_ground:
            self.done = self.reached = True
            return np.zeros(3)
        if self.xy is None:
            self.xy = nav[:2].copy()
        if self._approach is None and math.hypot(*(nav[:2] - self.xy)) > 1.0:
            self._approach = Line(nav, [self.xy[0], self.xy[1], nav[2]], radius_m=0.5)
        if self._approach is not None and not self._approach.done:
            return self._approach.command(nav, on_ground, dt, ctx)
        v = np.zeros(3)
        v[:2] = (self.xy - nav[:2]) * ctx.limits.hold_gain
        height = -nav[2]
        v[2] = ctx.land_speed_m_s if height < 5.0 else ctx.limits.max_descent_m_s
        return v


class ReturnHome(Task):
    """Climb to the return height, fly home on a straight line, land."""

    def __init__(self, nav, return_alt_m: float):
        self.return_down = min(float(nav[2]), -return_alt_m)
        self._phase: Task = Climb(nav[:2], self.return_down)
        self._stage = "climb"
        self.yaw_deg = None

    def command(self, nav, on_ground, dt, ctx):
        if self._stage == "climb" and self._phase.done:
            far = math.hypot(nav[0], nav[1]) > 1.0
            self._stage = "return" if far else "land"
            self._phase = Line(nav, [0.0, 0.0, self.return_down], radius_m=1.0) if far else Land([0.0, 0.0])
            if far:
                self.yaw_deg = math.degrees(math.atan2(-nav[1], -nav[0])) % 360.0
        elif self._stage == "return" and self._phase.done:
            self._stage = "land"
            self._phase = Land([0.0, 0.0])
        v = self._phase.command(nav, on_ground, dt, ctx)
        if self._stage == "land" and self._phase.done:
            self.done = self.reached = True
        return v

"""ArduCopter's heading in AUTO, as ArduCopter 4.7 (2598e9d4) decides it (mode_auto.cpp, autoyaw.cpp).

Copter ignores NAV_WAYPOINT param4. Its ``auto_yaw`` has a mode:
  * at every new waypoint (``ModeAuto::wp_start``) the mode is reset to the WP_YAW_BEHAVIOR default (0 HOLD,
    1 LOOK_AT_NEXT_WP, 2 LOOK_AT_NEXT_WP except RTL, 3 LOOK_AHEAD), unless it is ROI, or FIXED with
    WP_YAW_BEHAVIOR = 0;
  * CONDITION_YAW sets FIXED at an absolute or relative heading; while it is the active do-command its verify
    (``verify_yaw``) re-asserts FIXED every loop, until the heading is within 2 degrees of the target;
  * LOOK_AT_NEXT_WP points along the leg's horizontal direction (unchanged on a purely vertical leg);
    LOOK_AHEAD along the horizontal velocity when faster than 1 m/s; HOLD keeps the heading;
  * takeoff and land hold the heading.
With the default WP_YAW_BEHAVIOR = 2 a scan of vertical strips joined by sideways hops therefore faces along the
wall, 90 degrees off, which is what real ArduCopter did with our first missions.
"""

from __future__ import annotations

import math

from sim.vehicle.model import wrap_deg

HOLD, LOOK_AT_NEXT_WP, FIXED, LOOK_AHEAD = "hold", "look_at_next_wp", "fixed", "look_ahead"
LOOK_AHEAD_MIN_SPEED_M_S = 1.0  # YAW_LOOK_AHEAD_MIN_SPEED (100 cm/s)
FIXED_REACHED_DEG = 2.0  # reached_fixed_yaw_target


def default_mode(wp_yaw_behavior: int, rtl: bool = False) -> str:
    if wp_yaw_behavior == 0:
        return HOLD
    if wp_yaw_behavior == 2:
        return HOLD if rtl else LOOK_AT_NEXT_WP
    if wp_yaw_behavior == 3:
        return LOOK_AHEAD
    return LOOK_AT_NEXT_WP


class CopterAutoYaw:
    """The heading state of Copter's AUTO mode; ``target(...)`` gives the heading to steer to (None: keep)."""

    def __init__(self) -> None:
        self.mode = HOLD
        self.fixed_deg: float | None = None
        self.condition_active = False  # a CONDITION_YAW is the active do-command (not yet verified)
        self.leg_bearing_deg: float | None = None

    def wp_start(self, wp_yaw_behavior: int, leg_north_east: tuple[float, float]) -> None:
        """A new NAV_WAYPOINT starts; ``leg_north_east`` is its horizontal displacement."""
        if not (self.mode == FIXED and wp_yaw_behavior == 0):
            self.mode = default_mode(wp_yaw_behavior)
        north, east = leg_north_east
        if math.hypot(north, east) > 0.05:
            self.leg_bearing_deg = math.degrees(math.atan2(east, north)) % 360.0

    def hold(self) -> None:
        """Takeoff and land hold the heading."""
        self.mode = HOLD

    def condition_yaw(self, angle_deg: float, direction: float, relative: float, yaw_now_deg: float) -> None:
        if not math.isfinite(angle_deg):
            return
        if relative:
            base = self.fixed_deg if self.mode == FIXED and self.fixed_deg is not None else yaw_now_deg
            self.fixed_deg = (base + (angle_deg if direction >= 0 else -angle_deg)) % 360.0
        else:
            self.fixed_deg = angle_deg % 360.0
        self.mode = FIXED
        self.condition_active = True

    def target(self, yaw_now_deg: float, vel_north_east: tuple[float, float]) -> float | None:
        if self.condition_active:
            self.mode = FIXED  # verify_yaw re-asserts FIXED while the CONDITION_YAW is active
            if self.fixed_deg is None or abs(wrap_deg(self.fixed_deg - yaw_now_deg)) <= FIXED_REACHED_DEG:
                self.condition_active = False
        if self.mode == FIXED:
            return self.fixed_deg
        if self.mode == LOOK_AT_NEXT_WP:
            return self.leg_bearing_deg
        if self.mode == LOOK_AHEAD:
            vn, ve = vel_north_east
            if math.hypot(vn, ve) > LOOK_AHEAD_MIN_SPEED_M_S:
                return math.degrees(math.atan2(ve, vn)) % 360.0
        return None

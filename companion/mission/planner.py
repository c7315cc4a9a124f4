"""Constant-standoff facade scan planner: camera footprint -> strips -> waypoints -> MAVLink mission items."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np
import pymap3d

from companion.errors import CompanionError
from companion.geo import FacadeFrame, GeoPoint
from companion.mission import items as mi
from companion.mission.autopilot import DEFAULT_FLAVOUR, Autopilot, autopilot_for
from companion.mission.autopilot.px4 import PX4_HOME_MOVE_MAX_M, PX4_MAX_CLIMB_M_S
from companion.mission.geometry import footprint_enu, polyline_clearance, wall_frame
from companion.mission.keyframe_count import PathPoint, ScanView, expected_keyframes
from companion.mission.spec import Mission

# Nominal multirotor dynamics for the time estimate (a typical 1-2 kg inspection quad).
NOMINAL_ACCEL_M_S2 = 1.5
NOMINAL_CLIMB_M_S = 2.0
NOMINAL_LAND_M_S = 0.7
SCAN_ACCEPTANCE_M = 0.3
TRANSIT_ACCEPTANCE_M = 1.0
SCAN_START_HOLD_S = 0.5  # let the vehicle settle at the standoff before each strip
STANDOFF_TOLERANCE_M = 0.05
# The lowest a waypoint may come to the take-off ground after the autopilot moved home: 1 m keeps the rotor wash, the
# altitude estimate's wander (PX4 SIH: 0.5 m white GPS altitude noise) and a landing-gear height clear. The PX4 plan
# keeps it in PX4's home correction window whatever home does (``PX4_HOME_MOVE_MAX_M`` more), the flight's home watch
# after it (``companion.flight.home_watch``).
MIN_GROUND_CLEARANCE_M = 1.0
# The bottom band flown after PX4's window overlaps the lowest frames of the strips flown in it by at least this
# share of a frame's height (more rows when one is not enough).
BAND_MIN_OVERLAP = 1.0 / 3.0


@dataclass(frozen=True)
class Footprint:
    """What the camera sees on the wall plane at the standoff, and at what resolution."""

    width_m: float
    height_m: float
    gsd_mm_per_px: float


@dataclass(frozen=True)
class WallRegion:
    """A rectangle on the wall plane in facade metres (along from the wall start, up from the wall base)."""

    along_min_m: float
    along_max_m: float
    up_min_m: float
    up_max_m: float


# The plan's positions to 1e-8 degree (about 1 mm) and its heights to the mm: finer is below any autopilot's
# resolution (MISSION_ITEM_INT: 1e-7 deg), and the geodesy's float noise (37.56649999999999) would show in every
# exported text.
DEG_DECIMALS = 8
M_DECIMALS = 3


@dataclass(frozen=True)
class Waypoint:
    along_m: float
    out_m: float
    up_m: float
    lat: float
    lon: float
    alt_amsl_m: float
    rel_alt_m: float
    yaw_deg: float
    speed_m_s: float  # speed of the leg arriving at this waypoint
    kind: str  # 'takeoff' | 'transit' | 'scan' | 'land'
    hold_s: float = 0.0
    acceptance_m: float = SCAN_ACCEPTANCE_M


@dataclass(frozen=True)
class PlanEstimates:
    path_length_m: float
    flight_time_s: float
    scan_speed_m_s: float
    speed_limited_by: str
    keyframe_spacing_m: float
    expected_keyframes: int
    frames_per_keyframe: float
    motion_blur_px: float
    gsd_mm_per_px: float
    footprint_width_m: float
    footprint_height_m: float
    strips: int
    strip_spacing_m: float
    side_overlap_achieved: float
    uncovered_bottom_m: float
    # PX4 only (PX4 moves home's altitude, and every waypoint with it, for 120 s after take-off): what the plan flies
    # in that window is at least ``px4_window_floor_m`` above home (home's largest move + 1 m); the part below it
    # starts no earlier than ``px4_low_after_s`` after take-off (the fastest PX4 can get there, holding
    # ``px4_home_settle_hold_s`` before it when the part above is flown sooner than ``margins.home_settle_s`` + slack)
    px4_home_settle_hold_s: float = 0.0
    px4_window_floor_m: float = 0.0
    px4_low_after_s: float = 0.0
    px4_bottom_band_rows: int = 0  # horizontal passes flown after the window for the strips' bottoms

    def as_dict(self) -> dict:
        return {k: (round(v, 4) if isinstance(v, float) else v) for k, v in self.__dict__.items()}


@dataclass(frozen=True)
class ScanPlan:
    mission: Mission
    frame: FacadeFrame
    home: GeoPoint
    waypoints: list[Waypoint]
    scan_legs: list[tuple[int, int]]
    footprint: Footprint
    estimates: PlanEstimates
    warnings: list[str] = field(default_factory=list)
    # planned for an autopilot that moves home in flight (PX4): the part below ``estimates.px4_window_floor_m`` is
    # flown after its correction window; ``steady_home`` is the plan for one that keeps home where it armed
    # (ArduPilot), None when the two are the same plan (``margins.home_settle_s`` 0)
    moving_home: bool = False
    steady_home: ScanPlan | None = None

    @property
    def wall_length_m(self) -> float:
        return self.frame.length_m

    def mavlink_items(self, flavour: str | Autopilot = DEFAULT_FLAVOUR) -> list[mi.MissionItem]:
        return build_mission_items(self, flavour)

    def for_autopilot(self, flavour: str | Autopilot) -> ScanPlan:
        """The plan to fly on ``flavour``: PX4 (which moves home for 120 s after take-off) flies the part near the
        ground after that window; ArduPilot keeps home where it armed and flies the strips in their plain order."""
        ap = autopilot_for(flavour)
        if ap.home_correction_window_s <= 0:
            return self.steady_home if self.steady_home is not None else self
        if self.moving_home or self.mission.margins.home_settle_s <= 0:
            return self
        raise CompanionError(f"this plan is for an autopilot that keeps home where it armed, not for {ap.label}, "
                             f"which moves home in flight", "fly the plan plan_scan() returned on it")

    @property
    def settle_waypoint_index(self) -> int:
        """The last waypoint a PX4 flight flies while its home may still move: the last one before the first
        below ``estimates.px4_window_floor_m`` (it holds there when the part above ends before the window); -1 when
        the whole flight stays above it."""
        if self.moving_home:
            return settle_waypoint_index(self.waypoints, self.estimates.px4_window_floor_m)
        return settle_waypoint_index(self.waypoints)


def camera_footprint(mission: Mission) -> Footprint:
    cam = mission.camera
    width = 2.0 * mission.standoff_m * math.tan(math.radians(cam.hfov_deg) / 2.0)
    height = width * cam.height_px / cam.width_px
    return Footprint(width_m=width, height_m=height, gsd_mm_per_px=1000.0 * width / cam.width_px)


def effective_fps(mission: Mission) -> float:
    """Frames per second that reach the gate: the camera's, or fewer if the companion processes fewer."""
    if mission.onboard_fps is None:
        return mission.camera.fps
    return min(mission.camera.fps, mission.onboard_fps)


def _scan_speed(mission: Mission, fp: Footprint, spacing_m: float) -> tuple[float, str]:
    """Fastest speed that keeps enough frames per keyframe, blur within budget, and under max speed."""
    fps = effective_fps(mission)
    limits = {
        "frames per keyframe": fps * spacing_m / mission.min_frames_per_keyframe,
        "motion blur": mission.motion_blur_budget_px * (fp.gsd_mm_per_px / 1000.0) / mission.camera.exposure_s,
        "max speed": mission.max_speed_m_s,
    }
    reason = min(limits, key=limits.get)
    return limits[reason], reason


def _spread(lo: float, hi: float, size: float, max_step: float) -> list[float]:
    """Centres of frames of extent ``size`` covering [lo, hi] with steps no larger than ``max_step``."""
    first, last = lo + size / 2.0, hi - size / 2.0
    if last <= first:
        return [(lo + hi) / 2.0]
    n = math.ceil((last - first) / max_step - 1e-9) + 1
    return [float(v) for v in np.linspace(first, last, n)]


def scan_extent(mission: Mission, wall_length_m: float) -> WallRegion:
    """The part of the wall plane a scan can show: the wall plus ``margins.ends_m`` past each end and
    ``margins.roof_m`` above the roof, from the lowest frame edge the bottom clearance allows."""
    mg = mission.margins
    fp = camera_footprint(mission)
    bottom_edge = max(mg.bottom_clearance_m, fp.height_m / 2.0) - fp.height_m / 2.0
    top = max(mission.facade.height_m + mg.roof_m, bottom_edge + fp.height_m)
    return WallRegion(-mg.ends_m, wall_length_m + mg.ends_m, bottom_edge, top)


def _strips(
    m: Mission, fp: Footprint, kf_spacing: float, low_centre: float, regions: list[WallRegion]
) -> tuple[list[tuple[tuple[float, float], tuple[float, float]]], float]:
    """Strips (start, end) as (along, up) frame centres covering each region, regions in order along the wall;
    and the widest spacing between neighbouring strips of one region (0 when no region has two).

    Frame edges reach each region's edges; a region smaller than a footprint gets one frame centred on it (never
    below the lowest frame centre). The boustrophedon continues across regions so each strip starts near where
    the previous one ended; vertical strips start from the top (the vehicle arrives from above).
    """
    strips: list[tuple[tuple[float, float], tuple[float, float]]] = []
    widest = 0.0
    for r in sorted(regions, key=lambda r: (r.along_min_m + r.along_max_m) / 2.0):
        u0, u1 = r.up_min_m, r.up_max_m
        if u1 - u0 < fp.height_m:  # one frame high: centred, but not below the lowest centre
            centre = max((u0 + u1) / 2.0, low_centre)
            u0, u1 = centre - fp.height_m / 2.0, centre + fp.height_m / 2.0
        if m.pattern == "vertical":
            columns = _spread(r.along_min_m, r.along_max_m, fp.width_m, fp.width_m * (1.0 - m.side_overlap))
            rows_span = _spread(u0, u1, fp.height_m, kf_spacing)
            z_lo, z_hi = rows_span[0], rows_span[-1]
            if len(rows_span) == 1 and len(columns) > 1:  # one frame high: a single pass along it, not point strips
                strips.append(_nearest_first(strips, (columns[0], z_lo), (columns[-1], z_lo)))
                continue
            for a in columns:
                zs = (z_hi, z_lo) if len(strips) % 2 == 0 else (z_lo, z_hi)
                strips.append(((a, zs[0]), (a, zs[1])))
            steps = np.diff(columns)
        else:
            rows = _spread(u0, u1, fp.height_m, fp.height_m * (1.0 - m.side_overlap))
            cols_span = _spread(r.along_min_m, r.along_max_m, fp.width_m, kf_spacing)
            a_lo, a_hi = cols_span[0], cols_span[-1]
            if len(cols_span) == 1 and len(rows) > 1:  # one frame wide: a single pass down it, not point strips
                strips.append(_nearest_first(strips, (a_lo, rows[-1]), (a_lo, rows[0])))
                continue
            for z in reversed(rows):  # top row first
                xs = (a_lo, a_hi) if len(strips) % 2 == 0 else (a_hi, a_lo)
                strips.append(((xs[0], z), (xs[1], z)))
            steps = np.diff(rows)
        widest = max(widest, float(np.max(steps)) if len(steps) else 0.0)
    return strips, widest


def _nearest_first(strips: list, p: tuple[float, float], q: tuple[float, float]) -> tuple:
    """The strip p-q, started from whichever end is nearer where the previous strip ended (p when first)."""
    if strips and math.dist(strips[-1][1], q) < math.dist(strips[-1][1], p):
        return (q, p)
    return (p, q)


@dataclass(frozen=True)
class _Takeoff:
    """Where the vehicle takes off and lands, in the facade frame, and the altitude shift to heights above it."""

    home: GeoPoint
    along_m: float
    out_m: float
    up_to_rel_m: float  # add to a facade up_m to get the altitude above home (mission altitudes are relative to it)


def _takeoff_point(m: Mission, frame: FacadeFrame) -> _Takeoff:
    """Home is the takeoff point on the ground: the mission's, checked to be on the drone's side at least the
    standoff out, or by default mid-wall 6 m beyond the standoff."""
    d = m.standoff_m
    if m.takeoff is not None:
        home_alt = (
            m.takeoff.ground_alt_amsl_m if m.takeoff.ground_alt_amsl_m is not None else m.facade.ground_alt_amsl_m
        )
        home = GeoPoint(m.takeoff.lat, m.takeoff.lon, home_alt)
        ta, to, _ = frame.geodetic_to_facade(home.lat, home.lon, frame.origin.alt_amsl_m)
        ta, to = float(ta), float(to)
        if to < d - STANDOFF_TOLERANCE_M:
            side = "behind the wall (inside the building side)" if to < 0 else f"only {to:.1f} m from the wall"
            raise CompanionError(
                f"the takeoff point is {side}; it must be on the drone's side at least standoff_m={d} m out",
                "move takeoff further out on the drone's side (see the side convention in docs/ARCHITECTURE.md)",
            )
    else:
        ta, to = frame.length_m / 2.0, d + 6.0
        lat, lon, _ = frame.facade_to_geodetic(ta, to, 0.0)
        home = GeoPoint(round(float(lat), DEG_DECIMALS), round(float(lon), DEG_DECIMALS), m.facade.ground_alt_amsl_m)
    return _Takeoff(home, ta, to, m.facade.ground_alt_amsl_m - home.alt_amsl_m)


def _uncovered_bottom_warnings(m: Mission, extent: WallRegion) -> list[str]:
    """The warning for a wall base below the lowest frame the bottom clearance allows (none when it is seen)."""
    uncovered_bottom = max(0.0, extent.up_min_m)
    if uncovered_bottom <= 0:
        return []
    return [
        f"the bottom {uncovered_bottom:.2f} m of the wall is below the lowest frame (bottom clearance "
        f"{m.margins.bottom_clearance_m} m): lower margins.bottom_clearance_m or inspect it from the ground"
    ]


def _entrance_exit_altitudes(m: Mission, up_to_rel: float) -> tuple[float, float]:
    """Altitudes above home at which the vehicle arrives at and leaves the wall: the mission's, else the transit
    altitude (by default 5 m above the roof margin). Both must clear the bottom clearance."""
    default_transit = m.facade.height_m + m.margins.roof_m + 5.0 + up_to_rel
    transit_rel = m.transit_alt_m if m.transit_alt_m is not None else default_transit
    entrance_rel = m.entrance_alt_m if m.entrance_alt_m is not None else transit_rel
    exit_rel = m.exit_alt_m if m.exit_alt_m is not None else transit_rel
    for label, rel in (("entrance_alt_m", entrance_rel), ("exit_alt_m", exit_rel)):
        if rel < m.margins.bottom_clearance_m:
            raise CompanionError(
                f"{label}={rel} m is below the bottom clearance of {m.margins.bottom_clearance_m} m",
                f"raise {label} (it is measured above the takeoff point)",
            )
    return entrance_rel, exit_rel


@dataclass(frozen=True)
class _PathSpeeds:
    scan_m_s: float
    transit_m_s: float


def _waypoints(
    m: Mission,
    frame: FacadeFrame,
    takeoff: _Takeoff,
    strips: list[tuple[tuple[float, float], tuple[float, float]]],
    altitudes: tuple[float, float],
    speeds: _PathSpeeds,
) -> tuple[list[Waypoint], list[tuple[int, int]]]:
    """The flight as waypoints: takeoff to the entrance altitude, transit above the first strip at the standoff,
    each strip (a settle hold at its start), climb to the exit altitude, transit home, land; and the index pairs
    of the scan legs."""
    d = m.standoff_m
    yaw = frame.yaw_facing_wall_deg
    up_to_rel = takeoff.up_to_rel_m
    ta, to = takeoff.along_m, takeoff.out_m
    entrance_rel, exit_rel = altitudes
    wps: list[Waypoint] = []

    def add(along: float, out: float, up: float, speed: float, kind: str, hold: float = 0.0, accept=SCAN_ACCEPTANCE_M):
        lat, lon, alt = frame.facade_to_geodetic(along, out, up)
        wps.append(
            Waypoint(
                along_m=float(along),
                out_m=float(out),
                up_m=float(up),
                lat=round(float(lat), DEG_DECIMALS),
                lon=round(float(lon), DEG_DECIMALS),
                alt_amsl_m=round(float(alt), M_DECIMALS),
                rel_alt_m=round(float(up + up_to_rel), M_DECIMALS),
                yaw_deg=yaw,
                speed_m_s=speed,
                kind=kind,
                hold_s=hold,
                acceptance_m=accept,
            )
        )

    first = strips[0][0]
    add(ta, to, entrance_rel - up_to_rel, NOMINAL_CLIMB_M_S, "takeoff", accept=TRANSIT_ACCEPTANCE_M)
    add(first[0], d, entrance_rel - up_to_rel, speeds.transit_m_s, "transit", accept=TRANSIT_ACCEPTANCE_M)
    scan_legs: list[tuple[int, int]] = []
    for (a0, z0), (a1, z1) in strips:
        add(a0, d, z0, speeds.scan_m_s, "scan", hold=SCAN_START_HOLD_S)
        add(a1, d, z1, speeds.scan_m_s, "scan")
        scan_legs.append((len(wps) - 2, len(wps) - 1))
    last = strips[-1][1]
    add(last[0], d, exit_rel - up_to_rel, speeds.scan_m_s, "transit", accept=TRANSIT_ACCEPTANCE_M)
    add(ta, to, exit_rel - up_to_rel, speeds.transit_m_s, "transit", accept=TRANSIT_ACCEPTANCE_M)
    add(ta, to, -up_to_rel, NOMINAL_LAND_M_S, "land")
    return wps, scan_legs


def _expected_keyframes(m: Mission, wps: list[Waypoint], fp: Footprint, extent: WallRegion) -> int:
    """Keyframes the paper's rule keeps on this path at the camera's frame rate (``keyframe_count``: whole frame
    steps, strip-to-strip moves, the roof margin on the way in and out; take-off, transit and landing excluded)."""
    path = [PathPoint(w.along_m, w.out_m, w.up_m, w.speed_m_s) for w in wps]
    ends = m.margins.ends_m  # the wall itself: frames showing it are judged, as by the chain's scan scope
    view = ScanView(fp.width_m, fp.height_m, effective_fps(m), m.standoff_m, STANDOFF_TOLERANCE_M,
                    (extent.along_min_m, extent.along_max_m, extent.up_min_m, extent.up_max_m),
                    wall=(extent.along_min_m + ends, extent.along_max_m - ends, 0.0, float(m.facade.height_m)))
    return expected_keyframes(path, view, m.overlap)


def plan_scan(mission: Mission, regions: Sequence[WallRegion] | None = None) -> ScanPlan:
    """Plan the scan of the whole wall, or only of ``regions`` (rectangles on the wall plane, frame edges reaching
    their edges: a re-fly, ``companion.mission.refly``); takeoff, transit, landing and the standoff and geofence
    checks are the same. Raises CompanionError when the mission cannot be flown safely."""
    frame = wall_frame(mission)
    if frame.length_m < 0.5:
        raise CompanionError(
            f"the wall is only {frame.length_m:.2f} m long", "check facade.start/end: they should be the wall's ends"
        )
    m = mission
    fp = camera_footprint(m)
    takeoff = _takeoff_point(m, frame)

    extent = scan_extent(m, frame.length_m)
    warnings = _uncovered_bottom_warnings(m, extent)
    if regions is not None and not regions:
        raise CompanionError("no wall region to scan was given", "give at least one region, or none for the whole wall")
    kf_spacing = (fp.height_m if m.pattern == "vertical" else fp.width_m) * (1.0 - m.overlap)
    low_centre = extent.up_min_m + fp.height_m / 2.0
    strips, strip_step = _strips(m, fp, kf_spacing, low_centre, [extent] if regions is None else list(regions))
    side_extent = fp.width_m if m.pattern == "vertical" else fp.height_m
    side_achieved = 1.0 - strip_step / side_extent if strip_step > 0 else 1.0

    v_scan, limited_by = _scan_speed(m, fp, kf_spacing)
    altitudes = _entrance_exit_altitudes(m, takeoff.up_to_rel_m)
    speeds = _PathSpeeds(v_scan, m.max_speed_m_s)

    def assemble(strips_flown: list, moving_home: bool) -> ScanPlan:
        wps, scan_legs = _waypoints(m, frame, takeoff, strips_flown, altitudes, speeds)
        window = _HomeWindow()
        if moving_home:
            wps, window = _wait_for_home_below_floor(m, wps)
        _check_clearance(m, frame, takeoff.home, wps, m.standoff_m)
        _check_geofence(m, takeoff.home, wps)
        path_len, flight_time = _path_estimates(wps)
        est = PlanEstimates(
            path_length_m=path_len,
            flight_time_s=flight_time,
            scan_speed_m_s=v_scan,
            speed_limited_by=limited_by,
            keyframe_spacing_m=kf_spacing,
            expected_keyframes=_expected_keyframes(m, wps, fp, extent),
            frames_per_keyframe=effective_fps(m) * kf_spacing / v_scan,
            motion_blur_px=v_scan * m.camera.exposure_s / (fp.gsd_mm_per_px / 1000.0),
            gsd_mm_per_px=fp.gsd_mm_per_px,
            footprint_width_m=fp.width_m,
            footprint_height_m=fp.height_m,
            strips=len(strips),
            strip_spacing_m=float(abs(strip_step)),
            side_overlap_achieved=float(side_achieved),
            uncovered_bottom_m=max(0.0, extent.up_min_m),
            px4_home_settle_hold_s=window.hold_s,
            px4_window_floor_m=window.floor_m,
            px4_low_after_s=window.low_after_s,
            px4_bottom_band_rows=window_rows if moving_home else 0,
        )
        return ScanPlan(m, frame, takeoff.home, wps, scan_legs, fp, est, warnings, moving_home=moving_home)

    steady = assemble(strips, moving_home=False)
    if m.margins.home_settle_s <= 0:
        return steady
    floor_up = window_floor_m() - takeoff.up_to_rel_m
    window_strips, window_rows = _window_first(m, fp, strips, floor_up)
    plan = assemble(window_strips, moving_home=True)
    return replace(plan, steady_home=steady)


HOME_SETTLE_SLACK_S = 5.0  # PX4 detects take-off about 1 s after lift-off; HOME_POSITION streams at 0.5 Hz
# A SITL profile's put-back of home after the window is confirmed or given up within 3 tries 5 s apart
# (``home_watch.RESTORE_TRIES`` x ``RESTORE_WAIT_S``): the part below the floor waits for that too.
HOME_PUT_BACK_S = 15.0


def window_floor_m() -> float:
    """The lowest a waypoint flown in PX4's home correction window may be above home: home's largest move down
    (``PX4_HOME_MOVE_MAX_M``) plus the minimum ground clearance."""
    return PX4_HOME_MOVE_MAX_M + MIN_GROUND_CLEARANCE_M


def _window_first(m: Mission, fp: Footprint, strips: list, floor_up: float) -> tuple[list, int]:
    """The strips reordered for an autopilot that moves home for a while after take-off: first every frame
    centre at or above ``floor_up`` (facade height), then what lies below it; and how many bottom band rows that
    takes (0 when no strip crosses the floor).

    A vertical strip that crosses the floor is flown down to it only, in its place; the strips' bottoms below it
    are flown afterwards as a band of horizontal passes (one for the demo) along the clipped strips, its top row
    overlapping their lowest frames by ``BAND_MIN_OVERLAP`` at least: a pass along the wall costs about what the
    strips' bottoms did, where flying each bottom on its own would add a sideways hop per strip. Strips wholly
    below the floor (a horizontal pattern's low rows, a low re-fly region) keep their order after the rest."""
    eps = 1e-6
    high: list = []
    clipped: list[tuple[float, float]] = []  # (along, bottom frame centre) of each vertical strip crossing the floor
    low: list = []
    for s, e in strips:
        lo, hi = min(s[1], e[1]), max(s[1], e[1])
        if lo >= floor_up - eps:
            high.append((s, e))
        elif hi <= floor_up + eps or abs(s[0] - e[0]) > eps:
            low.append((s, e))
        else:
            high.append(((s[0], max(s[1], floor_up)), (e[0], max(e[1], floor_up))))
            clipped.append((s[0], lo))
    bands: list[list[float]] = []  # [along from, along to, bottom] of neighbouring clipped strips
    for a, z in sorted(clipped):
        if bands and abs(bands[-1][2] - z) < eps and a - bands[-1][1] <= fp.width_m + eps:
            bands[-1][1] = a
        else:
            bands.append([a, a, z])
    ordered = list(high)
    rows_flown = 0
    top_needed = floor_up - (1.0 - BAND_MIN_OVERLAP) * fp.height_m  # the top row's centre reaches this
    step = fp.height_m * (1.0 - m.side_overlap)
    for a0, a1, z in bands:
        n = 1 if top_needed <= z + eps else math.ceil((top_needed - z) / step - 1e-9) + 1
        rows = [float(v) for v in np.linspace(z, max(z, top_needed), n)]
        if a1 - a0 < eps:  # one strip: its bottom part as a strip of its own
            ordered.append(_nearest_first(ordered, (a0, floor_up), (a0, z)))
            continue
        rows_flown += len(rows)
        for r in reversed(rows):  # from the top: the vehicle comes from above
            ordered.append(_nearest_first(ordered, (a0, r), (a1, r)))
    for s, e in low:
        ordered.append(_nearest_first(ordered, s, e))
    return ordered, rows_flown


@dataclass(frozen=True)
class _HomeWindow:
    """What the plan does about an autopilot moving home after take-off (none: all zero)."""

    floor_m: float = 0.0
    hold_s: float = 0.0
    low_after_s: float = 0.0


def settle_waypoint_index(wps: Sequence[Waypoint], floor_m: float | None = None) -> int:
    """The last waypoint flown while PX4's home may still move: the one before the first waypoint below
    ``floor_m`` above home after the take-off (-1 when none is: the landing aside); without a floor, the one before
    the first scan waypoint."""
    if floor_m is None:
        first_scan = next(k for k, w in enumerate(wps) if w.kind == "scan")
        return max(0, first_scan - 1)
    low = [k for k, w in enumerate(wps) if k > 0 and w.kind in ("scan", "transit") and w.rel_alt_m < floor_m - 1e-6]
    return low[0] - 1 if low else -1


def _fastest_arrival_s(wps: Sequence[Waypoint], k: int) -> float:
    """The soonest after take-off the vehicle can reach waypoint ``k``: climbing at PX4's MPC_Z_VEL_MAX_UP, each
    leg at its speed without acceleration, each hold before ``k`` held."""
    fastest = wps[0].rel_alt_m / PX4_MAX_CLIMB_M_S
    for prev, wp in zip(wps[: k], wps[1: k + 1], strict=True):
        fastest += math.dist((prev.along_m, prev.out_m, prev.up_m), (wp.along_m, wp.out_m, wp.up_m)) / wp.speed_m_s
        fastest += prev.hold_s
    return fastest


def _wait_for_home_below_floor(m: Mission, wps: list[Waypoint]) -> tuple[list[Waypoint], _HomeWindow]:
    """PX4: nothing below the window floor before ``margins.home_settle_s`` (+ slack) after take-off.

    Why: PX4 moves home's altitude for 120 s after take-off (``autopilot.px4.PX4_HOME_CORRECTION_WINDOW_S``) and
    every waypoint activated later moves with it; on PX4 SIH home ended up to 1.51 m low, and strip bottoms planned
    1.55 m above home flew into the ground. The waypoints flown in the window are at least ``window_floor_m()`` above
    home, so home's largest move still leaves 1 m; the part below (``_window_first`` puts it last) starts no earlier
    than the window + ``HOME_SETTLE_SLACK_S`` + ``HOME_PUT_BACK_S``, counting the fastest PX4 can get there, and
    the last waypoint above the floor holds for what is missing (nothing when the part above takes longer, as the
    demo's does); the flight's home watch sees the final home before any waypoint below the floor."""
    floor = window_floor_m()
    k = settle_waypoint_index(wps, floor)
    if k < 0:  # the whole flight stays above the floor
        return wps, _HomeWindow(floor_m=floor)
    if k == 0:  # only a waypoint can hold: the take-off item cannot
        raise CompanionError(
            f"the vehicle enters the scan {wps[1].rel_alt_m:g} m above home, under the {floor:g} m PX4 needs for what "
            f"it flies in the {m.margins.home_settle_s:g} s after take-off (PX4 moves home's altitude then)",
            f"raise entrance_alt_m / transit_alt_m to {floor:g} m or more, or set margins.home_settle_s: 0 for an "
            f"autopilot that keeps home where it armed")
    due = m.margins.home_settle_s + HOME_SETTLE_SLACK_S + HOME_PUT_BACK_S
    fastest = _fastest_arrival_s(wps, k)
    planned = wps[k].hold_s
    hold = max(planned, round(due - fastest, 1))
    if hold > planned:
        wps = [*wps[:k], replace(wps[k], hold_s=hold), *wps[k + 1:]]
    return wps, _HomeWindow(floor_m=floor, hold_s=hold if hold > planned else 0.0,
                            low_after_s=round(fastest + hold, 1))


def _path_estimates(wps: list[Waypoint]) -> tuple[float, float]:
    length = wps[0].rel_alt_m - 0.0  # vertical climb of the takeoff
    time_s = length / NOMINAL_CLIMB_M_S
    for prev, wp in zip(wps, wps[1:], strict=False):
        leg = math.dist((prev.along_m, prev.out_m, prev.up_m), (wp.along_m, wp.out_m, wp.up_m))
        length += leg
        v = wp.speed_m_s
        time_s += leg / v + v / NOMINAL_ACCEL_M_S2 + wp.hold_s  # cruise + accelerate/brake
    return length, time_s


def _check_clearance(m: Mission, frame: FacadeFrame, home: GeoPoint, wps: list[Waypoint], standoff: float) -> None:
    """No leg may come horizontally closer than the standoff to the wall (or any footprint edge)."""
    origin = frame.origin
    fp = footprint_enu(m, origin)
    if fp is not None:
        edges = [(fp[i], fp[(i + 1) % len(fp)]) for i in range(len(fp))]
    else:
        e, n, _ = frame.facade_to_enu(np.array([0.0, frame.length_m]), 0.0, 0.0)
        edges = [(np.array([e[0], n[0]]), np.array([e[1], n[1]]))]
    path = []
    for wp in wps:
        e, n, _ = pymap3d.geodetic2enu(wp.lat, wp.lon, origin.alt_amsl_m, origin.lat, origin.lon, origin.alt_amsl_m)
        path.append((e, n))
    clearance = polyline_clearance(np.array(path), edges)
    worst = int(np.argmin(clearance)) if len(clearance) else 0
    if len(clearance) and clearance[worst] < standoff - STANDOFF_TOLERANCE_M:
        raise CompanionError(
            f"leg {worst}->{worst + 1} ({wps[worst].kind} -> {wps[worst + 1].kind}) passes {clearance[worst]:.2f} m "
            f"from the building, closer than the standoff of {standoff} m",
            "move the takeoff point so the straight line to the wall stays on the drone's side, or check the footprint",
        )


def _check_geofence(m: Mission, home: GeoPoint, wps: list[Waypoint]) -> None:
    gf = m.geofence
    for k, wp in enumerate(wps):
        if wp.rel_alt_m > gf.max_alt_m + 1e-6:
            raise CompanionError(
                f"the path leaves the geofence: waypoint {k} ({wp.kind}) is {wp.rel_alt_m:.1f} m above home, "
                f"above geofence.max_alt_m={gf.max_alt_m}",
                "raise geofence.max_alt_m (within your legal limit) or lower transit_alt_m / margins.roof_m",
            )
        e, n, _ = pymap3d.geodetic2enu(wp.lat, wp.lon, home.alt_amsl_m, home.lat, home.lon, home.alt_amsl_m)
        dist = math.hypot(e, n)
        if dist > gf.max_distance_m + 1e-6:
            raise CompanionError(
                f"the path leaves the geofence: waypoint {k} ({wp.kind}) is {dist:.1f} m from home, "
                f"beyond geofence.max_distance_m={gf.max_distance_m}",
                "raise geofence.max_distance_m or move the takeoff point closer to the wall",
            )


def build_mission_items(plan: ScanPlan, flavour: str | Autopilot = DEFAULT_FLAVOUR) -> list[mi.MissionItem]:
    """Raw MAVLink mission, in the form the firmware accepts and honours: its home (``companion.mission.autopilot``)
    gives what differs (a home placeholder, what an unused param holds, the speed items, each waypoint's items
    and how it faces the wall), from the plan for that firmware (``ScanPlan.for_autopilot``: PX4 flies the part near
    the ground after its home correction window)."""
    ap = autopilot_for(flavour)
    plan = plan.for_autopilot(ap)
    rows: list[tuple] = list(ap.home_rows(plan.home))  # (frame, command, p1, p2, p3, p4, lat, lon, z)
    pitch = plan.mission.gimbal_pitch_deg
    unused = ap.no_value
    wps = plan.waypoints
    speed = None
    for k, wp in enumerate(wps):
        if wp.kind == "takeoff":
            rows.append((mi.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, mi.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, unused, wp.lat,
                         wp.lon, wp.rel_alt_m))
            # Camera level and forward; gimbal manager first (PX4, ArduPilot 4.3+), mount control for older stacks.
            rows.append((mi.MAV_FRAME_MISSION, mi.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW, pitch, 0, unused, unused, 0, 0,
                         0))
            rows.append((mi.MAV_FRAME_MISSION, mi.MAV_CMD_DO_MOUNT_CONTROL, pitch, 0, 0, 0, 0, 0, 2))
            continue
        if wp.kind == "land":
            rows.append((mi.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, mi.MAV_CMD_NAV_LAND, 0, 0, 0, unused, wp.lat, wp.lon,
                         0.0))
            continue
        if speed is None or abs(wp.speed_m_s - speed) > 1e-6:
            speed = wp.speed_m_s
            rows += ap.speed_rows(speed, _segment_moves_vertically(wps, k))
        is_last_before_land = k + 1 < len(wps) and wps[k + 1].kind == "land"
        if is_last_before_land and plan.mission.end_action == "rtl":
            rows.append((mi.MAV_FRAME_MISSION, mi.MAV_CMD_NAV_RETURN_TO_LAUNCH, 0, 0, 0, 0, 0, 0, 0))
            break
        rows += ap.waypoint_rows(wp, wp.hold_s)
    items = []
    for seq, (frm, cmd, p1, p2, p3, p4, lat, lon, z) in enumerate(rows):
        items.append(
            mi.MissionItem(
                seq=seq,
                frame=frm,
                command=cmd,
                current=1 if seq == 0 else 0,
                autocontinue=1,
                param1=float(p1),
                param2=float(p2),
                param3=float(p3),
                param4=float(p4),
                x=int(round(lat * 1e7)),
                y=int(round(lon * 1e7)),
                z=float(z),
            )
        )
    return items


def _segment_moves_vertically(wps: list[Waypoint], k: int) -> bool:
    """Whether any leg flown at waypoint ``k``'s speed (up to the next speed change) climbs or descends."""
    j = k
    while j < len(wps) and wps[j].kind != "land" and abs(wps[j].speed_m_s - wps[k].speed_m_s) <= 1e-6:
        if j > 0 and abs(wps[j].rel_alt_m - wps[j - 1].rel_alt_m) > 0.05:
            return True
        j += 1
    return False

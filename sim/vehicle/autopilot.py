"""The simulated autopilot: flight modes, commands, mission execution, telemetry streams and the true-pose feed.

One ``SimVehicle`` runs a fixed 50 Hz simulated-time loop paced ``speedup`` times faster than the wall clock.
MAVLink timestamps are simulated time. It answers what mavsdk 4.1 asks of a PX4 SITL (or ArduCopter, with
``autopilot="ardupilot"``): heartbeats with decodable custom modes, health in SYS_STATUS, AUTOPILOT_VERSION on
request, parameters, message intervals, the mission protocol and the commands below.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import logging
import math
import select
import socket
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pymap3d
from pymavlink.dialects.v20 import ardupilotmega as mavlink  # common + ArduPilot messages

from companion.geo import GeoPoint
from companion.mission import items as mi
from sim.vehicle import flavours as fl
from sim.vehicle import rangefinder as rf
from sim.vehicle.commands import CommandHandler
from sim.vehicle.copter_yaw import CopterAutoYaw
from sim.vehicle.environment import Battery, GpsError, Wind
from sim.vehicle.firmware import FirmwareRules
from sim.vehicle.gnss_bias import GnssBias, ned_to_enu
from sim.vehicle.link import FaultyUdpLink
from sim.vehicle.mission_server import MissionServer
from sim.vehicle.model import Limits, Multirotor
from sim.vehicle.rangefinder import ForwardRangefinder, WallNed, WallSpec
from sim.vehicle.tasks import Climb, Hold, Land, Line, ReturnHome, Task
from sim.vehicle.telemetry import TelemetryStreams

log = logging.getLogger(__name__)

DT_S = 0.02  # 50 Hz simulated time
# Streams of random draws added later: each its own generator, seeded (vehicle seed, stream), so a new fault never
# shifts the sequences of the older ones (wind seed+1, GPS noise +2, link +3, stalls +4)
GNSS_BIAS_STREAM = 5
RANGEFINDER_STREAM = 6


@dataclass
class VehicleConfig:
    """Everything the command line can set. Link fault times: ``outage_at_s`` is simulated time since boot (so
    it hits a reproducible point of the flight), ``outage_s`` is wall time (the peer's timeouts are wall time)."""

    home: GeoPoint = field(default_factory=lambda: GeoPoint(37.56638, 126.97815, 30.0))
    home_yaw_deg: float = 0.0
    speedup: float = 1.0
    seed: int = 0
    autopilot: str = "px4"
    target: tuple[str, int] = ("127.0.0.1", 14540)
    bind_port: int = 0
    pose_port: int | None = 14660
    truth_log: Path | None = None
    wind_m_s: float = 0.0
    gusts_m_s: float = 0.0
    wind_from_deg: float | None = None
    gps_noise_m: float = 0.0
    packet_loss: float = 0.0
    latency_ms: float = 0.0
    stream_stall_s: float = 0.0  # ATTITUDE / GLOBAL_POSITION_INT each lag behind now and then, up to this (simulated)
    stream_stall_every_s: float = 30.0  # simulated seconds between one stream's stalls, on average
    outage_at_s: float | None = None
    outage_s: float = 0.0
    gps_glitch_at_s: float | None = None
    gps_glitch_m: float = 5.0
    gps_glitch_s: float = 3.0
    # GNSS bias (sim/vehicle/gnss_bias.py): estimate minus truth, East/North/Up metres, plus a random walk of
    # this RMS growth per axis (metres per minute), optionally clamped per axis; zeros: off (the old estimate)
    gnss_bias_enu_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    gnss_drift_m_per_min: float = 0.0
    gnss_drift_max_m: float | None = None
    # forward rangefinder (sim/vehicle/rangefinder.py): DISTANCE_SENSOR from the TRUE position to this wall
    rangefinder: bool = False
    rangefinder_wall: WallSpec | None = None
    rangefinder_max_m: float = rf.DEFAULT_MAX_M
    rangefinder_min_m: float = rf.DEFAULT_MIN_M
    rangefinder_noise_m: float = rf.DEFAULT_NOISE_M
    rangefinder_sees: str = "wall"  # "ground": ArduPilot SITL's rangefinder, the height labelled forward
    duration_s: float | None = None
    max_mission_items: int | None = None  # None: the firmware's own (flavour.max_mission_items)
    system_id: int = 1
    params: dict[str, float] = field(default_factory=dict)  # parameter values at boot, over the flavour's defaults

    # firmware behaviours (sim/vehicle/firmware.py): reboot this long (simulated) after take-off, silent for
    # reboot_s wall seconds;
    # PX4 geofence radius; seconds after boot until the estimator uses GPS (None: the flavour's); PX4 storage file
    reboot_after_takeoff_s: float | None = None
    outage_after_takeoff_s: float | None = None
    reboot_s: float = 2.0
    geofence_max_dist_m: float | None = None
    gps_ready_after_s: float | None = None
    storage: Path | None = None
    init_s: float | None = None  # wall seconds of start-up after each boot (None: the flavour's, firmware.py)
    # PX4's in-flight home correction: None (default) moves home as real PX4 SIH does (sim/vehicle/home_drift.py);
    # a number moves it once by that much (up positive; 0: never) home_shift_after_takeoff_s (simulated) after take-off
    home_shift_after_takeoff_s: float | None = None
    home_shift_m: float | None = None
    # the MAV_AUTOPILOT its HEARTBEAT names (None: the flavour's): a vehicle that is neither PX4 nor ArduPilot, for
    # the companion's refusal of a firmware it does not know
    heartbeat_autopilot: int | None = None
    limits: Limits = field(default_factory=Limits)


class _LinkWriter:
    def __init__(self, link: FaultyUdpLink):
        self.link = link

    def write(self, buf) -> None:
        self.link.send(bytes(buf))


class SimVehicle(TelemetryStreams, CommandHandler, FirmwareRules):
    """A MAVLink multirotor. ``run()`` blocks until ``stop()`` or ``duration_s`` of simulated time."""

    def __init__(self, cfg: VehicleConfig):
        if cfg.speedup <= 0:
            raise ValueError("speedup must be positive")
        if cfg.autopilot not in fl.FLAVOURS:
            raise ValueError(f"unknown autopilot flavour {cfg.autopilot!r}; use one of {sorted(fl.FLAVOURS)}")
        self.cfg = cfg
        self.flavour = fl.FLAVOURS[cfg.autopilot]()
        self.rng = np.random.default_rng(cfg.seed)
        self.model = Multirotor(cfg.limits)
        self.model.state.yaw_deg = cfg.home_yaw_deg % 360.0
        self.limits = cfg.limits
        self.wind = Wind(cfg.wind_m_s, cfg.gusts_m_s, np.random.default_rng(cfg.seed + 1), cfg.wind_from_deg)
        self.gps = GpsError(cfg.gps_noise_m, np.random.default_rng(cfg.seed + 2), cfg.gps_glitch_at_s,
                            cfg.gps_glitch_m, cfg.gps_glitch_s)
        self.gnss_bias = GnssBias(cfg.gnss_bias_enu_m, cfg.gnss_drift_m_per_min,
                                  np.random.default_rng((cfg.seed, GNSS_BIAS_STREAM)), cfg.gnss_drift_max_m)
        wall = WallNed.from_spec(cfg.rangefinder_wall, cfg.home) if cfg.rangefinder_wall else None
        self.rangefinder = ForwardRangefinder(wall, np.random.default_rng((cfg.seed, RANGEFINDER_STREAM)),
                                              min_m=cfg.rangefinder_min_m, max_m=cfg.rangefinder_max_m,
                                              noise_m=cfg.rangefinder_noise_m,
                                              sees=cfg.rangefinder_sees) if cfg.rangefinder else None
        self.battery = Battery()
        self.link = FaultyUdpLink(cfg.target, np.random.default_rng(cfg.seed + 3),
                                  bind=("127.0.0.1", cfg.bind_port), loss=cfg.packet_loss,
                                  latency_s=cfg.latency_ms / 1000.0)
        self.mav = mavlink.MAVLink(_LinkWriter(self.link), srcSystem=cfg.system_id, srcComponent=1)
        self.mav.robust_parsing = True
        self.params = dict(self.flavour.params)
        self.params.update({name: type(self.params.get(name, 0.0))(value) for name, value in cfg.params.items()})
        self.rates = dict(self.flavour.default_rates_hz)
        if self.rangefinder is not None:  # ArduPilot too: a rangefinder is no use to the companion unless it streams
            self.rates.setdefault("DISTANCE_SENSOR", rf.RATE_HZ)
        self._next_due: dict[str, float] = {}
        self.stream_rng = np.random.default_rng(cfg.seed + 4)  # its own draws: other faults keep their sequences
        self._held: dict[str, list] = {}  # stream -> messages held back while it stalls (--stream-stall)
        self._stall_until: dict[str, float] = {}
        self._next_stall: dict[str, float] = {}
        self.home_item = mi.MissionItem(0, mi.MAV_FRAME_GLOBAL, mi.MAV_CMD_NAV_WAYPOINT, 0, 1, 0.0, 0.0, 0.0, 0.0,
                                        round(cfg.home.lat * 1e7), round(cfg.home.lon * 1e7), cfg.home.alt_amsl_m)
        self.missions = MissionServer(
            self.mav, self._send, self.flavour.validate, self._on_new_mission,
            self.flavour.max_mission_items if cfg.max_mission_items is None else cfg.max_mission_items,
            transform_upload=lambda items: self.flavour.transform_upload(items, self.home_item),
            transform_download=lambda items: self.flavour.transform_download(items, self.home_item),
            on_too_many=self._too_many_items, on_invalid_item=self._invalid_item)
        self.pose_sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM) if cfg.pose_port else None
        self.truth_file = open(cfg.truth_log, "w") if cfg.truth_log else None  # noqa: SIM115 (closed in close())

        self.t = 0.0
        self.armed = False
        self.mode = self.flavour.boot_mode
        self.task: Task = Hold(self.model.state.pos)
        self.yaw_target: float | None = None
        self.cruise_m_s = self.param("MPC_XY_CRUISE", 5.0)
        self.climb_override_m_s: float | None = None  # DO_CHANGE_SPEED type 2 (ArduCopter)
        self.descent_override_m_s: float | None = None  # DO_CHANGE_SPEED type 3 (ArduCopter)
        self.copter_yaw = CopterAutoYaw()
        self.gimbal_pitch_deg = 0.0
        self.gimbal_yaw_deg = 0.0
        self.mission: list[mi.MissionItem] = []
        self.mission_seq = self.flavour.first_seq
        self.mission_task: Task | None = None
        self.mission_prev: np.ndarray | None = None
        self.mission_finished = False
        self.reached_seq = -1
        self.reached_repeats = 0
        self.landed_since: float | None = None
        self.took_off = False
        self.gcs: tuple[int, int] | None = None
        self.last_gcs_wall: float | None = None
        self.link_failsafe = False
        self.battery_failsafe = False
        self._outage_start_wall: float | None = None
        self._stop = False
        self.nav = self.model.state.pos.copy()
        if self.gnss_bias.active:
            self.nav = self.nav + self.gnss_bias.ned
        self._init_firmware_rules()

    # --- helpers -------------------------------------------------------------------------------------------
    def param(self, name: str, default: float) -> float:
        v = self.params.get(name)
        if v is None:
            return default
        return float(v)

    @property
    def yaw_deg(self) -> float:
        return self.model.state.yaw_deg

    @property
    def auto_climb_m_s(self) -> float:
        """Climb speed of mission legs: ArduCopter WPNAV_SPEED_UP (or DO_CHANGE_SPEED type 2), PX4
        MPC_Z_V_AUTO_UP (capped by MPC_Z_VEL_MAX_UP); never above the airframe's envelope."""
        return min(self.flavour.auto_climb_m_s(self), self.limits.max_climb_m_s)

    @property
    def auto_descent_m_s(self) -> float:
        """Descent speed of mission legs: ArduCopter WPNAV_SPEED_DN (or DO_CHANGE_SPEED type 3), PX4
        MPC_Z_V_AUTO_DN (capped by MPC_Z_VEL_MAX_DN)."""
        return min(self.flavour.auto_descent_m_s(self), self.limits.max_descent_m_s)

    @property
    def auto_limits(self) -> Limits:
        """The envelope with the autopilot's current climb/descent speeds, for mission legs."""
        return dataclasses.replace(self.limits, max_climb_m_s=self.auto_climb_m_s,
                                   max_descent_m_s=self.auto_descent_m_s)

    @property
    def land_speed_m_s(self) -> float:
        return self.flavour.land_speed_m_s(self)

    @property
    def on_ground(self) -> bool:
        return self.model.state.on_ground

    def _send(self, msg) -> None:
        self.mav.send(msg)

    def _too_many_items(self, limit: int) -> None:
        if self.flavour.too_many_items_text:
            self.statustext(mavlink.MAV_SEVERITY_WARNING, self.flavour.too_many_items_text.format(n=limit))

    def _invalid_item(self, result: int) -> None:
        if self.flavour.invalid_item_text:
            self.statustext(mavlink.MAV_SEVERITY_CRITICAL, self.flavour.invalid_item_text)

    def statustext(self, severity: int, text: str) -> None:
        log.info("statustext: %s", text)
        self._send(self.mav.statustext_encode(severity, text.encode()[:50]))

    def ned_to_geodetic(self, ned) -> tuple[float, float, float]:
        h = self.cfg.home
        return pymap3d.ned2geodetic(float(ned[0]), float(ned[1]), float(ned[2]), h.lat, h.lon, h.alt_amsl_m)

    def item_ned(self, item: mi.MissionItem) -> np.ndarray:
        """Local NED target of a positional mission item; lat/lon 0/0 means 'here'."""
        h = self.cfg.home
        if item.x == 0 and item.y == 0:
            north, east = float(self.nav[0]), float(self.nav[1])
        else:
            north, east, _ = pymap3d.geodetic2ned(item.lat, item.lon, h.alt_amsl_m, h.lat, h.lon, h.alt_amsl_m)
        # relative altitudes are above home as it is now (PX4 may have moved it in flight: firmware.py)
        down = (-(item.z - h.alt_amsl_m) if item.frame in (mi.MAV_FRAME_GLOBAL, mi.MAV_FRAME_GLOBAL_INT)
                else -(item.z + self.home_alt_shift_m))
        return np.array([north, east, down], dtype=float)

    # --- modes ---------------------------------------------------------------------------------------------
    def set_mode(self, mode: str) -> str | None:
        """Switch flight mode; returns a refusal reason or None."""
        nav = self.nav.copy()
        if mode == fl.MISSION:
            if len(self.mission) <= self.flavour.first_seq:
                return "no mission uploaded"
            if self.on_ground and self.armed:
                refusal = self.flavour.ground_start_refusal(self.mission)
                if refusal:
                    for severity, text in refusal[:-1]:
                        self.statustext(severity, text)
                    return refusal[-1][1]  # said (WARNING) with the refusing ACK
                if self.refuse_infeasible_start():
                    self.mode = mode
                    self.task = Hold(self.model.state.pos)
                    return None
            if self.mission_finished:
                self.mission_seq, self.mission_finished = self.flavour.first_seq, False
            self.mission_task = None
            self.mission_prev = nav
            if self.mode != fl.MISSION:
                log.info("mission mode from item %d", self.mission_seq)
        elif mode == fl.TAKEOFF:
            if not self.armed:
                return "takeoff needs the vehicle armed"
            alt = self.flavour.takeoff_alt_m(self)
            self.task = Climb(nav[:2], -max(alt, -nav[2]))
        elif mode == fl.RTL:
            if self.on_ground:
                self.task = Hold(nav)
            else:
                alt = self.flavour.rtl_alt_m(self)
                self.task = ReturnHome(nav, alt)
        elif mode == fl.LAND:
            self.task = Land()
        else:  # hold-like modes
            self.task = Hold(nav if not self.on_ground else self.model.state.pos)
        if mode != self.mode:
            log.info("mode %s -> %s", self.mode, mode)
        self.mode = mode
        return None

    def arm(self, force: bool = False) -> str | None:
        if self.armed:
            return None
        if not force:
            refusal = self.flavour.arm_refusal(self.mode)
            if refusal:
                return refusal
            if self.battery.remaining < 0.2:
                return "battery too low to arm"
            if self.gps.glitching(self.t):
                return "GPS position not usable"
            prearm = self.prearm_refusal()
            if prearm:
                return prearm
        self.armed = True
        self.armed_at = self.t
        self.took_off = False
        self.on_arm_home()
        self.landed_since = None
        self.battery_failsafe = False  # the link failsafe is the link's state: arming does not clear it
        if self.mode in (fl.HOLD, fl.POSCTL, fl.GUIDED, fl.BRAKE):
            self.task = Hold(self.model.state.pos)
        log.info("armed")
        return None

    def disarm(self, force: bool = False) -> str | None:
        if not self.armed:
            return None
        if not self.on_ground and not force:
            return "refusing to disarm in the air"
        self.armed = False
        log.info("disarmed")
        return None

    def _on_new_mission(self, items: list) -> None:
        keep = self.keeps_current_on_upload(list(items))
        self.mission = list(items)
        if keep:
            log.info("uploaded mission equals the stored one: current item %d kept", self.mission_seq)
        else:
            self.mission_seq = self.flavour.first_seq
        self.mission_refused = False
        self.mission_task = None
        self.mission_finished = False
        self.reached_seq = -1
        self.climb_override_m_s = self.descent_override_m_s = None
        if self.mode == fl.MISSION and self.armed:
            self.set_mode(fl.HOLD)
        self._send_mission_current()
        self.save_storage()

    # --- mission execution ---------------------------------------------------------------------------------
    def _start_item(self, item: mi.MissionItem) -> bool:
        """Set up the task for ``item``; returns True when the item completes at once (DO/CONDITION items)."""
        nav = self.nav
        cmd = item.command
        prev = self.mission_prev if self.mission_prev is not None else nav.copy()
        copter = self.flavour.copter_yaw
        if cmd == mi.MAV_CMD_NAV_TAKEOFF:
            target = self.item_ned(item)
            self.mission_task = Climb(nav[:2], min(target[2], nav[2]))
            if copter:
                self.copter_yaw.hold()
            return False
        if cmd == mi.MAV_CMD_NAV_WAYPOINT:
            target = self.item_ned(item)
            if copter:  # Copter does not use param4: its auto_yaw decides (see copter_yaw.py)
                yaw = None
                self.copter_yaw.wp_start(int(self.param("WP_YAW_BEHAVIOR", 2)), tuple(target[:2] - prev[:2]))
            else:
                yaw = item.param4 if math.isfinite(item.param4) else None
                if yaw is None and math.hypot(*(target[:2] - nav[:2])) > 2.0 and self.param("MIS_YAWMODE", 0) == 0:
                    yaw = math.degrees(math.atan2(target[1] - nav[1], target[0] - nav[0])) % 360.0
            radius = self.flavour.waypoint_reached_m
            alt_radius = None
            if radius is None:  # PX4: param2 (else NAV_ACC_RAD) horizontally, NAV_MC_ALT_RAD vertically
                radius = item.param2 if item.param2 > 0 else self.param("NAV_ACC_RAD", 2.0)
                alt_radius = self.param("NAV_MC_ALT_RAD", 0.8)
            self.mission_task = Line(prev, target, radius, max(item.param1, 0.0), yaw, alt_radius_m=alt_radius)
            return False
        if cmd == mi.MAV_CMD_NAV_LAND:
            if copter:
                self.copter_yaw.hold()
            xy = None if item.x == 0 and item.y == 0 else self.item_ned(item)[:2]
            self.mission_task = Land(xy)
            return False
        if cmd == mi.MAV_CMD_NAV_RETURN_TO_LAUNCH:
            self.mission_task = ReturnHome(nav, self.param("RTL_RETURN_ALT", 15.0))
            return False
        if cmd == mi.MAV_CMD_DO_CHANGE_SPEED:
            self._mission_change_speed(int(item.param1) if math.isfinite(item.param1) else -1, item.param2)
        elif cmd == mi.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW:
            self._set_gimbal(item.param1, item.param2)
        elif cmd == mi.MAV_CMD_DO_MOUNT_CONTROL:
            self._set_gimbal(item.param1, item.param3)
        elif cmd == mi.MAV_CMD_CONDITION_YAW:
            if copter:
                self.copter_yaw.condition_yaw(item.param1, item.param3, item.param4, self.yaw_deg)
            else:
                self._condition_yaw(item.param1, item.param3, item.param4)
        return True

    def _mission_change_speed(self, speed_type: int, speed: float) -> None:
        """DO_CHANGE_SPEED in a mission. ArduCopter: types 0/1 horizontal, 2 climb, 3 descent
        (ModeAuto::do_change_speed). PX4 takes param2 of any type as the horizontal cruise speed
        (navigator_main.cpp): its climb/descent speeds are parameters only."""
        if not (math.isfinite(speed) and speed > 0):
            return
        self.flavour.change_speed(self, int(speed_type), speed)

    def _set_gimbal(self, pitch: float, yaw: float) -> None:
        if math.isfinite(pitch):
            self.gimbal_pitch_deg = max(-90.0, min(30.0, float(pitch)))
        if math.isfinite(yaw):
            self.gimbal_yaw_deg = float(yaw)

    def _condition_yaw(self, angle: float, direction: float, relative: float) -> None:
        if not math.isfinite(angle):
            return
        if relative:
            self.yaw_target = (self.yaw_deg + (angle if direction >= 0 else -angle)) % 360.0
        else:
            self.yaw_target = angle % 360.0
        if isinstance(self.task, Hold):
            self.task.yaw_deg = self.yaw_target

    def _item_done(self) -> None:
        seq = self.mission_seq
        task = self.mission_task
        if isinstance(task, Line):
            self.mission_prev = task.b.copy()
        elif isinstance(task, Climb):
            self.mission_prev = task.point.copy()
        elif task is not None:
            self.mission_prev = self.nav.copy()
        self.reached_seq = seq
        self.reached_repeats = 0
        self._send(self.mav.mission_item_reached_encode(seq))
        self.mission_task = None
        self.mission_seq += 1
        if self.mission_seq >= len(self.mission):
            self.mission_finished = True
            self.mission_seq = len(self.mission) - 1
            self.task = Hold(self.nav if not self.on_ground else self.model.state.pos)
            log.info("mission finished")
        self._send_mission_current()
        self.save_storage()

    def _mission_command(self, on_ground: bool, dt: float) -> np.ndarray:
        for _ in range(len(self.mission) + 1):
            if self.mission_finished:
                return self.task.command(self.nav, on_ground, dt, self)
            if self.mission_task is None and self._start_item(self.mission[self.mission_seq]):
                self._item_done()
                continue
            assert self.mission_task is not None
            v = self.mission_task.command(self.nav, on_ground, dt, self)
            if self.flavour.copter_yaw:
                self.yaw_target = self.copter_yaw.target(self.yaw_deg, (float(self.model.state.vel[0]),
                                                                        float(self.model.state.vel[1])))
            elif self.mission_task.yaw_deg is not None:
                self.yaw_target = self.mission_task.yaw_deg
            if self.mission_task.done:
                self._item_done()
            return v
        return np.zeros(3)

    # --- simulation step -----------------------------------------------------------------------------------
    def step(self, dt: float = DT_S) -> None:
        self.t += dt
        st = self.model.state
        wind = self.wind.step(dt)
        self.nav = st.pos + self.gps.step(self.t, dt)
        if self.gnss_bias.active:  # off: not even + 0, so the estimate stays bit for bit the old one
            self.nav = self.nav + self.gnss_bias.step(dt)
        v_cmd = np.zeros(3)
        if self.armed:
            if self.mode == fl.MISSION and self.mission_refused:
                v_cmd = np.zeros(3)
            elif self.mode == fl.MISSION:
                v_cmd = self._mission_command(st.on_ground, dt)
            else:
                v_cmd = self.task.command(self.nav, st.on_ground, dt, self)
                if self.task.yaw_deg is not None:
                    self.yaw_target = self.task.yaw_deg
                if self.task.done and self.mode == fl.TAKEOFF:
                    self.set_mode(self.flavour.after_takeoff_mode)
        self.model.step(dt, v_cmd, self.yaw_target, wind if not st.on_ground else np.zeros(3), self.armed)
        if not st.on_ground:
            self.took_off = True
        self._landing_logic()
        self.preflight_disarm()
        self.update_home_shift()  # simulated time after take-off: reproducible whatever the machine's load
        self.battery.step(dt, self.armed, float(np.linalg.norm(st.vel)))
        self._failsafes()
        self._publish_truth()

    def _landing_logic(self) -> None:
        st = self.model.state
        if self.armed and st.on_ground and self.took_off:
            if self.landed_since is None:
                self.landed_since = self.t
            elif self.t - self.landed_since >= self.param("COM_DISARM_LAND", 2.0):
                self.disarm()
                self.statustext(mavlink.MAV_SEVERITY_INFO, "Landing detected, disarmed")
        elif not st.on_ground:
            self.landed_since = None

    def _failsafes(self) -> None:
        self._link_failsafe()  # tracked on the ground too, as the firmware tracks it
        if not (self.armed and not self.on_ground):
            return
        if (not self.battery_failsafe and self.battery.remaining < self.param("BAT_LOW_THR", 0.15)
                and self.mode not in (fl.RTL, fl.LAND)):
            self.battery_failsafe = True
            self.statustext(mavlink.MAV_SEVERITY_WARNING, "Low battery: returning to launch")
            self.set_mode(fl.RTL)

    def _link_failsafe(self) -> None:
        """The lost link's onset and recovery by each firmware's rule (firmware.py), whatever the vehicle does; the
        action only at the onset and only in the air. Copter::failsafe_gcs_check: nothing before a GCS was seen or
        with FS_GCS_ENABLE 0; an onset while disarmed takes no action and, already in failsafe, a later take-off
        none either; the next counted heartbeat clears it. (Arming used to clear it here, so a take-off right
        after the companion became the GCS, its first heartbeat not yet counted, went straight to RTL.)"""
        action = self.flavour.lost_link_action(self.params)
        if self.last_gcs_wall is None or action is None:
            return
        timeout = self.flavour.link_loss_timeout_s(self.params)
        if time.monotonic() - self.last_gcs_wall <= timeout:
            if self.link_failsafe:
                self.link_failsafe = False
                log.info("data link regained")
            return
        if self.link_failsafe:
            return
        self.link_failsafe = True
        if (not self.armed or self.on_ground or self.mode in (fl.RTL, fl.LAND)
                or self.flavour.lost_link_ignored(self.params, self.mode)):
            log.info("data link lost for more than %.0f s: no action (%s, %s)", timeout,
                     "armed" if self.armed else "disarmed", self.mode)
            return
        log.warning("data link lost for more than %.0f s: %s", timeout, action)
        self.statustext(mavlink.MAV_SEVERITY_CRITICAL, f"Data link lost: failsafe {action}")
        self.set_mode({"rtl": fl.RTL, "land": fl.LAND, "hold": fl.HOLD}[action])

    def landed_state(self) -> int:
        st = self.model.state
        if st.on_ground:
            return mavlink.MAV_LANDED_STATE_ON_GROUND
        if self.mode == fl.LAND or (isinstance(self.mission_task or self.task, Land) and st.vel[2] > 0.2):
            return mavlink.MAV_LANDED_STATE_LANDING
        if st.pos[2] > -1.0 and st.vel[2] < -0.2:
            return mavlink.MAV_LANDED_STATE_TAKEOFF
        return mavlink.MAV_LANDED_STATE_IN_AIR

    def true_pose(self) -> dict:
        """The pose channel's and truth log's line: the TRUE pose (what the camera renders from: ``lat``, ``lon``,
        ``alt_amsl_m``, ``north_m``...), and beside it the estimator's position (``nav_*``: what telemetry reports
        and position control flies) and the GNSS bias part of their difference (``gnss_bias_enu_m``, East/North/Up;
        the rest is ``--gps-noise`` / glitch), so an evaluation can compare the two."""
        st = self.model.state
        lat, lon, alt = self.ned_to_geodetic(st.pos)
        nav_lat, nav_lon, nav_alt = self.ned_to_geodetic(self.nav)
        h = self.cfg.home
        return {
            "t_s": round(self.t, 4), "time_boot_ms": int(round(self.t * 1000)), "lat": lat, "lon": lon,
            "alt_amsl_m": alt, "north_m": float(st.pos[0]), "east_m": float(st.pos[1]), "down_m": float(st.pos[2]),
            "vn_m_s": float(st.vel[0]), "ve_m_s": float(st.vel[1]), "vd_m_s": float(st.vel[2]),
            "roll_deg": st.roll_deg, "pitch_deg": st.pitch_deg, "yaw_deg": st.yaw_deg,
            "gimbal_pitch_deg": self.gimbal_pitch_deg, "gimbal_yaw_deg": self.gimbal_yaw_deg,
            "armed": self.armed, "in_air": not st.on_ground,
            "nav_lat": nav_lat, "nav_lon": nav_lon, "nav_alt_amsl_m": nav_alt, "nav_north_m": float(self.nav[0]),
            "nav_east_m": float(self.nav[1]), "nav_down_m": float(self.nav[2]),
            "gnss_bias_enu_m": ned_to_enu(self.gnss_bias.ned),
            "home": {"lat": h.lat, "lon": h.lon, "alt_amsl_m": h.alt_amsl_m},
        }

    def _publish_truth(self) -> None:
        if self.pose_sock is None and self.truth_file is None:
            return
        line = json.dumps(self.true_pose())
        if self.pose_sock is not None:
            with contextlib.suppress(OSError):
                self.pose_sock.sendto(line.encode(), ("127.0.0.1", self.cfg.pose_port))
        if self.truth_file is not None:
            self.truth_file.write(line + "\n")

    # --- main loop -----------------------------------------------------------------------------------------
    def _update_outage(self) -> None:
        cfg = self.cfg
        if cfg.outage_at_s is None or cfg.outage_s <= 0:
            return
        now = time.monotonic()
        if self._outage_start_wall is None and self.t >= cfg.outage_at_s:
            self._outage_start_wall = now
            log.warning("link outage starts (%.1f s wall)", cfg.outage_s)
        if self._outage_start_wall is not None:
            down = now - self._outage_start_wall < cfg.outage_s
            if self.link.down and not down:
                log.warning("link outage ends")
            self.link.down = down

    def _parse(self, data: bytes) -> list:
        try:
            return self.mav.parse_buffer(data) or []
        except Exception:
            log.debug("unparseable datagram dropped")
            return []

    def stop(self) -> None:
        self._stop = True

    def run(self) -> None:
        speed = self.cfg.speedup
        t0 = time.monotonic()
        self.begin_boot()
        try:
            while not self._stop:
                now = time.monotonic()
                target = (now - t0) * speed
                steps = 0
                while self.t + DT_S <= target and steps < 50:
                    self.step(DT_S)
                    steps += 1
                if steps == 50:  # cannot keep up: slow the simulated clock down instead of jumping
                    t0 = now - self.t / speed
                self.update_init()
                self._update_outage()
                self.update_outage_after_takeoff()
                if self.update_reboot():
                    t0 = time.monotonic()
                for data in self.link.receive():
                    for msg in self._parse(data):
                        try:
                            self.handle(msg)
                        except Exception:  # a malformed request must not bring the vehicle down
                            log.exception("failed to handle %s", msg.get_type())
                self.missions.poll()
                self.send_streams()
                if self.cfg.duration_s is not None and self.t >= self.cfg.duration_s:
                    break
                wake = t0 + (self.t + DT_S) / speed
                due = self.link.next_due()
                if due is not None:
                    wake = min(wake, due)
                timeout = wake - time.monotonic()
                if timeout > 0:
                    select.select([self.link.sock], [], [], timeout)
        finally:
            self.close()

    def close(self) -> None:
        if self.truth_file is not None:
            self.truth_file.close()
            self.truth_file = None
        if self.pose_sock is not None:
            self.pose_sock.close()
            self.pose_sock = None
        self.link.close()

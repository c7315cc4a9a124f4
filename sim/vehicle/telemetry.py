"""Telemetry of the simulated vehicle: the MAVLink messages it streams, their rates, and on-request messages.

A mixin of ``SimVehicle`` (it reads the vehicle's state); kept apart so the message encodings, which must match
what mavsdk decodes, sit in one place. Rates are simulated-time Hz, capped in wall time (the CPU is shared).
"""

from __future__ import annotations

import logging
import math

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink  # common + ArduPilot messages

from companion.attitude import euler_to_quat
from sim.vehicle import flavours as fl
from sim.vehicle.model import GRAVITY

log = logging.getLogger(__name__)

REACHED_REPEATS = 3
# Streams whose time stamps real SITL disagreed on, seen on the link (a pymavlink listener beside the companion, PX4
# SIH at speed-up 4, paper-edge mission, 250 s): 509 of 59473 messages came more than 0.3 s of autopilot time behind
# the other stream's latest, 17 more than 1 s, 5 more than 2 s (at most 7.1 s), in both directions, each stream in
# order within itself. --stream-stall reproduces it: the stream is held back a while, then sent in order with its
# old stamps.
STALLING_STREAMS = ("ATTITUDE", "GLOBAL_POSITION_INT")
WALL_CAP_HZ = 25.0  # no stream faster than this in wall time, whatever the speed-up
SENSORS = (mavlink.MAV_SYS_STATUS_SENSOR_3D_GYRO | mavlink.MAV_SYS_STATUS_SENSOR_3D_ACCEL
           | mavlink.MAV_SYS_STATUS_SENSOR_3D_MAG | mavlink.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
           | mavlink.MAV_SYS_STATUS_SENSOR_GPS | mavlink.MAV_SYS_STATUS_SENSOR_ANGULAR_RATE_CONTROL
           | mavlink.MAV_SYS_STATUS_SENSOR_ATTITUDE_STABILIZATION | mavlink.MAV_SYS_STATUS_SENSOR_YAW_POSITION
           | mavlink.MAV_SYS_STATUS_SENSOR_Z_ALTITUDE_CONTROL | mavlink.MAV_SYS_STATUS_SENSOR_XY_POSITION_CONTROL
           | mavlink.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS | mavlink.MAV_SYS_STATUS_AHRS
           | mavlink.MAV_SYS_STATUS_SENSOR_BATTERY)
PREARM = mavlink.MAV_SYS_STATUS_PREARM_CHECK


class TelemetryStreams:
    """Message builders and the stream scheduler (mixed into SimVehicle)."""

    def _heartbeat(self):
        base = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | mavlink.MAV_MODE_FLAG_STABILIZE_ENABLED
        if self.mode in (fl.MISSION, fl.RTL, fl.LAND, fl.TAKEOFF, fl.HOLD):
            base |= mavlink.MAV_MODE_FLAG_AUTO_ENABLED | mavlink.MAV_MODE_FLAG_GUIDED_ENABLED
        if self.armed:
            base |= mavlink.MAV_MODE_FLAG_SAFETY_ARMED
        status = mavlink.MAV_STATE_ACTIVE if self.armed else mavlink.MAV_STATE_STANDBY
        if self.link_failsafe or self.battery_failsafe:
            status = mavlink.MAV_STATE_CRITICAL
        named = self.cfg.heartbeat_autopilot
        autopilot = self.flavour.autopilot if named is None else named
        custom = self.flavour.custom_mode(self.mode)
        return self.mav.heartbeat_encode(mavlink.MAV_TYPE_QUADROTOR, autopilot, base, custom, status)

    def _sys_status(self):
        health = SENSORS
        if self.gps.glitching(self.t):
            health &= ~mavlink.MAV_SYS_STATUS_SENSOR_GPS
        elif self.armed or (self.battery.remaining >= 0.2 and self.armable_now()):
            health |= PREARM
        b = self.battery
        return self.mav.sys_status_encode(SENSORS | PREARM, SENSORS | PREARM, health, 250,
                                          int(b.voltage_v * 1000), int(b.current_a * 100), int(b.remaining * 100),
                                          0, 0, 0, 0, 0, 0)

    def _global_position(self):
        lat, lon, alt = self.ned_to_geodetic(self.nav)
        v = self.model.state.vel
        return self.mav.global_position_int_encode(
            int(self.t * 1000), round(lat * 1e7), round(lon * 1e7), int(alt * 1000),
            int((-self.nav[2] - self.home_alt_shift_m) * 1000),  # above home as the autopilot has it now
            int(v[0] * 100), int(v[1] * 100), int(v[2] * 100), int(self.yaw_deg * 100) % 36000)

    def _gps_raw(self):
        lat, lon, alt = self.ned_to_geodetic(self.nav)
        v = self.model.state.vel
        cog = int((math.degrees(math.atan2(v[1], v[0])) % 360.0) * 100)
        fix = 2 if self.gps.glitching(self.t) else 3
        return self.mav.gps_raw_int_encode(int(self.t * 1e6), fix, round(lat * 1e7), round(lon * 1e7),
                                           int(alt * 1000), 80, 120, int(math.hypot(v[0], v[1]) * 100), cog, 14)

    def _attitude(self):
        st = self.model.state
        yaw = math.radians(((st.yaw_deg + 180.0) % 360.0) - 180.0)
        return self.mav.attitude_encode(int(self.t * 1000), math.radians(st.roll_deg), math.radians(st.pitch_deg),
                                         yaw, 0.0, 0.0, 0.0)

    def _attitude_q(self):
        st = self.model.state
        q = [float(v) for v in euler_to_quat(yaw_deg=st.yaw_deg, pitch_deg=st.pitch_deg, roll_deg=st.roll_deg)]
        return self.mav.attitude_quaternion_encode(int(self.t * 1000), *q, 0.0, 0.0, 0.0)

    def _local_position(self):
        v = self.model.state.vel
        n = self.nav
        return self.mav.local_position_ned_encode(int(self.t * 1000), n[0], n[1], n[2], v[0], v[1], v[2])

    def _home_position(self):
        h = self.cfg.home
        alt_mm = int((h.alt_amsl_m + self.home_alt_shift_m) * 1000)  # PX4 may have moved it in flight
        return self.mav.home_position_encode(round(h.lat * 1e7), round(h.lon * 1e7), alt_mm,
                                             0.0, 0.0, -self.home_alt_shift_m, [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0,
                                             int(self.t * 1e6))

    def _battery_status(self):
        b = self.battery
        cell_mv = int(b.voltage_v / b.cells * 1000)
        volts = [cell_mv] * b.cells + [65535] * (10 - b.cells)
        return self.mav.battery_status_encode(0, mavlink.MAV_BATTERY_FUNCTION_ALL, mavlink.MAV_BATTERY_TYPE_LIPO,
                                              32767, volts, int(b.current_a * 100), int(b.consumed_mah), -1,
                                              int(b.remaining * 100))

    def _mission_current_msg(self):
        total = len(self.mission)
        if total == 0:
            state = mavlink.MISSION_STATE_NO_MISSION
        elif self.mission_finished:
            state = mavlink.MISSION_STATE_COMPLETE
        elif self.mode == fl.MISSION:
            state = mavlink.MISSION_STATE_ACTIVE
        else:
            state = mavlink.MISSION_STATE_NOT_STARTED if self.reached_seq < 0 else mavlink.MISSION_STATE_PAUSED
        return self.mav.mission_current_encode(self.mission_seq if total else 0, total, state,
                                               1 if self.mode == fl.MISSION else 0)

    def _send_mission_current(self) -> None:
        self._send(self._mission_current_msg())

    def _vfr_hud(self):
        v = self.model.state.vel
        lat, lon, alt = self.ned_to_geodetic(self.nav)
        return self.mav.vfr_hud_encode(float(np.linalg.norm(v)), math.hypot(v[0], v[1]), int(self.yaw_deg),
                                       50 if self.armed else 0, alt, -v[2])

    def _extended_sys_state(self):
        return self.mav.extended_sys_state_encode(mavlink.MAV_VTOL_STATE_MC, self.landed_state())

    def _ekf_status(self):
        """ArduPilot's estimator report; mavsdk reads position health from it on ArduPilot."""
        flags = (mavlink.EKF_ATTITUDE | mavlink.EKF_VELOCITY_HORIZ | mavlink.EKF_VELOCITY_VERT
                 | mavlink.EKF_POS_HORIZ_REL | mavlink.EKF_POS_HORIZ_ABS | mavlink.EKF_POS_VERT_ABS
                 | mavlink.EKF_PRED_POS_HORIZ_REL | mavlink.EKF_PRED_POS_HORIZ_ABS)
        bad = 0.9 if self.gps.glitching(self.t) else 0.05
        if not self.position_ready:  # estimator not using GPS yet: attitude and relative position only
            flags = mavlink.EKF_ATTITUDE | mavlink.EKF_VELOCITY_VERT | mavlink.EKF_CONST_POS_MODE
        return self.mav.ekf_status_report_encode(flags, 0.05, bad, 0.05, 0.02, 0.0)

    def _distance_sensor(self):
        """The forward rangefinder's reading, measured from the TRUE position (not the estimate): centimetres, or
        max_distance + 1 when no wall is in range (MAVLink's 'no reading')."""
        rf = self.rangefinder
        st = self.model.state
        d = rf.measure(st.pos, st.yaw_deg, st.pitch_deg)
        max_cm = int(round(rf.max_m * 100))
        current = max_cm + 1 if d is None else int(round(d * 100))
        return self.mav.distance_sensor_encode(int(self.t * 1000), int(round(rf.min_m * 100)), max_cm, current,
                                               mavlink.MAV_DISTANCE_SENSOR_LASER, 0,
                                               mavlink.MAV_SENSOR_ROTATION_NONE,
                                               min(254, int(round((rf.noise_m * 100) ** 2))),
                                               signal_quality=1 if d is None else 100)

    def _truth_attitude(self) -> tuple[float, float, float, float, float, float, float, float, float]:
        """ArduPilot SITL's attitude fields (SIM::sim_state_send): roll, pitch and yaw in radians from the TRUE
        state, yaw wrapped the way ArduPilot does (degrees over 180 less 360); the body-frame accelerometer reading
        of gravity alone (the model keeps no acceleration) and body rates 0 (nor rates)."""
        st = self.model.state
        yaw = st.yaw_deg - 360.0 if st.yaw_deg > 180.0 else st.yaw_deg
        roll, pitch = math.radians(st.roll_deg), math.radians(st.pitch_deg)
        g = GRAVITY
        acc = (g * math.sin(pitch), -g * math.sin(roll) * math.cos(pitch), -g * math.cos(roll) * math.cos(pitch))
        return roll, pitch, math.radians(yaw), *acc, 0.0, 0.0, 0.0

    def _sim_state(self):
        """SIM_STATE (108) as ArduPilot SITL sends it: the simulator's TRUE state (``model.state``, never the
        estimate ``nav`` that a GNSS bias moves), with ArduPilot's quirks: ``lat``/``lon`` floats holding
        degrees * 1e7, the exact position in the int32 extensions ``lat_int``/``lon_int`` (truncated, as
        ``(int32_t)(lat * 1e7)``), ``alt`` metres AMSL, no standard deviations, NED velocity."""
        st = self.model.state
        lat, lon, alt = self.ned_to_geodetic(st.pos)
        roll, pitch, yaw, ax, ay, az, gx, gy, gz = self._truth_attitude()
        q = [float(v) for v in euler_to_quat(yaw_deg=st.yaw_deg, pitch_deg=st.pitch_deg, roll_deg=st.roll_deg)]
        v = st.vel
        return self.mav.sim_state_encode(*q, roll, pitch, yaw, ax, ay, az, gx, gy, gz, lat * 1e7, lon * 1e7,
                                         alt, 0.0, 0.0, float(v[0]), float(v[1]), float(v[2]),
                                         int(lat * 1e7), int(lon * 1e7))

    def _simstate(self):
        """SIMSTATE (164, ArduPilot dialect) as ArduPilot SITL sends it: true attitude and position (int32 degE7),
        no altitude."""
        lat, lon, _ = self.ned_to_geodetic(self.model.state.pos)
        return self.mav.simstate_encode(*self._truth_attitude(), int(lat * 1e7), int(lon * 1e7))

    def _autopilot_version(self):
        caps = (mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_INT | mavlink.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
                | mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2 | mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_FENCE
                | mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_RALLY)
        caps |= (mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE if self.flavour.param_bytewise
                 else mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_C_CAST)
        return self.mav.autopilot_version_encode(caps, self.flavour.sw_version, 0, 0, 0, [0] * 8, [0] * 8, [0] * 8,
                                                 0x26AC, 0x11, 1000 + self.cfg.seed)

    STREAMS = {
        "HEARTBEAT": "_heartbeat", "SYS_STATUS": "_sys_status", "GPS_RAW_INT": "_gps_raw",
        "GLOBAL_POSITION_INT": "_global_position", "LOCAL_POSITION_NED": "_local_position",
        "ATTITUDE": "_attitude", "ATTITUDE_QUATERNION": "_attitude_q", "HOME_POSITION": "_home_position",
        "EXTENDED_SYS_STATE": "_extended_sys_state", "BATTERY_STATUS": "_battery_status",
        "MISSION_CURRENT": "_mission_current_msg", "VFR_HUD": "_vfr_hud", "EKF_STATUS_REPORT": "_ekf_status",
        "DISTANCE_SENSOR": "_distance_sensor", "SIM_STATE": "_sim_state", "SIMSTATE": "_simstate",
    }

    def send_streams(self) -> None:
        floor = self.cfg.speedup / WALL_CAP_HZ
        for name, rate in self.rates.items():
            if rate <= 0 or name not in self.STREAMS:
                continue
            if name == "HOME_POSITION" and not self.position_ready:
                continue  # no home until the estimator uses GPS
            if name == "DISTANCE_SENSOR" and self.rangefinder is None:
                continue  # no rangefinder fitted
            if self.initialising and name != "HEARTBEAT":
                continue  # ArduPilot sends only HEARTBEAT while it starts up (should_send_message_in_delay_callback)
            due = self._next_due.get(name, 0.0)
            if self.t + 1e-9 < due:
                continue
            interval = max(1.0 / rate, floor)
            if name == "HEARTBEAT":
                interval = min(interval, self.cfg.speedup * 1.0)  # at least 1 Hz of wall time
            self._next_due[name] = self.t + interval
            self._send_stream(name, getattr(self, self.STREAMS[name])())
            if name == "MISSION_CURRENT" and self.reached_seq >= 0 and self.reached_repeats < REACHED_REPEATS:
                # Like PX4, repeat the last MISSION_ITEM_REACHED a few times: it is an event, and mavsdk only
                # reports a mission as finished (current == total) once it has seen the last one.
                self.reached_repeats += 1
                self._send(self.mav.mission_item_reached_encode(self.reached_seq))

    def _send_stream(self, name: str, msg) -> None:
        """Send a stream message, or hold it (in order) while that stream is stalled (``--stream-stall``)."""
        stall_s = self.cfg.stream_stall_s
        if stall_s <= 0 or name not in STALLING_STREAMS:
            self._send(msg)
            return
        held = self._held.setdefault(name, [])
        until, next_stall = self._stall_until, self._next_stall
        if name not in next_stall:
            next_stall[name] = self.t + self.stream_rng.exponential(self.cfg.stream_stall_every_s)
        if self.t < until.get(name, -1.0):
            held.append(msg)
            return
        for old in held:
            self._send(old)
        held.clear()
        self._send(msg)
        if self.t >= next_stall[name]:
            until[name] = self.t + self.stream_rng.uniform(0.25 * stall_s, stall_s)
            next_stall[name] = until[name] + self.stream_rng.exponential(self.cfg.stream_stall_every_s)

    def _known(self, name: str) -> bool:
        """A message this firmware sends: SIM_STATE / SIMSTATE only from a SITL that has them (flavour)."""
        return name in self.STREAMS and (name not in fl.SIM_STATE_MESSAGES or self.flavour.sim_state)

    def _requested(self, msg_id: int):
        if msg_id == mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION:
            return self._autopilot_version()
        if msg_id == mavlink.MAVLINK_MSG_ID_HOME_POSITION and not self.position_ready:
            return None
        if msg_id == mavlink.MAVLINK_MSG_ID_DISTANCE_SENSOR and self.rangefinder is None:
            return None
        cls = mavlink.mavlink_map.get(msg_id)
        if cls is not None and self._known(cls.msgname):
            return getattr(self, self.STREAMS[cls.msgname])()
        return None

    def _set_interval(self, msg_id: int, interval_us: float) -> bool:
        cls = mavlink.mavlink_map.get(msg_id)
        if cls is None or not self._known(cls.msgname):
            log.info("message interval for unsupported message %d (%s) refused", msg_id,
                     getattr(cls, "msgname", "unknown"))
            return False
        name = cls.msgname
        if interval_us < 0:
            self.rates[name] = 0.0
        elif interval_us == 0:
            self.rates[name] = fl.Px4.default_rates_hz.get(name, 1.0)
        else:
            self.rates[name] = 1e6 / interval_us
        self._next_due[name] = 0.0
        return True

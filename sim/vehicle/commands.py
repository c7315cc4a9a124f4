"""Incoming MAVLink of the simulated vehicle: commands (COMMAND_LONG/INT), parameters, TIMESYNC, stream requests.

A mixin of ``SimVehicle``: it turns requests into mode changes and state updates and ACKs them the way PX4 (or
ArduCopter) does, so mavsdk's retries and result codes behave as against a real autopilot.
"""

from __future__ import annotations

import logging
import math
import time

from pymavlink.dialects.v20 import ardupilotmega as mavlink  # common + ArduPilot messages

from sim.vehicle import flavours as fl
from sim.vehicle.firmware import counts_for_link_failsafe

log = logging.getLogger(__name__)

FORCE_MAGIC = 21196
MAV_RESULT_UNSUPPORTED_MAV_FRAME = 9  # MAV_RESULT_COMMAND_UNSUPPORTED_MAV_FRAME (PX4 sends 9; newer than pymavlink)


def _int(x: float, default: int = 0) -> int:
    """Integer value of a float command parameter; NaN (\"unset\") gives ``default``."""
    return int(x) if math.isfinite(x) else default


class CommandHandler:
    """Handles everything the GCS sends that is not mission protocol (mixed into SimVehicle)."""

    def handle(self, msg) -> None:
        t = msg.get_type()
        if t == "BAD_DATA" or msg.get_srcSystem() == self.cfg.system_id:
            return
        if counts_for_link_failsafe(self.flavour.name, self.params, msg, self.cfg.system_id):
            self.last_gcs_wall = time.monotonic()
        if t == "HEARTBEAT":
            if self.gcs is None:
                log.info("GCS heartbeat from system %d component %d", msg.get_srcSystem(), msg.get_srcComponent())
            self.gcs = (msg.get_srcSystem(), msg.get_srcComponent())
            return
        target = getattr(msg, "target_system", None)
        if target not in (None, 0, self.cfg.system_id):
            return
        if self.missions.handle(msg):
            return
        if t == "COMMAND_LONG":
            self._on_command(msg, msg.command, [msg.param1, msg.param2, msg.param3, msg.param4, msg.param5,
                                                msg.param6, msg.param7])
        elif t == "COMMAND_INT":
            if self.flavour.name == "px4" and msg.frame != mavlink.MAV_FRAME_GLOBAL_INT:
                # PX4 takes COMMAND_INT in MAV_FRAME_GLOBAL_INT only (mavlink_receiver.cpp
                # handle_message_command_int: "frame invalid for command"): its DO_SET_HOME in frame 0 went unheard
                return self._ack(msg, msg.command, MAV_RESULT_UNSUPPORTED_MAV_FRAME)
            self._on_command(msg, msg.command, [msg.param1, msg.param2, msg.param3, msg.param4, msg.x / 1e7,
                                                msg.y / 1e7, msg.z])
        elif t == "MISSION_SET_CURRENT":
            self._set_current(msg.seq)
        elif t == "PARAM_REQUEST_LIST":
            for i, name in enumerate(self.params):
                self._send_param(name, i)
        elif t == "PARAM_REQUEST_READ":
            self._on_param_read(msg)
        elif t == "PARAM_SET":
            self._on_param_set(msg)
        elif t == "TIMESYNC" and msg.tc1 == 0:
            self._send(self.mav.timesync_encode(int(self.t * 1e9), msg.ts1))
        elif t == "REQUEST_DATA_STREAM":
            for name, rate in fl.Px4.default_rates_hz.items():
                self.rates[name] = (rate if msg.req_message_rate <= 0 else max(rate, msg.req_message_rate)) \
                    if msg.start_stop else (1.0 if name == "HEARTBEAT" else 0.0)

    def _send_param(self, name: str, index: int) -> None:
        value, ptype = self.flavour.encode_param(self.params[name])
        self._send(self.mav.param_value_encode(name.encode(), value, ptype, len(self.params), index))

    def _on_param_read(self, msg) -> None:
        names = list(self.params)
        pid = msg.param_id.rstrip("\x00") if isinstance(msg.param_id, str) else msg.param_id.decode().rstrip("\x00")
        if msg.param_index >= 0:
            if msg.param_index < len(names):
                self._send_param(names[msg.param_index], msg.param_index)
        elif pid in self.params:
            self._send_param(pid, names.index(pid))

    def _on_param_set(self, msg) -> None:
        pid = msg.param_id.rstrip("\x00") if isinstance(msg.param_id, str) else msg.param_id.decode().rstrip("\x00")
        if pid not in self.params:
            return  # PX4 ignores unknown parameters; the client times out
        self.params[pid] = self.flavour.decode_param(msg.param_value, msg.param_type, self.params[pid])
        if pid == "MPC_XY_CRUISE":
            self.cruise_m_s = float(self.params[pid])
        self._send_param(pid, list(self.params).index(pid))

    def _set_current(self, seq: int) -> bool:
        if not self.flavour.first_seq <= seq < len(self.mission):
            return False
        self.mission_seq = seq
        self.mission_task = None
        self.mission_finished = False
        self.mission_prev = self.nav.copy()
        self._send_mission_current()
        self.save_storage()
        return True

    def _ack(self, msg, command: int, result: int) -> None:
        self._send(self.mav.command_ack_encode(command, result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent()))

    def _refused(self, msg, command: int, reason: str, result: int = mavlink.MAV_RESULT_DENIED) -> None:
        self.statustext(mavlink.MAV_SEVERITY_WARNING, reason)
        self._ack(msg, command, result)

    def _on_command(self, msg, cmd: int, p: list[float]) -> None:
        ok = mavlink.MAV_RESULT_ACCEPTED
        if cmd == mavlink.MAV_CMD_COMPONENT_ARM_DISARM:
            force = _int(p[1]) == FORCE_MAGIC
            reason = self.arm(force) if p[0] >= 0.5 else self.disarm(force)
            if reason:
                return self._refused(msg, cmd, reason)
            return self._ack(msg, cmd, ok)
        if cmd == mavlink.MAV_CMD_NAV_TAKEOFF:
            if self.flavour.name == "ardupilot":
                if self.mode != fl.GUIDED or not self.armed:
                    return self._refused(msg, cmd, "Takeoff needs GUIDED and armed")
                self.params["PILOT_TKOFF_ALT"] = float(p[6] if math.isfinite(p[6]) else 2.5) * 100.0
            elif math.isfinite(p[6]):
                self.params["MIS_TAKEOFF_ALT"] = float(p[6]) - self.cfg.home.alt_amsl_m
            reason = self.set_mode(fl.TAKEOFF)
            return self._refused(msg, cmd, reason) if reason else self._ack(msg, cmd, ok)
        if cmd == mavlink.MAV_CMD_DO_SET_MODE:
            mode = self.flavour.mode_from_set_mode(p[0], p[1], p[2])
            if mode is None:
                return self._ack(msg, cmd, mavlink.MAV_RESULT_UNSUPPORTED)
            if mode == self.mode and mode != fl.MISSION:
                return self._ack(msg, cmd, ok)
            reason = self.set_mode(mode)
            refused = self.flavour.mode_refused_result
            return self._refused(msg, cmd, reason, refused) if reason else self._ack(msg, cmd, ok)
        if cmd == mavlink.MAV_CMD_MISSION_START:
            if _int(p[0]) > 0 and not self._set_current(_int(p[0])):
                return self._ack(msg, cmd, mavlink.MAV_RESULT_DENIED)
            reason = self.set_mode(fl.MISSION)
            refused = self.flavour.mode_refused_result
            return self._refused(msg, cmd, reason, refused) if reason else self._ack(msg, cmd, ok)
        if cmd == mavlink.MAV_CMD_DO_PAUSE_CONTINUE:
            reason = self.set_mode(fl.MISSION if p[0] >= 0.5 else fl.HOLD)
            return self._refused(msg, cmd, reason) if reason else self._ack(msg, cmd, ok)
        if cmd == mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH:
            self.set_mode(fl.RTL)
            return self._ack(msg, cmd, ok)
        if cmd == mavlink.MAV_CMD_NAV_LAND:
            self.set_mode(fl.LAND)
            return self._ack(msg, cmd, ok)
        if cmd == mavlink.MAV_CMD_DO_CHANGE_SPEED:
            # the mission item's rules: ArduCopter's command handler takes types 2/3 as climb/descent speed too
            # (GCS_MAVLINK_Copter::handle_MAV_CMD_DO_CHANGE_SPEED), PX4 any type as the cruise speed
            self._mission_change_speed(_int(p[0]), p[1])
            return self._ack(msg, cmd, ok)
        if cmd == mavlink.MAV_CMD_DO_SET_HOME:
            accepted = self.set_home(p[0] >= 0.5, p[6])
            return self._ack(msg, cmd, ok if accepted else mavlink.MAV_RESULT_DENIED)
        if cmd == mavlink.MAV_CMD_DO_SET_MISSION_CURRENT:
            return self._ack(msg, cmd, ok if self._set_current(_int(p[0], -1)) else mavlink.MAV_RESULT_DENIED)
        if cmd == mavlink.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW:
            self._set_gimbal(p[0], p[1])
            return self._ack(msg, cmd, ok)
        if cmd == mavlink.MAV_CMD_DO_MOUNT_CONTROL:
            self._set_gimbal(p[0], p[2])
            return self._ack(msg, cmd, ok)
        if cmd == mavlink.MAV_CMD_CONDITION_YAW:
            self._condition_yaw(p[0], p[2], p[3])
            return self._ack(msg, cmd, ok)
        if cmd == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL:
            accepted = self._set_interval(_int(p[0], -1), p[1])
            return self._ack(msg, cmd, ok if accepted else mavlink.MAV_RESULT_UNSUPPORTED)
        if cmd in (mavlink.MAV_CMD_REQUEST_MESSAGE, mavlink.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES):
            msg_id = mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION
            if cmd == mavlink.MAV_CMD_REQUEST_MESSAGE:
                msg_id = _int(p[0], -1)
            reply = self._requested(msg_id)
            self._ack(msg, cmd, ok if reply is not None else mavlink.MAV_RESULT_UNSUPPORTED)
            if reply is not None and (not self.initialising or reply.get_type() == "AUTOPILOT_VERSION"):
                self._send(reply)  # while starting up, ArduPilot answers only AUTOPILOT_VERSION at once
            return None
        return self._ack(msg, cmd, mavlink.MAV_RESULT_UNSUPPORTED)

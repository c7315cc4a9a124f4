"""Firmware behaviours that decide how a flight starts and ends, as the real firmware does them (a SimVehicle mixin).

Each rule here was seen on real firmware in SITL (shared/notes/real-firmware.md; ArduCopter V4.7.0-dev, PX4 main of
2026-03) and is what the companion's supervision must survive:

* PX4 keeps its current mission item when an upload equals the stored mission (the ``current`` flag on item 0
  does not reset it), and across a restart: a re-fly after an interrupted flight resumes at the interrupted item
  unless the companion sets the current item itself. ArduCopter resets it to 1 on every upload.
* A reboot mid-flight (``--reboot-after-takeoff``): the link goes silent for a moment, then the vehicle is back on
  the ground, disarmed, with ``time_boot_ms`` restarting from 0 and (PX4) its stored mission and current item.
* A mission outside PX4's geofence (``--geofence-max-dist``, PX4's GF_MAX_HOR_DIST): the upload is accepted, the
  takeoff is refused at start with PX4's STATUSTEXTs ("Geofence violation for waypoint N", "Switching to Mission is
  currently not available") and the vehicle disarms on the ground (COM_DISARM_PRFLT).
* ArduCopter's EKF uses GPS only 35-40 s after boot: until then no home, no absolute position, and arming is
  refused with a "PreArm: ..." STATUSTEXT.
* ArduCopter starts up for about a second of wall time after each boot (real SITL at speed-ups 1 and 5): it sends
  HEARTBEAT only (no SYS_STATUS: ``AP_Vehicle::scheduler_delay_callback``) and, its mission storage not
  initialised, refuses any mission upload with NO_SPACE and "Only 0 items are supported"; then "ArduPilot Ready".
* The failsafe parameters with the firmware defaults (FS_GCS_ENABLE 0 and RTL_ALT 1500 cm on ArduCopter,
  NAV_DLL_ACT 0 and RTL_RETURN_ALT 30 m on PX4) and the lost-link action each of them selects. The link counts as
  lost by each firmware's own rule (``counts_for_link_failsafe``): ArduCopter counts only the GCS system id's
  heartbeats (MAV_GCS_SYSID, default 255; mavsdk's 245 does not count) for FS_GCS_TIMEOUT; PX4 any
  MAV_TYPE_GCS heartbeat, COM_DL_LOSS_T after its 2.5 s, and ignores the loss in modes COM_DLL_EXCEPT names.
* PX4 moves its home altitude in flight: for 120 s after take-off (commander HomePosition.cpp,
  ``kHomePositionCorrectionTimeWindow``, COM_HOME_EN 1) it shifts home by the barometer-vs-GPS altitude difference
  whenever that exceeds 1 m. The PX4 flavour does so by default, with SIH's sensor noise (``home_drift.py``: about
  140 moves in the window, swinging about +-1.5 m, ending wherever the last one put it, as real PX4 SIH did);
  ``--home-shift-m M [--home-shift-after-takeoff S]`` replaces that with one move of M metres S s after take-off
  (``--home-shift-m 0``: home stays where the vehicle armed). The ArduCopter flavour keeps home where it armed, as
  ArduCopter does. HOME_POSITION and the relative altitude report the new home, every mission item activated later
  flies its altitude above it, and PX4 sets home at the vehicle again when it arms (unless home was set by hand).
"""

from __future__ import annotations

import json
import logging
import math
import time
from pathlib import Path

import numpy as np
import pymap3d
from pymavlink.dialects.v20 import ardupilotmega as mavlink  # common + ArduPilot messages

from companion.mission import items as mi
from sim.vehicle import flavours as fl
from sim.vehicle.environment import Battery
from sim.vehicle.home_drift import Px4HomeCorrection
from sim.vehicle.model import Multirotor
from sim.vehicle.tasks import Hold

log = logging.getLogger(__name__)

# Real defaults (PX4 main 2026-03: commander/navigator params; ArduCopter 4.7: Parameters.cpp / notes).
FAILSAFE_DEFAULTS = {
    "px4": {"NAV_DLL_ACT": 0, "COM_DL_LOSS_T": 10, "RTL_RETURN_ALT": 30.0, "COM_DISARM_PRFLT": 10.0,
            "GF_MAX_HOR_DIST": 0.0, "COM_DLL_EXCEPT": 0},
    # MAV_GCS_SYSID: the only source system whose heartbeats the GCS failsafe counts (HI 0: no range; GCS.cpp)
    "ardupilot": {"FS_GCS_ENABLE": 0, "FS_GCS_TIMEOUT": 5.0, "RTL_ALT": 1500, "MAV_GCS_SYSID": 255,
                  "MAV_GCS_SYSID_HI": 0},
}
# Simulated seconds after boot before the estimator uses GPS (ArduCopter 4.7 SITL: 35-40 s; PX4 SIH: a few).
GPS_READY_AFTER_S = {"px4": 0.0, "ardupilot": 38.0}
COPTER_PREARM_NO_POSITION = "PreArm: Need Position Estimate"
COPTER_PREARM_GCS_FAILSAFE = "PreArm: GCS failsafe on"  # AP_Arming_Copter::gcs_failsafe_check
# Wall seconds from (re)boot until the autopilot has initialised. Real ArduCopter 4.7 SITL (-w, wiped storage): its
# first words ("ArduPilot Ready") came about 1 s after the first heartbeat at speed-up 1 and at 5 alike, so the
# start-up is wall time (storage and sensor set-up), not simulated time. PX4 SITL answers from its first heartbeat.
INIT_WALL_S = {"px4": 0.0, "ardupilot": 1.0}
COPTER_READY_TEXT = "ArduPilot Ready"


def lost_link_action(flavour: str, params: dict) -> str | None:
    """What the firmware does when the ground link is lost in a mission: 'rtl', 'land', 'hold' or None (flies on).

    PX4 NAV_DLL_ACT: 0 disabled, 1 hold, 2 return, 3 land, 5 terminate, 6 disarm. ArduCopter FS_GCS_ENABLE:
    0 disabled, 1 RTL, 2 continue in AUTO, 3/4 SmartRTL (RTL here), 5 land, 6 DO_LAND_START or RTL, 7 brake/land."""
    if flavour == "px4":
        return {1: "hold", 2: "rtl", 3: "land"}.get(int(params.get("NAV_DLL_ACT", 0)))
    return {1: "rtl", 3: "rtl", 4: "rtl", 5: "land", 6: "rtl", 7: "land"}.get(int(params.get("FS_GCS_ENABLE", 0)))


# PX4 keeps a GCS heartbeat alive this long (telemetry_status HEARTBEAT_TIMEOUT_US) before COM_DL_LOSS_T starts
PX4_HEARTBEAT_ALIVE_S = 2.5
# ArduPilot: these messages from a GCS system id reset the GCS failsafe timer (GCS_Common.cpp sysid_mygcs_seen)
COPTER_GCS_ALIVE_MESSAGES = frozenset({"HEARTBEAT", "RC_CHANNELS_OVERRIDE", "MANUAL_CONTROL"})
PX4_DLL_EXCEPT_MISSION, PX4_DLL_EXCEPT_AUTO = 1, 2  # COM_DLL_EXCEPT bits (commander_params.c)


def counts_for_link_failsafe(flavour: str, params: dict, msg, own_system: int) -> bool:
    """Whether ``msg`` keeps the lost-link failsafe from firing, as each firmware decides it.

    ArduCopter (``GCS_MAVLINK::handle_heartbeat``, ``Copter::failsafe_gcs_check``): a HEARTBEAT, RC override or
    MANUAL_CONTROL whose source system is a GCS id: MAV_GCS_SYSID (default 255), or MAV_GCS_SYSID ..
    MAV_GCS_SYSID_HI when HI is not below it. Anything from another system id (mavsdk's 245) does not count: real
    ArduCopter 4.7 flew on after the companion was killed. PX4 (``MavlinkReceiver::handle_message_heartbeat``): a
    HEARTBEAT of type MAV_TYPE_GCS from any system, or any HEARTBEAT from its own system id."""
    kind = msg.get_type()
    if flavour == "px4":
        return kind == "HEARTBEAT" and (msg.type == mavlink.MAV_TYPE_GCS or msg.get_srcSystem() == own_system)
    if kind not in COPTER_GCS_ALIVE_MESSAGES:
        return False
    low, high = int(params.get("MAV_GCS_SYSID", 255)), int(params.get("MAV_GCS_SYSID_HI", 0))
    src = msg.get_srcSystem()
    return low <= src <= high if high >= low else src == low


def link_loss_after_s(flavour: str, params: dict) -> float:
    """Seconds from the last counted heartbeat to the failsafe: ArduCopter FS_GCS_TIMEOUT (default 5); PX4
    COM_DL_LOSS_T (default 10) after the heartbeat's own 2.5 s (Commander::dataLinkCheck)."""
    if flavour == "px4":
        return float(params.get("COM_DL_LOSS_T", 10)) + PX4_HEARTBEAT_ALIVE_S
    return float(params.get("FS_GCS_TIMEOUT", 5.0))


def lost_link_ignored(flavour: str, params: dict, mode: str) -> bool:
    """PX4 ignores a lost link in Mission with COM_DLL_EXCEPT bit 0, in its other auto modes with bit 1
    (``Failsafe::isFailsafeIgnored``); ArduCopter has no such exception by default (FS_OPTIONS 0)."""
    if flavour != "px4":
        return False
    bits = int(params.get("COM_DLL_EXCEPT", 0))
    if mode == fl.MISSION:
        return bool(bits & PX4_DLL_EXCEPT_MISSION)
    return mode in (fl.HOLD, fl.TAKEOFF, fl.RTL, fl.LAND) and bool(bits & PX4_DLL_EXCEPT_AUTO)


def _same_items(a: list, b: list) -> bool:
    """Equal missions as PX4 compares them: every field but the ``current`` flag (NaN equals NaN)."""
    if len(a) != len(b):
        return False
    for x, y in zip(a, b, strict=True):
        for name in ("seq", "frame", "command", "autocontinue", "param1", "param2", "param3", "param4", "x", "y",
                     "z"):
            u, v = getattr(x, name), getattr(y, name)
            if u != v and not (isinstance(u, float) and isinstance(v, float) and math.isnan(u) and math.isnan(v)):
                return False
    return True


class FirmwareRules:
    """Mixed into SimVehicle: the start/stop behaviours above, each in its own method."""

    def _init_firmware_rules(self) -> None:
        self.params.update(FAILSAFE_DEFAULTS[self.flavour.name])
        if self.cfg.geofence_max_dist_m is not None:
            self.params["GF_MAX_HOR_DIST"] = float(self.cfg.geofence_max_dist_m)
        delay = self.cfg.gps_ready_after_s
        self.gps_ready_after_s = GPS_READY_AFTER_S[self.flavour.name] if delay is None else float(delay)
        self.boot_count = 0
        self.mission_refused = False
        self.armed_at: float | None = None
        self._reboot_wall: float | None = None
        self._takeoff_t: float | None = None
        self._outage_wall: float | None = None
        self._init_until_wall: float | None = None
        self._mission_capacity = self.missions.max_items
        self.home_alt_shift_m = 0.0  # how far PX4 has moved home's altitude from the take-off ground (up positive)
        self._home_shift_done = False  # the scheduled move happened (a later DO_SET_HOME does not undo the schedule)
        self.manual_home = False  # home set by DO_SET_HOME at a given altitude: PX4 keeps it at the next arming
        modelled = self.flavour.name == "px4" and self.cfg.home_shift_m is None
        # its own random draws (seed + 5): the other faults keep their sequences
        self.home_correction = Px4HomeCorrection(np.random.default_rng(self.cfg.seed + 5)) if modelled else None
        self._load_storage()

    # --- start-up after each boot (ArduCopter: about 1 s of wall time) ---------------------------------------
    @property
    def initialising(self) -> bool:
        """Still starting up: HEARTBEAT only, and no room for a mission (ArduPilot's storage is not initialised)."""
        return self._init_until_wall is not None

    def begin_boot(self) -> None:
        """The autopilot process starts (``run()``) or restarts (``reboot()``)."""
        init_s = INIT_WALL_S[self.flavour.name] if self.cfg.init_s is None else float(self.cfg.init_s)
        if init_s <= 0:
            return
        if self._init_until_wall is None:
            self._mission_capacity = self.missions.max_items
        self._init_until_wall = time.monotonic() + init_s
        self.missions.max_items = 0  # MissionItemProtocol: max_items() is 0 until AP_Mission::init()
        log.info("starting up for %.1f s (wall): heartbeat only, mission uploads refused", init_s)

    def update_init(self) -> None:
        if self._init_until_wall is None or time.monotonic() < self._init_until_wall:
            return
        self._init_until_wall = None
        self.missions.max_items = self._mission_capacity
        if self.flavour.name == "ardupilot":
            self.statustext(mavlink.MAV_SEVERITY_INFO, COPTER_READY_TEXT)
        log.info("initialised")

    # --- estimator readiness (ArduCopter: 35-40 s after boot) -----------------------------------------
    @property
    def position_ready(self) -> bool:
        return self.t >= self.gps_ready_after_s

    def prearm_refusal(self) -> str | None:
        """The firmware's refusal text: the estimator not using GPS yet, (PX4) Mission mode without a valid
        mission, which PX4 does not arm in, or (ArduCopter) its GCS failsafe on."""
        if not self.position_ready:
            return COPTER_PREARM_NO_POSITION if self.flavour.name == "ardupilot" else "Preflight Fail: No position"
        if self.flavour.name == "px4" and self.mode == fl.MISSION and (not self.mission or self.mission_refused):
            return "Arming denied: no valid mission"
        if self.flavour.name == "ardupilot" and self.link_failsafe:
            return COPTER_PREARM_GCS_FAILSAFE
        return None

    def armable_now(self) -> bool:
        """SYS_STATUS pre-arm bit (mavsdk's ``is_armable``): false in a mode the firmware does not arm in."""
        return self.flavour.arm_refusal(self.mode) is None and self.prearm_refusal() is None

    # --- current item kept across an identical upload (PX4) ------------------------------------------
    def keeps_current_on_upload(self, new_items: list) -> bool:
        """PX4 keeps the current item when the new mission equals the stored one (and it is inside the mission)."""
        return (self.flavour.name == "px4" and bool(self.mission) and _same_items(self.mission, new_items)
                and 0 <= self.mission_seq < len(new_items))

    # --- storage across a restart of the simulator process (PX4 dataman) -----------------------------
    def _load_storage(self) -> None:
        path = self.cfg.storage
        if path is None or not Path(path).exists() or self.flavour.name != "px4":
            return
        data = json.loads(Path(path).read_text())
        items = [mi.MissionItem(**d) for d in data.get("mission", [])]
        self.missions.lists[0] = items
        self.mission = items
        self.mission_seq = int(data.get("current", 0)) if items else 0
        log.info("restored %d mission items from %s, current item %d", len(items), path, self.mission_seq)

    def save_storage(self) -> None:
        path = self.cfg.storage
        if path is None or self.flavour.name != "px4":
            return
        data = {"mission": [it.__dict__ for it in self.mission], "current": self.mission_seq}
        Path(path).write_text(json.dumps(data, allow_nan=True))

    # --- geofence feasibility at start (PX4) ----------------------------------------------------------
    def geofence_violation(self) -> int | None:
        """1-based number of the first positional item beyond GF_MAX_HOR_DIST from home, as PX4 reports it."""
        limit = float(self.params.get("GF_MAX_HOR_DIST", 0.0))
        if self.flavour.name != "px4" or limit <= 0:
            return None
        h = self.cfg.home
        for i, it in enumerate(self.mission):
            if it.frame not in fl.GLOBAL_FRAMES or (it.x == 0 and it.y == 0):
                continue
            n, e, _ = pymap3d.geodetic2ned(it.x / 1e7, it.y / 1e7, h.alt_amsl_m, h.lat, h.lon, h.alt_amsl_m)
            if math.hypot(n, e) > limit:
                return i + 1
        return None

    def refuse_infeasible_start(self) -> bool:
        """PX4 at mission start on the ground: a mission that fails the feasibility check is not flown; the
        takeoff is refused with PX4's messages and the armed vehicle disarms after COM_DISARM_PRFLT."""
        bad = self.geofence_violation()
        if bad is None:
            return False
        # real PX4 main (2026-03) SITL, GF_MAX_HOR_DIST 5 m: these two, CRITICAL, each ending in a tab (PX4's events
        # marker); the mode switch itself was acknowledged (the companion's start command did not fail)
        self.statustext(mavlink.MAV_SEVERITY_CRITICAL, f"Geofence violation for waypoint {bad}\t")
        self.statustext(mavlink.MAV_SEVERITY_CRITICAL, "Switching to Mission is currently not available\t")
        self.mission_refused = True
        return True

    def preflight_disarm(self) -> None:
        """PX4 disarms an armed vehicle that has not taken off after COM_DISARM_PRFLT s. Modelled for a refused
        mission only: at high speed-ups a general 10 s (simulated) timer would race the companion's start command."""
        if not (self.armed and self.mission_refused and self.on_ground and not self.took_off):
            return
        if self.armed_at is not None and self.t - self.armed_at >= float(self.params.get("COM_DISARM_PRFLT", 10.0)):
            self.disarm()
            self.statustext(mavlink.MAV_SEVERITY_INFO, "Disarmed by auto preflight disarming")

    # --- faults timed from the take-off (reproducible whatever the companion's start-up took) -------------
    def seconds_since_takeoff(self) -> float | None:
        if self._takeoff_t is None and self.took_off:
            self._takeoff_t = self.t
        return None if self._takeoff_t is None else self.t - self._takeoff_t

    def update_outage_after_takeoff(self) -> None:
        """``--outage-after-takeoff S``: the link goes down S simulated seconds after take-off, for ``outage_s``
        wall seconds (a very long one is a link that never comes back)."""
        cfg = self.cfg
        if cfg.outage_after_takeoff_s is None:
            return
        since = self.seconds_since_takeoff()
        now = time.monotonic()
        if self._outage_wall is None:
            if since is None or since < cfg.outage_after_takeoff_s:
                return
            self._outage_wall = now
            log.warning("link outage starts %.1f s after take-off (%.1f s wall)", since, cfg.outage_s)
        down = now - self._outage_wall < cfg.outage_s
        if self.link.down and not down:
            log.warning("link outage ends")
        self.link.down = down

    def update_home_shift(self) -> None:
        """PX4's in-flight home correction: by default SIH's (``home_drift.py``), or the one move
        ``--home-shift-m M --home-shift-after-takeoff S`` asks for (S simulated seconds after take-off)."""
        if self.home_correction is not None:
            self._update_modelled_home()
            return
        cfg = self.cfg
        if cfg.home_shift_after_takeoff_s is None or self._home_shift_done or not cfg.home_shift_m:
            return
        since = self.seconds_since_takeoff()
        if since is None or since < cfg.home_shift_after_takeoff_s:
            return
        self._home_shift_done = True
        self.home_alt_shift_m = float(cfg.home_shift_m)
        log.warning("home altitude moved by %+.2f m %.1f s after take-off (PX4's baro/GPS home correction)",
                    self.home_alt_shift_m, since)

    def _update_modelled_home(self) -> None:
        st = self.model.state
        in_air = self.armed and self.took_off
        before = self.home_correction.moves
        move = self.home_correction.step(self.t, self.cfg.home.alt_amsl_m - float(st.pos[2]), float(st.vel[2]), in_air)
        if move:
            self.home_alt_shift_m += move
            self.manual_home = False  # PX4's correction clears the manual flag (HomePosition::update)
            if before == 0:
                log.warning("PX4 home correction: home's altitude moves with SIH's GPS noise for %g s after "
                            "take-off (first move %+.2f m)", self.home_correction.window_s, move)
            log.debug("home altitude moved by %+.2f m, now %+.2f m from the take-off ground", move,
                      self.home_alt_shift_m)

    def on_arm_home(self) -> None:
        """PX4 sets home at the vehicle when it arms, unless home was set by hand (Commander: ``manual_home``); its
        correction window starts again at the next take-off."""
        if self.flavour.name != "px4":
            return
        if not self.manual_home:
            self.home_alt_shift_m = 0.0
        if self.home_correction is not None:
            self.home_correction.reset()

    def set_home(self, use_current: bool, alt_amsl_m: float) -> bool:
        """MAV_CMD_DO_SET_HOME: home's altitude at the vehicle's (param1 1) or at ``alt_amsl_m`` (param1 0; PX4's
        ``HomePosition::setManually``). The simulator keeps home's horizontal place (the take-off point): only the
        altitude moves, which is what relative mission altitudes follow. False for a non-finite altitude (PX4:
        DENIED)."""
        if use_current:
            self.home_alt_shift_m = -float(self.nav[2])
        elif math.isfinite(alt_amsl_m):
            self.home_alt_shift_m = float(alt_amsl_m) - self.cfg.home.alt_amsl_m
        else:
            return False
        self.manual_home = not use_current
        log.info("home set at %.2f m AMSL (%+.2f m from the take-off ground)",
                 self.cfg.home.alt_amsl_m + self.home_alt_shift_m, self.home_alt_shift_m)
        return True

    # --- reboot mid-flight ----------------------------------------------------------------------------
    def update_reboot(self) -> bool:
        """Runs the scheduled reboot: silence on the link for ``reboot_s`` wall seconds, then a fresh boot.
        Returns True at the moment the vehicle boots again (the caller restarts its clock)."""
        cfg = self.cfg
        if cfg.reboot_after_takeoff_s is None or self.boot_count > 0:
            return False
        since = self.seconds_since_takeoff()
        now = time.monotonic()
        if self._reboot_wall is None:
            if since is None or since < cfg.reboot_after_takeoff_s:
                return False
            self._reboot_wall = now
            self.link.down = True
            log.warning("autopilot reboot at %.1f s (link silent for %.1f s wall)", self.t, cfg.reboot_s)
            return False
        if now - self._reboot_wall < cfg.reboot_s:
            return False
        self.reboot()
        self.link.down = False
        return True

    def reboot(self) -> None:
        """A fresh boot: on the ground at home, disarmed, clocks from 0, streams at the firmware defaults; the
        stored mission (and on PX4 its current item) survive, as they do in the firmware's storage."""
        self.boot_count += 1
        self.model = Multirotor(self.cfg.limits)
        self.model.state.yaw_deg = self.cfg.home_yaw_deg % 360.0
        self.nav = self.model.state.pos.copy()
        self.t = 0.0
        self.armed = False
        self.took_off = False
        self.landed_since = None
        self.armed_at = None
        self.mode = fl.HOLD if self.flavour.name == "px4" else fl.POSCTL
        self.task = Hold(self.model.state.pos)
        self.yaw_target = None
        self.mission_task = None
        self.mission_prev = None
        self.mission_refused = False
        self.link_failsafe = self.battery_failsafe = False
        self.last_gcs_wall = None  # a restarted firmware has seen no GCS yet (Copter: gcs_last_seen_ms 0)
        self.battery = Battery()
        self.rates = dict(self.flavour.default_rates_hz)
        self._next_due = {}
        self._held, self._stall_until, self._next_stall = {}, {}, {}  # a new boot: no stream is held back
        if self.flavour.name != "px4":
            self.mission_seq = self.flavour.first_seq
        self.begin_boot()
        log.warning("autopilot booted again (boot %d): mission of %d items, current item %d", self.boot_count + 1,
                    len(self.mission), self.mission_seq)

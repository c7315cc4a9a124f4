"""Fly a planned mission: connect, check health, upload + verify, arm, start, supervise to landed + disarmed.

Supervision rules (why they look like this; docs/FLIGHT.md "Supervision"):
  * the autopilot flies the mission; the companion only watches, records and steps in on request, so a dead
    companion or a cut link never leaves the vehicle without a plan (its own link-loss failsafe decides);
  * every flight starts from its first item, set and read back before the start (PX4 keeps its current item
    across an identical upload and a restart);
  * progress is never trusted across an autopilot restart (time since boot going backwards): that flight failed;
  * every ending is bounded and said: a start the vehicle refuses (it disarms on the ground, or reports a critical
    error before taking off) ends within seconds; a link silent for ``link_loss_s`` is counted as a loss, one
    silent for ``link_dead_s`` ends supervision as failed; a timeout commands RTL; a failed RTL is reported;
  * the autopilot's home altitude is watched (mission altitudes are relative to it and PX4 moves it in flight):
    each move of more than 0.3 m is said; one that brings a waypoint still ahead under 1 m above the take-off
    ground ends the scan (pause, RTL) as failed (``home_watch.py``), once home has settled when the plan holds
    above the wall for it (PX4); home is put back where it was at arming after the autopilot's correction window
    (and handed back after landing) only when a SITL profile asks for it (``sitl_profile.py``: PX4 SIH, whose GPS
    altitude noise is white, so its moves are noise): the same flight on a simulator as on a vehicle otherwise;
  * SIGINT/SIGTERM: pause (hold), then RTL, then wait at most ``stop_wait_s`` for landed + disarmed (said, with the
    time left); a second signal stops waiting.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import signal
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path

from companion.errors import CompanionError
from companion.flight.connection import (
    Vehicle,
    check_home,
    connect,
    request_rates,
    wait_healthy,
    wait_initialised,
)
from companion.flight.failsafe import failsafe_overrides, failsafe_warnings, read_failsafe, required_return_alt
from companion.flight.home_watch import HomeWatch, settle_item_seq
from companion.flight.limits import FLIGHT_DEFAULTS
from companion.flight.link_watch import link_watch_overrides, until_heartbeat_counted
from companion.flight.parameters import FlightParameters, ParamChange
from companion.flight.progress import WaypointProgress
from companion.flight.restore import restore_before_flight
from companion.flight.sitl_profile import SitlProfile
from companion.flight.standoff_control import StandoffCorrection, StandoffSummary
from companion.flight.standoff_loop import StandoffLoop, StandoffOptions, settings_for
from companion.flight.start import arm_with_reason, select_arming_mode, start_from_first_item, start_with_reason
from companion.flight.status_texts import StatusTexts
from companion.flight.telemetry_log import PlannedGimbal, TelemetryRecorder
from companion.flight.upload import upload_and_verify
from companion.mission import items as mi
from companion.mission.autopilot import Autopilot, autopilot_for
from companion.records import StandoffEstimate

log = logging.getLogger(__name__)

_ENDS_ON_GROUND = {mi.MAV_CMD_NAV_LAND, mi.MAV_CMD_NAV_RETURN_TO_LAUNCH}
MAV_CMD_DO_SET_HOME = 179
# STATUSTEXT severities that, before take-off, mean the vehicle refuses to fly the mission (real PX4: "Geofence
# violation for waypoint N", "Switching to Mission is currently not available" are CRITICAL)
_REFUSAL_SEVERITIES = {"EMERGENCY", "ALERT", "CRITICAL", "ERROR"}
REFUSAL_GRACE_S = 1.0  # after the first refusal text, collect the ones that follow before ending


@dataclass(frozen=True)
class LinkLoss:
    started_s: float  # seconds after the mission start (wall)
    duration_s: float
    closed: bool = True  # False: the link had not come back when supervision ended


class FlightAbort(StrEnum):
    """Why supervision ended a flight early (``FlightResult.aborted``). An enum so that the flight's ending and its
    callers compare members; a StrEnum so that messages and logs print the same word as before."""

    SIGNAL = "signal"  # a stop request (Ctrl-C, SIGTERM)
    TIMEOUT = "timeout"  # longer than the flight limit
    FAILSAFE = "failsafe"  # landed early
    REBOOT = "reboot"  # the autopilot restarted
    LINK = "link"  # silent longer than the limit
    HOME = "home"  # home moved so low that a waypoint ahead nears the ground
    STANDOFF = "standoff"  # below the safety floor and not recovered, or a correction that could not be made
    REFUSED = "refused"  # the vehicle refused the mission start


@dataclass
class FlightResult:
    """What happened. ``completed``: every mission item was reached and the vehicle ended landed + disarmed.

    ``aborted``: 'signal', 'timeout', 'failsafe' (landed early), 'reboot' (the autopilot restarted), 'link' (silent
    longer than the limit), 'home' (the autopilot moved home so low that a waypoint ahead nears the ground),
    'standoff' (measured below the safety floor and not recovered, or a correction that could not be made) or
    None; ``problem`` says it in words for a person."""

    completed: bool
    landed: bool
    disarmed: bool
    aborted: FlightAbort | None
    items_total: int
    items_reached: int
    autopilot: str
    duration_s: float
    telemetry_samples: int
    link_losses: list[LinkLoss] = field(default_factory=list)
    telemetry_log: Path | None = None
    status_texts: list[str] = field(default_factory=list)
    problem: str | None = None
    waypoints_total: int = 0
    waypoints_reached: int = 0
    parameter_changes: list[ParamChange] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    # the standoff measured on the scan legs and the corrections made (None: not a scan plan, or not watched)
    standoff: StandoffSummary | None = None
    standoff_corrections: list[StandoffCorrection] = field(default_factory=list)


_SIGNAL_SOURCES = {"SIGINT": "Ctrl-C", "SIGTERM": "kill or a service manager"}


def stop_request_text(signum: int | None, count: int) -> str:
    """The log line for a stop request, naming the signal (SIGINT, SIGTERM: never a bare number, which read as
    signal 1, SIGHUP, when it was the first request) and what the companion does about it."""
    try:
        name = signal.Signals(signum).name if signum is not None else None
    except ValueError:
        name = f"signal {signum}"
    by = f" by {name}" + (f" ({_SIGNAL_SOURCES[name]})" if name in _SIGNAL_SOURCES else "") if name else ""
    if count <= 1:
        return f"stop requested{by}: pausing, then returning to launch"
    return f"stop requested again{by}: no longer waiting for the landing"


def _down_and_disarmed(state: Mapping) -> bool:
    """Landed and disarmed: nothing to correct any more."""
    return state.get("armed") is False and state.get("in_air") is False


def mission_items_for(plan, autopilot: str) -> list[mi.MissionItem]:
    """The raw items to upload: a ScanPlan (``plan.mavlink_items(flavour)``) or a ready list of MissionItems."""
    if hasattr(plan, "mavlink_items"):
        return list(plan.mavlink_items(flavour=autopilot))
    items = list(plan)
    if not all(isinstance(it, mi.MissionItem) for it in items):
        raise CompanionError("fly_mission needs a ScanPlan or a list of MissionItem",
                             "pass plan_scan(load_mission(path)) or the plan's mavlink_items()")
    return items


async def _retry(what: str, coro_fn, attempts: int = 3):
    """mavsdk already retransmits commands; this covers a whole command timing out on a very lossy link."""
    for i in range(attempts):
        try:
            return await coro_fn()
        except Exception as exc:
            if i == attempts - 1:
                raise CompanionError(f"{what} failed: {exc}",
                                     "check the vehicle's status messages and the link, then retry") from exc
            log.warning("%s failed (%s), retrying", what, exc)
            await asyncio.sleep(0.5)
    return None


class _Supervisor:
    def __init__(self, vehicle: Vehicle, items: Sequence[mi.MissionItem], rec: TelemetryRecorder, *,
                 link_loss_s: float, flight_timeout_s: float, end_action: str, progress: bool,
                 link_dead_s: float = 60.0, stop_wait_s: float = 180.0, first_seq: int = 0,
                 telemetry_rate_hz: float | None = None, home_watch: HomeWatch | None = None,
                 standoff: StandoffLoop | None = None):
        self.v = vehicle
        self.items = items
        self.rec = rec
        self.link_loss_s = link_loss_s
        self.link_dead_s = link_dead_s
        self.flight_timeout_s = flight_timeout_s
        self.stop_wait_s = stop_wait_s
        self.end_action = end_action
        self.progress = WaypointProgress(items, first_seq, enabled=progress)
        self.signalled = asyncio.Event()
        self.signal_count = 0
        self.link_losses: list[LinkLoss] = []
        self.lost_since: float | None = None
        self.t0 = time.monotonic()
        self.texts_from = self.t0  # refusal texts count from here (before arming: they can beat the start's ACK)
        self.max_reached = 0
        self.problems: list[str] = []
        self.telemetry_rate_hz = telemetry_rate_hz
        self._rerequest: asyncio.Task | None = None
        self._rerequested_at = 0.0
        self.home = home_watch if home_watch is not None else HomeWatch(items)
        self.takeoff_boot_s: float | None = None  # the autopilot's time since boot when it was first seen flying
        self.home_latlon_before_arming: tuple[float, float] | None = None
        self.standoff = standoff

    def on_signal(self, signum: int | None = None) -> None:
        self.signal_count += 1
        self.signalled.set()
        log.warning("%s", stop_request_text(signum, self.signal_count))

    @property
    def problem(self) -> str | None:
        """Everything that went wrong, first (the one that ended the flight) first; None when nothing did."""
        return "; then ".join(self.problems) if self.problems else None

    def _fail(self, text: str) -> None:
        log.error("%s", text)
        self.problems.append(text)

    def _track_link(self, now: float) -> float:
        """Count link losses; returns the current gap in seconds."""
        last = self.rec.last_sample_wall
        gap = now - last if last is not None else now - self.t0
        if gap > self.link_loss_s and self.lost_since is None:
            self.lost_since = last if last is not None else self.t0
            log.warning("link lost: no telemetry for %.1f s; the vehicle continues on its own (its failsafe "
                        "decides); supervision ends if it stays silent for %.0f s", gap, self.link_dead_s)
        elif self.lost_since is not None and gap > self.link_loss_s:
            self._ask_for_telemetry_again(now)
        elif gap <= self.link_loss_s and self.lost_since is not None:
            self.link_losses.append(LinkLoss(self.lost_since - self.t0, now - self.lost_since))
            log.warning("link restored after %.1f s; resuming supervision", now - self.lost_since)
            self.lost_since = None
        return gap

    def _ask_for_telemetry_again(self, now: float, every_s: float = 5.0) -> None:
        """While silent, ask for the streams again now and then (in the background): an ArduPilot that restarted
        streams nothing but HEARTBEAT until asked, and only its telemetry can show the restart."""
        if self.telemetry_rate_hz is None or now - self._rerequested_at < every_s:
            return
        if self._rerequest is not None and not self._rerequest.done():
            return
        self._rerequested_at = now
        self._rerequest = asyncio.create_task(self._request_time_streams())

    async def _request_time_streams(self) -> None:
        t, hz = self.v.telemetry, self.telemetry_rate_hz
        for setter in (t.set_rate_position, t.set_rate_attitude_euler):  # GLOBAL_POSITION_INT, ATTITUDE
            with contextlib.suppress(Exception):
                await setter(hz)

    async def finish_background(self) -> None:
        """Wait for a stream request still in flight: mavsdk's call runs in a worker thread that never returns if
        mavsdk is destroyed under it (the process would hang at exit). Each call ends by its own timeout."""
        if self._rerequest is not None:
            with contextlib.suppress(Exception, asyncio.CancelledError):
                await self._rerequest

    def close_open_loss(self) -> None:
        """A loss still open when supervision ends is a loss too (counted, marked open)."""
        if self.lost_since is not None:
            now = time.monotonic()
            self.link_losses.append(LinkLoss(self.lost_since - self.t0, now - self.lost_since, closed=False))
            self.lost_since = None

    def _refusal_texts(self, since: float) -> list[str]:
        return [f"{sev}: {text}" for t, sev, text in self.rec.status_events
                if t >= since and sev in _REFUSAL_SEVERITIES]

    async def run(self) -> FlightAbort | None:
        """Returns the abort reason or None."""
        st = self.rec.state
        total = len(self.items)
        airborne = False
        end_sent = False
        refusal_seen: float | None = None
        ends_on_ground = self.items[-1].command in _ENDS_ON_GROUND
        try:
            while True:
                now = time.monotonic()
                gap = self._track_link(now)
                if self.signalled.is_set():
                    return FlightAbort.SIGNAL
                if self.rec.reboot is not None:
                    self._fail(f"{self.rec.reboot}; mission progress after a restart cannot be trusted (the vehicle "
                               f"had reached item {self.max_reached} of {total}); the flight failed")
                    return FlightAbort.REBOOT
                if self.lost_since is not None and gap > self.link_dead_s:
                    self._fail(f"no telemetry for {gap:.0f} s (limit {self.link_dead_s:g} s): supervision ends; "
                               f"the vehicle is on its own and its lost-link failsafe decides")
                    return FlightAbort.LINK
                if now - self.t0 > self.flight_timeout_s:
                    self._fail(f"flight took longer than {self.flight_timeout_s:.0f} s: returning to launch")
                    await self._rtl_and_wait(timeout_s=min(self.stop_wait_s, 120.0))
                    return FlightAbort.TIMEOUT
                if self.lost_since is None:
                    current = max(0, int(st["mission_item"]))
                    self.max_reached = max(self.max_reached, min(current, total))
                    self.progress.update(self.max_reached, f"item {self.max_reached}/{total}")
                    if st["in_air"] or self.rec.was_in_air:  # latched: the flight may predate this loop
                        airborne = True
                    if await self._home_moved_too_low(current, airborne):
                        return FlightAbort.HOME
                    if airborne and await self._standoff_failed(current):
                        return FlightAbort.STANDOFF
                    if not airborne:
                        reason = self._start_refused(refusal_seen, now)
                        if reason is not None:
                            return reason
                        if refusal_seen is None and self._refusal_texts(self.texts_from):
                            refusal_seen = now
                    done = self.max_reached >= total
                    if done and st["in_air"] and not ends_on_ground and not end_sent:
                        end_sent = True
                        log.info("mission complete; %s", "returning to launch" if self.end_action == "rtl"
                                 else "landing")
                        action = self.v.action.return_to_launch if self.end_action == "rtl" else self.v.action.land
                        try:
                            await _retry(self.end_action, action)
                        except CompanionError as exc:
                            self._fail(f"the mission ended in the air and {exc.problem}: the vehicle hovers at the "
                                       f"last waypoint; take control from the ground station")
                    if airborne and st["armed"] is False and st["in_air"] is False:
                        if not done and ends_on_ground and self.max_reached >= total - 1:
                            # Down and disarmed while executing the final LAND/RTL item: that item is complete
                            # even if its MISSION_ITEM_REACHED was lost on the link.
                            self.max_reached = total
                            self.progress.update(total)
                            done = True
                        if not done:
                            self._fail(f"the vehicle landed and disarmed at item {self.max_reached} of {total} "
                                       "(a failsafe or the pilot ended the mission early)")
                        return None if done else FlightAbort.FAILSAFE
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(self.signalled.wait(), 0.1)
        finally:
            self.close_open_loss()
            self.progress.close()

    async def _home_moved_too_low(self, current_seq: int, airborne: bool) -> bool:
        """Feed the latest home altitude to the watch; when its move puts a waypoint ahead too near the ground, end
        the scan now, while the vehicle is still clear of it (pause, RTL, wait for the landing)."""
        before = self.rec.home_before_air_m  # home at arming (PX4 sets it again when it arms)
        if not self.home.airborne and before is not None and before != self.home.home_now_m:
            self.home.on_home(before)
        if airborne and not self.home.airborne:
            self.home.on_airborne()
        since = self._since_takeoff_s(airborne)
        alt = self.rec.state.get("home_alt_m")
        if self.home.airborne and alt is not None and alt != self.home.home_now_m:
            self.home.on_home(alt, in_window=self.home.window_open(since))
        self.home.summarise_window(since)
        restore_to = self.home.restore_step(since)
        if restore_to is not None:
            await self._send_home(restore_to)
        low = self.home.check(current_seq, since)  # while home may move: only what is flown until it settles
        if low is None:
            return False
        self._fail(low.problem(self.home.min_clearance_m))
        await self._rtl_and_wait(timeout_s=self.stop_wait_s)
        return True

    async def _standoff_failed(self, current_seq: int) -> bool:
        """The standoff loop's step (measure, correct); when it ends the flight: pause, RTL, wait for the landing."""
        if self.standoff is None or _down_and_disarmed(self.rec.state):
            return False
        problem = await self.standoff.step(self.v, current_seq)
        if problem is None:
            return False
        self._fail(problem)
        await self._rtl_and_wait(timeout_s=self.stop_wait_s)
        return True

    def _since_takeoff_s(self, airborne: bool) -> float | None:
        """Seconds of the autopilot's clock since it was first seen flying (None before, or without its clock)."""
        now = self.rec.boot_time_s
        if airborne and self.takeoff_boot_s is None:
            self.takeoff_boot_s = now
        if now is None or self.takeoff_boot_s is None:
            return None
        return now - self.takeoff_boot_s

    async def _send_home(self, alt_amsl_m: float) -> None:
        """Asked for by a SITL profile only: ask for home at ``alt_amsl_m`` where it was at arming (DO_SET_HOME as
        COMMAND_INT, AMSL: COMMAND_LONG's float32 would move home's longitude by up to 0.7 m). Fire and forget: the
        home watch confirms it by HOME_POSITION and asks again if it does not come."""
        latlon = self.rec.home_before_air_latlon or self.home_latlon_before_arming
        if latlon is None:
            self.home.restore_done = True
            log.error("cannot put home back: where it was at arming is not known; the home watch decides")
            return
        yaw = self.rec.state.get("yaw_deg")
        params = (0.0, 0.0, 0.0, float(yaw) if yaw is not None else 0.0)  # param1 0: the position given
        log.info("asking the vehicle to put home back at %.2f m AMSL (try %d)", alt_amsl_m, self.home.restore_sends)
        try:
            await self.v.send_command_int(MAV_CMD_DO_SET_HOME, mi.MAV_FRAME_GLOBAL_INT, params, latlon[0], latlon[1],
                                          alt_amsl_m)
        except Exception as exc:  # said; the next try or the watch follows
            log.warning("could not send DO_SET_HOME: %s", exc)

    async def hand_home_back(self) -> None:
        """After a flight in which the companion put home back (a SITL profile's restore_home): landed and disarmed,
        home is set at the vehicle's position again (DO_SET_HOME param1 1), which also clears PX4's manual-home flag;
        PX4 would otherwise keep the companion's home at the next arming. Sent without waiting for its ACK (see
        ``_send_home``)."""
        st = self.rec.state
        if not self.home.put_back or st["armed"] is not False or st["in_air"] is not False:
            return
        latlon = self.rec.home_before_air_latlon or self.home_latlon_before_arming or (0.0, 0.0)
        try:
            await self.v.send_command_int(MAV_CMD_DO_SET_HOME, mi.MAV_FRAME_GLOBAL_INT, (1.0, 0.0, 0.0, 0.0), *latlon,
                                          0.0)
            log.info("home handed back to the vehicle (DO_SET_HOME 1: at its position, as PX4 sets it at arming)")
        except Exception as exc:
            log.warning("could not hand home back (%s): the vehicle keeps the home the companion set; set home "
                        "again from the ground station or restart it before the next flight", exc)

    async def read_home_before_arming(self, timeout_s: float = 5.0) -> None:
        """The home altitude before arming, so the watch has its reference even if the vehicle is in the air
        before the next HOME_POSITION arrives (0.5 Hz); one received later, before take-off, replaces it."""
        try:
            home = await asyncio.wait_for(self.v.telemetry.home(), timeout_s)
        except Exception as exc:  # the watch still takes the first one the recorder receives before take-off
            log.warning("could not read home before arming (%s): its in-flight moves are measured from the first "
                        "home received before take-off", exc)
            return
        self.home.on_home(home.absolute_altitude_m)
        self.home_latlon_before_arming = (home.latitude_deg, home.longitude_deg)

    def _start_refused(self, refusal_seen: float | None, now: float) -> FlightAbort | None:
        """Before take-off: the vehicle disarmed again (PX4 refuses the takeoff of an infeasible mission and
        disarms on the ground), or it reported a critical error. Ends within seconds, quoting the vehicle."""
        st = self.rec.state
        disarmed = self.rec.was_armed and st["armed"] is False and not st["in_air"]
        if not disarmed and (refusal_seen is None or now - refusal_seen < REFUSAL_GRACE_S):
            return None
        texts = self._refusal_texts(self.texts_from) or [
            f"{sev}: {text}" for t, sev, text in self.rec.status_events if t >= self.texts_from][-3:]
        said = "; ".join(texts) if texts else "no reason given (no STATUSTEXT)"
        what = "disarmed without taking off" if disarmed else "did not take off"
        self._fail(f"the vehicle refused the mission start: it {what}; it said: {said}")
        return FlightAbort.REFUSED

    async def _rtl_and_wait(self, timeout_s: float) -> None:
        st = self.rec.state
        try:
            await self.v.mission.pause_mission()
            await asyncio.sleep(1.0)
        except Exception as exc:  # RTL follows anyway; say that the pause did not happen
            log.warning("pause (hold) failed: %s; commanding RTL directly", exc)
        try:
            await _retry("return to launch", self.v.action.return_to_launch)
        except CompanionError as exc:
            self._fail(f"{exc.problem}: the vehicle was NOT sent home; take control from the ground station")
        self.signalled.clear()
        t_start = time.monotonic()
        deadline = t_start + timeout_s
        log.warning("waiting up to %.0f s for the vehicle to land and disarm (stop again to stop waiting)",
                    timeout_s)
        last_said = t_start
        while time.monotonic() < deadline:
            if st["armed"] is False and st["in_air"] is False:
                log.info("landed and disarmed after RTL")
                return
            if self.signal_count >= 2:
                return
            if self.rec.reboot is not None:
                self._fail(self.rec.reboot)
                return
            now = time.monotonic()
            self._track_link(now)
            if now - last_said >= 10.0:
                last_said = now
                log.info("still waiting for landed + disarmed (%.0f s left)", deadline - now)
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self.signalled.wait(), 0.2)
            self.signalled.clear()
        log.error("the vehicle was not landed and disarmed %.0f s after RTL; stopped waiting", timeout_s)
        self.close_open_loss()


async def _failsafe_check(vehicle: Vehicle, plan, *, lost_link_action: str | None,
                          return_alt: str | float | None) -> tuple[dict[str, float], list[str]]:
    """Read the lost-link action and return altitude; warn; the parameters the explicit options ask for."""
    need = required_return_alt(plan)
    failsafe_overrides(vehicle.autopilot, link_action=lost_link_action, return_alt=return_alt, need=need)  # check
    settings = None
    try:
        settings = await read_failsafe(vehicle.param, vehicle.autopilot)
    except CompanionError as exc:
        if lost_link_action is not None or return_alt is not None:
            raise
        text = f"could not check the lost-link failsafe: {exc.problem}"
        log.warning("%s", text)
        return {}, [text]
    overrides = failsafe_overrides(vehicle.autopilot, link_action=lost_link_action, return_alt=return_alt,
                                   need=need, current=settings)
    if lost_link_action is not None:  # the failsafe must count the companion's heartbeats (link_watch.py); set
        overrides = {**await link_watch_overrides(vehicle), **overrides}  # before it is enabled, restored after
    log.info("lost-link failsafe: %s=%d (%s); return altitude %s = %g m", settings.names.link_action,
             settings.link_action, settings.link_action_text, settings.names.return_alt, settings.return_alt_m)
    warnings = []
    for text in failsafe_warnings(settings, need):
        fixed = (settings.names.link_action in overrides if "lost-link" in text
                 else settings.names.return_alt in overrides)
        if not fixed:
            log.warning("failsafe: %s", text)
            warnings.append(text)
    return overrides, warnings


def plan_flight_parameters(plan, autopilot: str | Autopilot) -> dict[str, float]:
    """The parameters a ScanPlan needs on ``autopilot`` for its flight; none for a bare list of items."""
    if hasattr(plan, "mavlink_items"):
        return autopilot_for(autopilot).flight_parameters(plan)
    return {}


def _check_flight_options(end_action: str, link_loss_s: float, link_dead_s: float, stop_wait_s: float) -> None:
    """Refuse option values no flight can be supervised with, before anything connects."""
    if end_action not in ("rtl", "land"):
        raise CompanionError(f"end_action {end_action!r} is not 'rtl' or 'land'", "use end_action='rtl'")
    for name, value in (("link_loss_s", link_loss_s), ("link_dead_s", link_dead_s), ("stop_wait_s", stop_wait_s)):
        if not value > 0:
            raise CompanionError(f"{name} must be positive, got {value}", f"give {name} in seconds, e.g. 60")
    if link_dead_s <= link_loss_s:
        raise CompanionError(f"the dead-link limit ({link_dead_s:g} s) must be longer than the link-loss threshold "
                             f"({link_loss_s:g} s)", "raise --link-dead or lower --link-loss")


async def _prepare_vehicle(vehicle: Vehicle, plan, items, *, health_timeout_s: float,
                           flight_parameters: Mapping[str, float] | None, lost_link_action: str | None,
                           return_alt: str | float | None,
                           sitl_profile: SitlProfile | None = None) -> tuple[dict[str, float], list[str], int]:
    """Everything before arming: upload + verify, arming mode, health, home, failsafe, parameters, first item.

    Returns the parameters to set for the flight, the failsafe warnings and the item the mission starts from.
    """
    # upload before the health wait, once the vehicle is up: a mission it refuses is an error at once, not
    # after its EKF converged (real ArduCopter SITL: about 40 s after boot)
    if not await wait_initialised(vehicle, health_timeout_s):
        log.warning("no SYS_STATUS within %g s: uploading anyway", health_timeout_s)
    async with StatusTexts(vehicle.telemetry) as texts:  # a refusal quotes what the vehicle said about it
        await upload_and_verify(vehicle.mission, items, vehicle.autopilot, texts=texts)
    await select_arming_mode(vehicle)
    await wait_healthy(vehicle, health_timeout_s, when_only_armable_missing=lambda: select_arming_mode(vehicle))
    if getattr(plan, "home", None) is not None:
        await check_home(vehicle, plan.home)
    overrides, warnings = await _failsafe_check(vehicle, plan, lost_link_action=lost_link_action,
                                                return_alt=return_alt)
    wanted = plan_flight_parameters(plan, vehicle.autopilot)  # what the plan needs (e.g. vertical scan speed)
    if sitl_profile is not None:  # asked for by name (--sitl-profile): never chosen by what the vehicle looks like
        log.warning("SITL profile %s: %s (a simulator's accommodations; never fly a real vehicle with it)",
                    sitl_profile.source or "given", sitl_profile.describe())
        wanted.update(sitl_profile.parameters)
    wanted.update(flight_parameters or {})
    wanted.update(overrides)
    first_seq = await start_from_first_item(vehicle)
    return wanted, warnings, first_seq


def standoff_loop_for(plan, items, first_seq: int, options: StandoffOptions, rec: TelemetryRecorder,
                      camera: Callable[[], StandoffEstimate | None] | None) -> StandoffLoop | None:
    """The standoff loop of a ScanPlan's flight (none for a bare item list: no wall to measure), fed the
    recorder's rows."""
    if not hasattr(plan, "frame"):
        return None
    loop = StandoffLoop(plan, items, first_seq, options, clock=lambda: rec.boot_time_s, camera=camera)
    rec.row_hook = loop.on_row
    return loop


def home_watch_for(plan, items: Sequence[mi.MissionItem], autopilot: str | Autopilot,
                   restore_home: bool = False) -> HomeWatch:
    """The flight's home watch: the autopilot's correction window (PX4 moves home for 120 s after take-off;
    ArduPilot keeps it where it armed); until then a ScanPlan flies only what home's largest move leaves clear of
    the ground, up to its settle waypoint (where it holds if that part ends sooner);
    ``restore_home`` (a SITL profile's, asked for) puts home back after it."""
    window_s = autopilot_for(autopilot).home_correction_window_s
    settle = -1
    if window_s > 0 and getattr(plan, "moving_home", False) and plan.settle_waypoint_index >= 0:
        settle = settle_item_seq(items, plan.settle_waypoint_index)
    return HomeWatch(items, window_s=window_s, settle_seq=settle, restore=window_s > 0 and restore_home)


async def _arm_and_start(vehicle: Vehicle, rec: TelemetryRecorder, first_seq: int) -> None:
    """Arm from a mode that allows it (quoting the firmware's refusal) and start the mission; disarm if refused."""
    if not await select_arming_mode(vehicle):
        log.warning("the vehicle did not confirm the switch to %s before arming",
                    autopilot_for(vehicle.autopilot).arming_mode.name)
    await arm_with_reason(vehicle, lambda n: rec.status_texts[n:], lambda: len(rec.status_texts))
    log.info("armed; starting the mission at item %d", first_seq)
    try:
        await start_with_reason(vehicle, lambda n: rec.status_texts[n:], lambda: len(rec.status_texts))
    except CompanionError:
        with contextlib.suppress(Exception):
            await vehicle.action.disarm()
        raise


async def _handle_ending(vehicle: Vehicle, sup: _Supervisor, rec: TelemetryRecorder, params: FlightParameters,
                         reason: FlightAbort | None, stop_wait_s: float) -> None:
    """Act on why supervision ended: a dead link, a refused start (an error), or a stop request (RTL + wait)."""
    if reason == FlightAbort.LINK:
        params.unreachable = "the link is dead"
    if reason == FlightAbort.REFUSED:
        if rec.state["armed"]:
            try:
                await vehicle.action.disarm()
            except Exception as exc:
                log.error("could not disarm the refused vehicle: %s", exc)
        raise CompanionError(sup.problem or "the vehicle refused the mission start",
                             "fix what the vehicle reports (e.g. move the mission inside its geofence, or "
                             "check the mission's feasibility on the ground station), then retry")
    if reason == FlightAbort.SIGNAL:
        await sup._rtl_and_wait(timeout_s=stop_wait_s)


def _flight_result(vehicle: Vehicle, sup: _Supervisor, rec: TelemetryRecorder, params: FlightParameters, items,
                   reason: FlightAbort | None, duration_s: float, telemetry_log: Path | str | None,
                   warnings: list[str]) -> FlightResult:
    """The flight's outcome, read after the recorder has closed (its exit flushes the last rows)."""
    st = rec.state
    landed, disarmed = st["in_air"] is False, st["armed"] is False
    total = len(items)
    problem = sup.problem
    if params.restore_failures:
        text = ("parameters not restored: " + ", ".join(params.restore_failures) + " (kept in the parameter "
                "journal: the next `companion fly` or `companion restore --connect URL` puts them back)")
        problem = f"{problem}; {text}" if problem else text
    return FlightResult(
        completed=reason is None and problem is None and landed and disarmed and sup.max_reached >= total,
        landed=landed, disarmed=disarmed, aborted=reason, items_total=total,
        items_reached=sup.max_reached, autopilot=vehicle.autopilot,
        duration_s=duration_s, telemetry_samples=rec.samples,
        link_losses=sup.link_losses, telemetry_log=Path(telemetry_log) if telemetry_log else None,
        status_texts=list(rec.status_texts), problem=problem, waypoints_total=sup.progress.total,
        waypoints_reached=sup.progress.done, parameter_changes=list(params.applied), warnings=warnings,
        standoff=sup.standoff.summary() if sup.standoff is not None else None,
        standoff_corrections=list(sup.standoff.controller.corrections) if sup.standoff is not None else [])


def _standoff_options(plan, standoff: StandoffOptions | None) -> StandoffOptions:
    """The flight's standoff options (default ``StandoffOptions()``); an impossible tolerance or floor for a
    ScanPlan is refused here, before anything connects."""
    standoff = standoff if standoff is not None else StandoffOptions()
    if hasattr(plan, "frame"):
        settings_for(plan, standoff)
    return standoff


def _install_stop_handlers(loop: asyncio.AbstractEventLoop, sup: _Supervisor, installed: list[int]) -> None:
    """SIGINT and SIGTERM ask the supervisor to stop (bounded Ctrl-C); each signal installed is appended to
    ``installed`` as it is, so the caller removes exactly those whatever happens next."""
    for sig in (signal.SIGINT, signal.SIGTERM):
        with contextlib.suppress(NotImplementedError, RuntimeError, ValueError):
            loop.add_signal_handler(sig, sup.on_signal, sig)
            installed.append(sig)


async def _fly_supervised(vehicle: Vehicle, sup: _Supervisor, rec: TelemetryRecorder, params: FlightParameters,
                          first_seq: int, stop_wait_s: float) -> tuple[FlightAbort | None, float]:
    """The flight itself, once everything is set: home read, the companion's heartbeat counted by the lost-link
    failsafe, armed and started, supervised to its end, the ending acted on, home handed back. Returns why
    supervision ended (None: the mission ran out) and the seconds from the start."""
    await sup.read_home_before_arming()
    await until_heartbeat_counted(params.applied)  # link_watch.py: no arming in a stale GCS failsafe
    await _arm_and_start(vehicle, rec, first_seq)
    sup.t0 = time.monotonic()
    reason = await sup.run()
    await _handle_ending(vehicle, sup, rec, params, reason, stop_wait_s)
    await sup.hand_home_back()
    return reason, time.monotonic() - sup.t0


async def fly_mission(plan, connect_url: str = FLIGHT_DEFAULTS.connect_url, *,
                      telemetry_log: Path | str | None = None, autopilot: str = "auto",
                      connect_timeout_s: float = FLIGHT_DEFAULTS.connect_timeout_s,
                      health_timeout_s: float = FLIGHT_DEFAULTS.health_timeout_s,
                      link_loss_s: float = FLIGHT_DEFAULTS.link_loss_s,
                      link_dead_s: float = FLIGHT_DEFAULTS.link_dead_s,
                      flight_timeout_s: float = FLIGHT_DEFAULTS.flight_timeout_s,
                      telemetry_rate_hz: float = FLIGHT_DEFAULTS.telemetry_rate_hz,
                      end_action: str = FLIGHT_DEFAULTS.end_action, progress: bool = True, handle_signals: bool = True,
                      stop_wait_s: float = FLIGHT_DEFAULTS.stop_wait_s,
                      flight_parameters: Mapping[str, float] | None = None,
                      lost_link_action: str | None = None, return_alt: str | float | None = None,
                      standoff: StandoffOptions | None = None,
                      camera_standoff: Callable[[], StandoffEstimate | None] | None = None,
                      state_dir: Path | str | None = None,
                      sitl_profile: SitlProfile | None = None) -> FlightResult:
    """Upload, verify and fly ``plan`` (a ScanPlan or a list of MissionItem) on the autopilot at ``connect_url``.

    The parameters a ScanPlan needs on this firmware (its home's ``flight_parameters``, ``companion.mission.autopilot``:
    PX4's climb/descent speed = the vertical scan speed, ArduCopter's WP_YAW_BEHAVIOR = 0) are always set for the
    flight and restored afterwards.
    ``flight_parameters``: further autopilot parameters to set for this flight only (restored afterwards, also after an
    error or Ctrl-C); ``lost_link_action`` ('rtl'/'land') and ``return_alt`` (metres or 'auto': the plan's transit
    altitude or wall top + margin) set the lost-link failsafe the same way.
    ``standoff``: how the flight holds the measured standoff on a ScanPlan's scan legs (default
    ``StandoffOptions()``: corrected, tolerance 0.3 m, floor = the mission's ``min_distance_m`` or 60 %); the
    measurements are the forward rangefinder's (DISTANCE_SENSOR in the telemetry rows) and ``camera_standoff()``'s
    (the live chain's ``CullChain.standoff``). Without either the flight says the standoff was not measured.
    ``state_dir``: where the parameter journal lives (``param_journal.state_dir``); whatever an earlier run left
    changed on this vehicle is restored first, and every change this flight makes is journaled before it is made.
    ``sitl_profile``: a simulator's accommodations (``companion.flight.sitl_profile``: parameters set for the flight,
    home put back after the autopilot's correction window); None (default): none, on any vehicle or simulator.

    Returns when the vehicle is landed and disarmed, or supervision ended (stop request, timeout, restart, dead
    link: ``aborted`` and ``problem`` say which). Raises CompanionError for anything that prevents the flight from
    starting, including a start the vehicle refuses.
    """
    _check_flight_options(end_action, link_loss_s, link_dead_s, stop_wait_s)
    standoff = _standoff_options(plan, standoff)
    vehicle = await connect(connect_url, timeout_s=connect_timeout_s, autopilot=autopilot)
    loop = asyncio.get_running_loop()
    installed: list[int] = []
    sup: _Supervisor | None = None
    try:
        journal = await restore_before_flight(vehicle, state_dir)  # before anything else (restore.py)
        if hasattr(plan, "for_autopilot"):  # PX4 flies the part near the ground after its home correction window
            plan = plan.for_autopilot(vehicle.autopilot)
        items = mission_items_for(plan, vehicle.autopilot)
        await request_rates(vehicle, telemetry_rate_hz)
        wanted, warnings, first_seq = await _prepare_vehicle(
            vehicle, plan, items, health_timeout_s=health_timeout_s, flight_parameters=flight_parameters,
            lost_link_action=lost_link_action, return_alt=return_alt, sitl_profile=sitl_profile)
        restore_home = sitl_profile is not None and sitl_profile.restore_home
        async with FlightParameters(vehicle.param, wanted, journal) as params, \
                TelemetryRecorder(vehicle, Path(telemetry_log) if telemetry_log else None,
                                  planned_gimbal=PlannedGimbal.from_items(items)) as rec:
            loop_ = standoff_loop_for(plan, items, first_seq, standoff, rec, camera_standoff)
            sup = _Supervisor(vehicle, items, rec, link_loss_s=link_loss_s, flight_timeout_s=flight_timeout_s,
                              end_action=end_action, progress=progress, link_dead_s=link_dead_s,
                              stop_wait_s=stop_wait_s, first_seq=first_seq, telemetry_rate_hz=telemetry_rate_hz,
                              home_watch=home_watch_for(plan, items, vehicle.autopilot, restore_home), standoff=loop_)
            if handle_signals:
                _install_stop_handlers(loop, sup, installed)
            reason, duration_s = await _fly_supervised(vehicle, sup, rec, params, first_seq, stop_wait_s)
        return _flight_result(vehicle, sup, rec, params, items, reason, duration_s, telemetry_log, warnings)
    finally:
        for sig in installed:
            loop.remove_signal_handler(sig)
        if sup is not None:
            await sup.finish_background()
        vehicle.close()


def fly_mission_sync(plan, connect_url: str = FLIGHT_DEFAULTS.connect_url, **kwargs) -> FlightResult:
    """Blocking wrapper of :func:`fly_mission` for callers without an event loop."""
    return asyncio.run(fly_mission(plan, connect_url, **kwargs))

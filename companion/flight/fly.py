"""Fly a planned mission: connect, check health, upload + verify, arm, start, supervise to landed + disarmed.

Supervision rules (why they look like this):
  * the autopilot flies the mission; the companion only watches, records and steps in on request, so a dead
    companion or a cut link never leaves the vehicle without a plan (its own link-loss failsafe decides);
  * a silent link longer than ``link_loss_s`` is logged and timed; recording continues and supervision resumes
    when telemetry returns;
  * SIGINT/SIGTERM: pause (hold), then RTL, then wait for landed + disarmed and return; a second signal stops
    waiting.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import signal
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from tqdm import tqdm

from companion.errors import CompanionError
from companion.flight.connection import (
    MAV_CMD_DO_SET_MODE,
    Vehicle,
    check_home,
    connect,
    request_rates,
    wait_healthy,
)
from companion.flight.telemetry_log import TelemetryRecorder
from companion.flight.upload import upload_and_verify
from companion.mission import items as mi

log = logging.getLogger(__name__)

ARDUCOPTER_GUIDED = 4
_ENDS_ON_GROUND = {mi.MAV_CMD_NAV_LAND, mi.MAV_CMD_NAV_RETURN_TO_LAUNCH}


@dataclass(frozen=True)
class LinkLoss:
    started_s: float  # seconds after the mission start (wall)
    duration_s: float


@dataclass
class FlightResult:
    """What happened. ``completed``: every mission item was reached and the vehicle ended landed + disarmed."""

    completed: bool
    landed: bool
    disarmed: bool
    aborted: str | None  # 'signal', 'timeout', 'failsafe' (landed early) or None
    items_total: int
    items_reached: int
    autopilot: str
    duration_s: float
    telemetry_samples: int
    link_losses: list[LinkLoss] = field(default_factory=list)
    telemetry_log: Path | None = None
    status_texts: list[str] = field(default_factory=list)


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
                 link_loss_s: float, flight_timeout_s: float, end_action: str, progress: bool):
        self.v = vehicle
        self.items = items
        self.rec = rec
        self.link_loss_s = link_loss_s
        self.flight_timeout_s = flight_timeout_s
        self.end_action = end_action
        self.progress = progress
        self.signalled = asyncio.Event()
        self.signal_count = 0
        self.link_losses: list[LinkLoss] = []
        self.t0 = time.monotonic()
        self.max_reached = 0

    def on_signal(self) -> None:
        self.signal_count += 1
        self.signalled.set()
        log.warning("stop requested (signal %d): pausing, then returning to launch", self.signal_count)

    async def run(self) -> str | None:
        """Returns the abort reason or None."""
        st = self.rec.state
        total = len(self.items)
        bar = tqdm(total=total, unit="item", desc="mission", disable=not self.progress, leave=True)
        lost_since: float | None = None
        airborne = False
        end_sent = False
        ends_on_ground = self.items[-1].command in _ENDS_ON_GROUND
        try:
            while True:
                now = time.monotonic()
                last = self.rec.last_sample_wall
                gap = now - last if last is not None else now - self.t0
                if gap > self.link_loss_s and lost_since is None:
                    lost_since = last if last is not None else self.t0
                    log.warning("link lost: no telemetry for %.1f s; the vehicle continues on its own "
                                "(its failsafe decides), still recording", gap)
                elif gap <= self.link_loss_s and lost_since is not None:
                    self.link_losses.append(LinkLoss(lost_since - self.t0, now - lost_since))
                    log.warning("link restored after %.1f s; resuming supervision", now - lost_since)
                    lost_since = None
                if self.signalled.is_set():
                    return "signal"
                if now - self.t0 > self.flight_timeout_s:
                    log.error("flight took longer than %.0f s: returning to launch", self.flight_timeout_s)
                    await self._rtl_and_wait(timeout_s=120.0)
                    return "timeout"
                if lost_since is None:
                    current = max(0, int(st["mission_item"]))
                    self.max_reached = max(self.max_reached, min(current, total))
                    bar.n = self.max_reached
                    bar.refresh()
                    if st["in_air"] or self.rec.was_in_air:  # latched: the flight may predate this loop
                        airborne = True
                    done = self.max_reached >= total
                    if done and st["in_air"] and not ends_on_ground and not end_sent:
                        end_sent = True
                        log.info("mission complete; %s", "returning to launch" if self.end_action == "rtl"
                                 else "landing")
                        action = self.v.action.return_to_launch if self.end_action == "rtl" else self.v.action.land
                        await _retry(self.end_action, action)
                    if airborne and st["armed"] is False and st["in_air"] is False:
                        if not done and ends_on_ground and self.max_reached >= total - 1:
                            # Down and disarmed while executing the final LAND/RTL item: that item is complete
                            # even if its MISSION_ITEM_REACHED was lost on the link.
                            self.max_reached = total
                            done = True
                        return None if done else "failsafe"
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(self.signalled.wait(), 0.1)
        finally:
            bar.close()

    async def _rtl_and_wait(self, timeout_s: float) -> None:
        st = self.rec.state
        with contextlib.suppress(Exception):
            await self.v.mission.pause_mission()
            await asyncio.sleep(1.0)
        with contextlib.suppress(CompanionError):
            await _retry("return to launch", self.v.action.return_to_launch)
        self.signalled.clear()
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if st["armed"] is False and st["in_air"] is False:
                log.info("landed and disarmed after RTL")
                return
            if self.signal_count >= 2:
                log.warning("second stop request: not waiting for the landing")
                return
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self.signalled.wait(), 0.2)
            self.signalled.clear()


async def fly_mission(plan, connect_url: str = "udp://:14540", *, telemetry_log: Path | str | None = None,
                      autopilot: str = "auto", connect_timeout_s: float = 10.0, health_timeout_s: float = 30.0,
                      link_loss_s: float = 3.0, flight_timeout_s: float = 1800.0, telemetry_rate_hz: float = 10.0,
                      end_action: str = "rtl", progress: bool = True, handle_signals: bool = True) -> FlightResult:
    """Upload, verify and fly ``plan`` (a ScanPlan or a list of MissionItem) on the autopilot at ``connect_url``.

    Returns when the vehicle is landed and disarmed (or after a stop request / timeout, having commanded RTL).
    Raises CompanionError for anything that prevents the flight from starting.
    """
    if end_action not in ("rtl", "land"):
        raise CompanionError(f"end_action {end_action!r} is not 'rtl' or 'land'", "use end_action='rtl'")
    vehicle = await connect(connect_url, timeout_s=connect_timeout_s, autopilot=autopilot)
    loop = asyncio.get_running_loop()
    installed: list[int] = []
    try:
        items = mission_items_for(plan, vehicle.autopilot)
        await request_rates(vehicle, telemetry_rate_hz)
        await wait_healthy(vehicle, health_timeout_s)
        if getattr(plan, "home", None) is not None:
            await check_home(vehicle, plan.home)
        await upload_and_verify(vehicle.mission, items, vehicle.autopilot)
        async with TelemetryRecorder(vehicle, Path(telemetry_log) if telemetry_log else None) as rec:
            sup = _Supervisor(vehicle, items, rec, link_loss_s=link_loss_s, flight_timeout_s=flight_timeout_s,
                              end_action=end_action, progress=progress)
            if handle_signals:
                for sig in (signal.SIGINT, signal.SIGTERM):
                    with contextlib.suppress(NotImplementedError, RuntimeError, ValueError):
                        loop.add_signal_handler(sig, sup.on_signal)
                        installed.append(sig)
            if vehicle.autopilot == "ardupilot":
                # ArduCopter refuses to arm in BRAKE (mavsdk's "Hold"): arm in GUIDED.
                await vehicle.command_long(MAV_CMD_DO_SET_MODE, 1, ARDUCOPTER_GUIDED)
            await _retry("arming", vehicle.action.arm)
            log.info("armed; starting the mission")
            await _retry("mission start", vehicle.mission.start_mission)
            sup.t0 = time.monotonic()
            reason = await sup.run()
            if reason == "signal":
                await sup._rtl_and_wait(timeout_s=max(60.0, flight_timeout_s / 4))
            duration_s = time.monotonic() - sup.t0
        # read after the recorder has closed: its exit flushes the last rows, and the count must match the file
        st = rec.state
        landed, disarmed = st["in_air"] is False, st["armed"] is False
        total = len(items)
        return FlightResult(
            completed=reason is None and landed and disarmed and sup.max_reached >= total,
            landed=landed, disarmed=disarmed, aborted=reason, items_total=total,
            items_reached=sup.max_reached, autopilot=vehicle.autopilot,
            duration_s=duration_s, telemetry_samples=rec.samples,
            link_losses=sup.link_losses, telemetry_log=Path(telemetry_log) if telemetry_log else None,
            status_texts=list(rec.status_texts))
    finally:
        for sig in installed:
            loop.remove_signal_handler(sig)
        vehicle.close()


def fly_mission_sync(plan, connect_url: str = "udp://:14540", **kwargs) -> FlightResult:
    """Blocking wrapper of :func:`fly_mission` for callers without an event loop."""
    return asyncio.run(fly_mission(plan, connect_url, **kwargs))

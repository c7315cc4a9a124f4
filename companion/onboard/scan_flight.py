"""One flight of a planned scan, with or without live culling, against an autopilot or a simulator started for
it: what ``companion fly`` runs (the command only turns its arguments into a ``ScanFlight``)."""

from __future__ import annotations

import contextlib
import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from companion.errors import CompanionError
from companion.flight.limits import FLIGHT_DEFAULTS
from companion.onboard.standoff_watch import standoff_line
from companion.plugins import SitlRequest, provided

log = logging.getLogger(__name__)

SIM_CAPTURE = "sim"  # --capture sim: the simulated camera, started with the simulated vehicle


@dataclass(frozen=True)
class ScanFlight:
    """Where to fly and what to record; ``fly_options`` are ``companion.flight.fly.fly_mission``'s keywords."""

    mission_path: Path
    connect_url: str
    fly_options: dict[str, Any] = field(default_factory=dict)
    telemetry_log: Path | None = None
    telemetry_rate_hz: float = FLIGHT_DEFAULTS.telemetry_rate_hz
    capture: str | None = None  # a frame source spec (companion.capture.sources.open_source) or SIM_CAPTURE
    spool_dir: Path | None = None  # keyframe spool, required with ``capture``
    model: Path | None = None
    mask: bool = True
    parallax: bool = True  # confirm the network's mask by motion parallax (docs/DEPTH.md)
    gcs_camera_url: str | None = None
    sitl: SitlRequest | None = None  # start this simulator and fly it instead of ``connect_url``


@dataclass(frozen=True)
class ScanFlightOutcome:
    flight: Any  # companion.flight.fly.FlightResult
    culling: Any = None  # companion.onboard.live.LiveScanResult with live culling, else None


def check_scan_flight(request: ScanFlight) -> None:
    """Refuse combinations that cannot fly before anything starts."""
    if request.capture and request.spool_dir is None:
        raise CompanionError("--capture needs --out DIR for the keyframe spool", "add --out out/spool")
    if request.capture == SIM_CAPTURE and request.sitl is None:
        raise CompanionError("--capture sim needs --sitl (it starts the simulated camera)", "add --sitl")


def fly_scan(request: ScanFlight) -> ScanFlightOutcome:
    """Plan ``request.mission_path``, start the simulator if asked, fly (culling live frames into the spool when a
    capture is given), and always stop what was started."""
    from companion.mission import load_mission, plan_scan

    check_scan_flight(request)
    plan = plan_scan(load_mission(request.mission_path))
    for warning in plan.warnings:
        log.warning("plan: %s", warning)
    simulator = None
    url, capture = request.connect_url, request.capture
    if request.sitl is not None:
        simulator = provided("start_sitl", "flying in SITL (--sitl)")(request.sitl)
        url = simulator.url
        if capture == SIM_CAPTURE:
            capture = simulator.capture
        log.info("started the simulated vehicle (speed-up %g) on %s", request.sitl.speedup, url)
    try:
        return _fly(plan, url, capture, request)
    finally:
        if simulator is not None:
            with contextlib.suppress(Exception):
                simulator.stop()


def _fly(plan, url: str, capture: str | None, request: ScanFlight) -> ScanFlightOutcome:
    if capture:
        from companion.onboard.live import run_live_scan

        # the tagger interpolates between samples: ask for at least 30 Hz while culling
        scan = run_live_scan(plan, url, capture, request.spool_dir, telemetry_log=request.telemetry_log,
                             model=request.model, mask=request.mask, parallax=request.parallax,
                             gcs_camera_url=request.gcs_camera_url,
                             telemetry_rate_hz=max(request.telemetry_rate_hz, 30.0), **request.fly_options)
        return ScanFlightOutcome(scan.flight, scan)
    from companion.flight.fly import fly_mission_sync

    result = fly_mission_sync(plan, url, telemetry_log=request.telemetry_log,
                              telemetry_rate_hz=request.telemetry_rate_hz, **request.fly_options)
    return ScanFlightOutcome(result)


def flight_summary(result) -> str:
    """A line for a person: how far it got, how it ended, every link loss (open ones said so); then, for a scan,
    a line with the standoff measured on the scan legs and the corrections made (or that it was not measured)."""
    state = "landed" if result.landed else "NOT landed"
    state += ", disarmed" if result.disarmed else ", still ARMED"
    open_losses = sum(1 for loss in result.link_losses if not loss.closed)
    losses = f"{len(result.link_losses)} link loss(es)" + (f" ({open_losses} never restored)" if open_losses else "")
    return (f"{'mission complete' if result.completed else 'mission NOT complete'}: "
            f"{result.waypoints_reached}/{result.waypoints_total} waypoints "
            f"({result.items_reached}/{result.items_total} items), {state}, {result.duration_s:.0f} s, "
            f"{result.telemetry_samples} telemetry samples, {losses}"
            + (f", stopped by {result.aborted}" if result.aborted else "")
            + ("; parameters set for this flight only: "
               + ", ".join(c.name for c in result.parameter_changes) if result.parameter_changes else "")
            + (f"\n{result.standoff.line()}" if getattr(result, "standoff", None) is not None else ""))


def culling_summary(stats, spool_dir: Path | None = None) -> str:
    """One line for a person, the same for `companion fly` and the demo: frames in, keyframes, and what a field
    engineer checks first (keyframes below the overlap target, warnings, gaps, how far the chain fell behind), and
    the standoff measured from the images against the plan (median +- robust spread of the pairs) when measured."""
    where = f" in {spool_dir}" if spool_dir is not None else ""
    standoff = getattr(stats, "standoff", None)
    measured = ""
    if standoff:
        measured = "; " + standoff_line(standoff.get("measured_median_m"), standoff.get("measured_spread_m"),
                                         standoff.get("planned_m"))
        if standoff.get("measurements"):
            measured += (f" from {standoff['measurements']} frame pairs, none for "
                         f"{100 * (standoff.get('frames_without_share') or 0.0):.0f} % of the scan")
    return (f"culling: {stats.frames_in} frames -> {stats.keyframes} keyframes{where} "
            f"({stats.skipped_backlog} skipped for CPU, {stats.dropped_no_roi} without facade, {stats.off_scan} off "
            f"the scan's standoff, {stats.low_overlap_keyframes} below the overlap target, {stats.overlap_warnings} "
            f"overlap warnings, {stats.gaps} gaps; at most {stats.backlog_max_s:.1f} s behind the camera){measured}")

"""``companion fly`` (plan, upload, verify, fly, supervise; optionally culling live frames) and ``companion cull``
(the offline twin of live culling, for recorded flights): the onboard chain run during a flight or after it."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from companion.errors import CompanionError
from companion.flight.commands import STATE_DIR_HELP
from companion.flight.limits import FlightLimits
from companion.flight.sitl_profile import load_sitl_profile
from companion.flight.standoff_loop import StandoffOptions
from companion.mission.autopilot import DEFAULT_FLAVOUR, Flavour
from companion.onboard.mission_source import find_cull_mission
from companion.onboard.offline import OfflineCull, cull_recorded_flight
from companion.onboard.scan_flight import SIM_CAPTURE, ScanFlight, culling_summary, flight_summary, fly_scan
from companion.plugins import SitlRequest
from companion.resources import mission_argument


def register(sub: argparse._SubParsersAction) -> None:
    _register_fly(sub)
    _register_cull(sub)


def _register_fly(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("fly", help="upload, verify and fly a facade mission through mavsdk (PX4 or ArduPilot)")
    p.add_argument("mission", type=mission_argument, help="mission YAML (e.g. missions/demo-facade.yaml)")
    p.add_argument("--connect", default=FlightLimits.connect_url,
                   help="MAVLink address: udp://:14540 (PX4 SITL), tcpout://127.0.0.1:5760 (ArduPilot SITL), "
                        "serial:///dev/ttyACM0:921600")
    p.add_argument("--autopilot", choices=["auto", *(str(f) for f in Flavour)], default="auto",
                   help="autopilot behaviour to expect (auto: from its heartbeat); with --sitl also the simulator's")
    p.add_argument("--telemetry-log", type=Path, help="write every telemetry sample as JSON lines here")
    p.add_argument("--connect-timeout", type=float, default=FlightLimits.connect_timeout_s,
                   help="seconds to wait for a heartbeat")
    p.add_argument("--health-timeout", type=float, default=FlightLimits.health_timeout_s,
                   help="seconds to wait for GPS/home/pre-arm (ArduCopter's EKF needs 35-40 s after boot)")
    p.add_argument("--link-loss", type=float, default=FlightLimits.link_loss_s,
                   help="seconds without telemetry that count as lost")
    p.add_argument("--link-dead", type=float, default=FlightLimits.link_dead_s,
                   help="seconds without telemetry after which supervision ends as failed (the vehicle's "
                        "failsafe flies on)")
    p.add_argument("--stop-wait", type=float, default=FlightLimits.stop_wait_s,
                   help="after Ctrl-C (RTL): seconds to wait at most for landed + disarmed")
    p.add_argument("--lost-link-action", choices=["rtl", "land"],
                   help="set the firmware's lost-link failsafe for this flight (PX4 NAV_DLL_ACT, ArduPilot "
                        "FS_GCS_ENABLE); restored after")
    p.add_argument("--return-alt", metavar="M|auto",
                   help="set the return altitude for this flight (PX4 RTL_RETURN_ALT, ArduPilot RTL_ALT); 'auto': "
                        "the plan's transit altitude or wall top + roof margin; restored after")
    p.add_argument("--set-param", action="append", default=[], metavar="NAME=VALUE",
                   help="set an autopilot parameter for this flight only (restored after; repeatable)")
    p.add_argument("--state-dir", type=Path, help=STATE_DIR_HELP + "; a run's changes are journaled there and "
                   "what an interrupted run left is restored before the flight")
    p.add_argument("--sitl-profile", type=Path, metavar="FILE",
                   help="a simulator's accommodations, never for a real vehicle: parameters set for the flight and "
                        "home put back after the autopilot's correction window (PX4 SIH: sim/sitl/px4-sih.yaml, "
                        "docs/FLIGHT.md)")
    p.add_argument("--timeout", type=float, default=FlightLimits.flight_timeout_s,
                   help="RTL if the flight takes longer (seconds)")
    p.add_argument("--rate", type=float, default=FlightLimits.telemetry_rate_hz, help="telemetry rate to request, Hz")
    p.add_argument("--end-action", choices=["rtl", "land"], default=FlightLimits.end_action,
                   help="if the mission ends in the air: return to launch or land there")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    standoff = p.add_argument_group("standoff held by measurement (forward rangefinder, or the camera with --capture)")
    standoff.add_argument("--standoff-tolerance", type=float, default=StandoffOptions.tolerance_m, metavar="M",
                          help="correct the scan when the measured standoff is off the plan by more than this for "
                               "3 s (metres)")
    standoff.add_argument("--standoff-floor", type=float, metavar="M",
                          help="safety floor: measured below it the vehicle backs off and the flight ends unless it "
                               "recovers (default: the mission's min_distance_m, else 60 %% of the standoff)")
    standoff.add_argument("--no-standoff-correction", action="store_true",
                          help="measure and report the standoff only; never move the scan (below the floor the "
                               "flight still ends)")
    p.add_argument("--sitl", action="store_true",
                   help="start the simulated vehicle (python -m sim vehicle) on a free port, fly, stop it")
    p.add_argument("--speedup", type=float, default=SitlRequest.speedup, help="with --sitl: simulator speed-up")
    p.add_argument("--sim-arg", action="append", default=[], metavar="OPT=VALUE",
                   help="with --sitl: extra simulator option, e.g. --sim-arg gusts=5 (repeatable)")
    live = p.add_argument_group("live culling (keyframes chosen during the flight)")
    live.add_argument("--capture", metavar="SOURCE",
                      help="camera to cull while flying: /dev/videoN, rtsp://..., a video file, an image folder, "
                           f"sim://HOST:PORT, or '{SIM_CAPTURE}' with --sitl (starts the simulated camera too)")
    live.add_argument("--out", type=Path, help="keyframe spool directory (required with --capture; resumable)")
    live.add_argument("--model", type=Path, help="depth model .onnx (default: the shipped model)")
    live.add_argument("--no-mask", action="store_true", help="no background removal (whole frame is ROI)")
    live.add_argument("--no-parallax", action="store_true",
                      help="depth network alone: do not confirm its mask by motion parallax along the flight")
    live.add_argument("--gcs-camera", metavar="URL",
                      help="also appear as a MAVLink camera to a ground station here, e.g. udpout:127.0.0.1:14550")
    live.add_argument("--sim-fps", type=float, default=3.0, help="with --capture sim: camera fps (simulated time)")
    live.add_argument("--sim-width", type=int, default=SitlRequest.camera_width_px,
                      help="with --capture sim: camera width in px")
    p.set_defaults(func=run_fly)


def _register_cull(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("cull", help="cull a recorded flight into a keyframe spool (offline twin of live culling)")
    p.add_argument("video", help="video file or image folder of the flight")
    p.add_argument("--telemetry", type=Path, required=True, help="telemetry log (JSON lines from companion fly)")
    p.add_argument("--out", type=Path, required=True, help="keyframe spool directory (resumable)")
    p.add_argument("--mission", type=mission_argument,
                   help="mission YAML the flight flew: overlap threshold, camera and facade, the map's scale, and "
                        "beyond a 4 m standoff where each frame can show the wall (found in a `companion record` "
                        "recording's meta.json; otherwise required)")
    p.add_argument("--no-mission", action="store_true",
                   help="cull without a mission: the spool has no camera identity or scale, its map is in pixels")
    p.add_argument("--model", type=Path, help="depth model (.onnx); default: the shipped model")
    p.add_argument("--no-mask", action="store_true", help="skip background removal (whole frame is ROI)")
    p.add_argument("--no-parallax", action="store_true",
                   help="depth network alone: do not confirm its mask by motion parallax along the flight")
    p.add_argument("--time-offset", type=float, default=OfflineCull.time_offset_s,
                   help="autopilot boot time (s) at video time 0; frame times + offset = telemetry t_boot_s")
    p.add_argument("--fps", type=float, default=OfflineCull.fps, help="frame rate of an image folder without times.csv")
    p.set_defaults(func=run_cull)


def sim_options(pairs: list[str]) -> dict[str, str]:
    """``--sim-arg packet-loss=20`` pairs -> simulator keyword options (``{"packet_loss": "20"}``)."""
    opts = {}
    for pair in pairs:
        key, sep, value = pair.partition("=")
        if not sep or not key:
            raise CompanionError(f"--sim-arg {pair!r} is not OPT=VALUE", "write e.g. --sim-arg packet-loss=20")
        opts[key.replace("-", "_")] = value
    return opts


def flight_parameters(pairs: list[str]) -> dict[str, float]:
    """``--set-param NAME=NUMBER`` pairs -> parameters to set for the flight."""
    out = {}
    for pair in pairs:
        name, sep, value = pair.partition("=")
        try:
            out[name.strip()] = float(value)
        except ValueError:
            name = ""
        if not sep or not name.strip():
            raise CompanionError(f"--set-param {pair!r} is not NAME=NUMBER", "write e.g. --set-param MPC_XY_CRUISE=3")
    return out


def scan_flight_from_args(args: argparse.Namespace) -> ScanFlight:
    sitl = None
    if args.sitl:
        sitl = SitlRequest(
            mission_path=args.mission, autopilot=str(DEFAULT_FLAVOUR if args.autopilot == "auto" else args.autopilot),
            speedup=args.speedup, options=sim_options(args.sim_arg),
            camera_fps=args.sim_fps if args.capture == SIM_CAPTURE else None, camera_width_px=args.sim_width,
            log_dir=args.out / "sim" if args.capture == SIM_CAPTURE and args.out is not None else None)
    fly_options = dict(
        autopilot=args.autopilot, connect_timeout_s=args.connect_timeout, health_timeout_s=args.health_timeout,
        link_loss_s=args.link_loss, flight_timeout_s=args.timeout, end_action=args.end_action,
        progress=not args.no_progress, link_dead_s=args.link_dead, stop_wait_s=args.stop_wait,
        lost_link_action=args.lost_link_action, return_alt=args.return_alt,
        flight_parameters=flight_parameters(args.set_param) or None, state_dir=args.state_dir,
        sitl_profile=load_sitl_profile(args.sitl_profile) if args.sitl_profile is not None else None,
        standoff=StandoffOptions(correct=not args.no_standoff_correction, tolerance_m=args.standoff_tolerance,
                                 floor_m=args.standoff_floor))
    return ScanFlight(mission_path=args.mission, connect_url=args.connect, fly_options=fly_options,
                      telemetry_log=args.telemetry_log, telemetry_rate_hz=args.rate, capture=args.capture,
                      spool_dir=args.out, model=args.model, mask=not args.no_mask, parallax=not args.no_parallax,
                      gcs_camera_url=args.gcs_camera,
                      sitl=sitl)


def run_fly(args: argparse.Namespace) -> int:
    outcome = fly_scan(scan_flight_from_args(args))
    if outcome.culling is not None:
        print(culling_summary(outcome.culling.stats, args.out), file=sys.stderr)
    result = outcome.flight
    print(flight_summary(result), file=sys.stderr)
    if result.problem:
        print(f"error: {result.problem}", file=sys.stderr)
    from companion.flight.fly import FlightAbort  # fly_scan has imported it: the flight's modules load when flown

    if result.aborted == FlightAbort.SIGNAL:
        return 130
    return 0 if result.completed else 1


def run_cull(args: argparse.Namespace) -> int:
    mission = find_cull_mission(args.video, args.mission, allow_none=args.no_mission)
    if mission.path is not None and mission.found_in != "--mission":
        print(f"mission: {mission.path} (the recording's, from {mission.found_in})", file=sys.stderr)
    request = OfflineCull(video=args.video, telemetry_log=args.telemetry, spool_dir=args.out,
                          mission_path=mission.path, model=args.model, mask=not args.no_mask,
                          parallax=not args.no_parallax, time_offset_s=args.time_offset, fps=args.fps)
    result = cull_recorded_flight(request)
    stats = result.stats.as_dict()
    print(
        f"{stats['frames_in']} frames -> {result.stats.keyframes} keyframes in {args.out} "
        f"({stats['corrupt']} corrupt, {stats['dropped_no_roi']} without ROI, {stats['stale_pose']} without pose, "
        f"{stats['before_telemetry']} not placed in the telemetry)"
    )
    if stats["corrupt_files"]:
        print(f"corrupt frames skipped: {', '.join(stats['corrupt_files'])}")
    if result.no_keyframes is not None:
        raise result.no_keyframes
    return 0

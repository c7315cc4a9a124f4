"""``companion fly`` (plan, upload, verify, fly, supervise) and ``companion sim`` (the SITL vehicle)."""

from __future__ import annotations

import argparse
import contextlib
import logging
import sys
from pathlib import Path

from companion.errors import CompanionError

log = logging.getLogger(__name__)


def register(sub) -> None:
    p = sub.add_parser("fly", help="upload, verify and fly a facade mission through mavsdk (PX4 or ArduPilot)")
    p.add_argument("mission", type=Path, help="mission YAML (e.g. missions/demo-facade.yaml)")
    p.add_argument("--connect", default="udp://:14540",
                   help="MAVLink address: udp://:14540 (PX4 SITL), tcpout://127.0.0.1:5760 (ArduPilot SITL), "
                        "serial:///dev/ttyACM0:921600")
    p.add_argument("--autopilot", choices=["auto", "px4", "ardupilot"], default="auto",
                   help="autopilot behaviour to expect (auto: from its heartbeat); with --sitl also the simulator's")
    p.add_argument("--telemetry-log", type=Path, help="write every telemetry sample as JSON lines here")
    p.add_argument("--connect-timeout", type=float, default=10.0, help="seconds to wait for a heartbeat")
    p.add_argument("--health-timeout", type=float, default=120.0,
                   help="seconds to wait for GPS/home/pre-arm (ArduCopter's EKF needs 35-40 s after boot)")
    p.add_argument("--link-loss", type=float, default=3.0, help="seconds without telemetry that count as lost")
    p.add_argument("--link-dead", type=float, default=60.0,
                   help="seconds without telemetry after which supervision ends as failed (the vehicle's "
                        "failsafe flies on)")
    p.add_argument("--stop-wait", type=float, default=180.0,
                   help="after Ctrl-C (RTL): seconds to wait at most for landed + disarmed")
    p.add_argument("--lost-link-action", choices=["rtl", "land"],
                   help="set the firmware's lost-link failsafe for this flight (PX4 NAV_DLL_ACT, ArduPilot "
                        "FS_GCS_ENABLE); restored after")
    p.add_argument("--return-alt", metavar="M|auto",
                   help="set the return altitude for this flight (PX4 RTL_RETURN_ALT, ArduPilot RTL_ALT); 'auto': "
                        "the plan's transit altitude or wall top + roof margin; restored after")
    p.add_argument("--set-param", action="append", default=[], metavar="NAME=VALUE",
                   help="set an autopilot parameter for this flight only (restored after; repeatable)")
    p.add_argument("--timeout", type=float, default=1800.0, help="RTL if the flight takes longer (seconds)")
    p.add_argument("--rate", type=float, default=10.0, help="telemetry rate to request, Hz")
    p.add_argument("--end-action", choices=["rtl", "land"], default="rtl",
                   help="if the mission ends in the air: return to launch or land there")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--sitl", action="store_true",
                   help="start the simulated vehicle (python -m sim vehicle) on a free port, fly, stop it")
    p.add_argument("--speedup", type=float, default=10.0, help="with --sitl: simulator speed-up")
    p.add_argument("--sim-arg", action="append", default=[], metavar="OPT=VALUE",
                   help="with --sitl: extra simulator option, e.g. --sim-arg gusts=5 (repeatable)")
    live = p.add_argument_group("live culling (keyframes chosen during the flight)")
    live.add_argument("--capture", metavar="SOURCE",
                      help="camera to cull while flying: /dev/videoN, rtsp://..., a video file, an image folder, "
                           "sim://HOST:PORT, or 'sim' with --sitl (starts the simulated camera too)")
    live.add_argument("--out", type=Path, help="keyframe spool directory (required with --capture; resumable)")
    live.add_argument("--model", type=Path, help="depth model .onnx (default: the shipped model)")
    live.add_argument("--no-mask", action="store_true", help="no background removal (whole frame is ROI)")
    live.add_argument("--gcs-camera", metavar="URL",
                      help="also appear as a MAVLink camera to a ground station here, e.g. udpout:127.0.0.1:14550")
    live.add_argument("--sim-fps", type=float, default=3.0, help="with --capture sim: camera fps (simulated time)")
    live.add_argument("--sim-width", type=int, default=640, help="with --capture sim: camera width in px")
    p.set_defaults(func=_fly)

    s = sub.add_parser("sim", allow_abbrev=False,
                       help="run the simulated MAVLink vehicle (same options as `python -m sim vehicle`)")
    from sim.vehicle.cli import add_arguments

    add_arguments(s)
    s.set_defaults(func=_sim)
    # `companion sim record MISSION --out DIR`: fly in SITL with the simulated camera and write a recording.
    from sim.camera.commands import register as register_record

    register_record(s.add_subparsers(dest="sim_command", metavar="{record}", required=False))


def _sim(args: argparse.Namespace) -> int:
    from sim.vehicle.cli import run

    return run(args)


def _sim_options(pairs: list[str]) -> dict:
    opts = {}
    for pair in pairs:
        key, sep, value = pair.partition("=")
        if not sep or not key:
            raise CompanionError(f"--sim-arg {pair!r} is not OPT=VALUE", "write e.g. --sim-arg packet-loss=20")
        opts[key.replace("-", "_")] = value
    return opts


def _flight_parameters(pairs: list[str]) -> dict[str, float]:
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


def _fly(args: argparse.Namespace) -> int:
    from companion.flight.fly import fly_mission_sync
    from companion.flight.simulator import SimulatorProcess
    from companion.mission import load_mission, plan_scan

    mission = load_mission(args.mission)
    plan = plan_scan(mission)
    for warning in getattr(plan, "warnings", []) or []:
        log.warning("plan: %s", warning)
    if args.capture and args.out is None:
        raise CompanionError("--capture needs --out DIR for the keyframe spool", "add --out out/spool")
    if args.capture == "sim" and not args.sitl:
        raise CompanionError("--capture sim needs --sitl (it starts the simulated camera)", "add --sitl")
    url = args.connect
    capture = args.capture
    sim = None
    if args.sitl:
        home = plan.home
        options = {"autopilot": "ardupilot" if args.autopilot == "ardupilot" else "px4"}
        options.update(_sim_options(args.sim_arg))
        if capture == "sim":
            from sim.rig import SitlRig

            autopilot = options.pop("autopilot")
            sim = SitlRig(args.mission, log_dir=args.out / "sim", speedup=args.speedup, fps=args.sim_fps,
                          width_px=args.sim_width, autopilot=autopilot, sim_options=options).start()
            capture = sim.capture
        else:
            sim = SimulatorProcess(speedup=args.speedup, home=f"{home.lat},{home.lon},{home.alt_amsl_m}",
                                   **options).start()
        url = sim.url
        log.info("started the simulated vehicle (speed-up %g) on %s", args.speedup, url)
    fly_kwargs = dict(autopilot=args.autopilot, connect_timeout_s=args.connect_timeout,
                      health_timeout_s=args.health_timeout, link_loss_s=args.link_loss, flight_timeout_s=args.timeout,
                      end_action=args.end_action, progress=not args.no_progress, link_dead_s=args.link_dead,
                      stop_wait_s=args.stop_wait, lost_link_action=args.lost_link_action, return_alt=args.return_alt,
                      flight_parameters=_flight_parameters(args.set_param) or None)
    try:
        if capture:
            from companion.onboard.live import run_live_scan

            scan = run_live_scan(plan, url, capture, args.out, telemetry_log=args.telemetry_log, model=args.model,
                                 mask=not args.no_mask, gcs_camera_url=args.gcs_camera,
                                 telemetry_rate_hz=max(args.rate, 30.0), **fly_kwargs)
            result = scan.flight
            st = scan.stats
            print(f"culling: {st.frames_in} frames -> {st.keyframes} keyframes in {args.out} "
                  f"({st.skipped_backlog} skipped for CPU, {st.dropped_no_roi} without facade, "
                  f"{st.overlap_warnings} overlap warnings, {st.gaps} possible gaps)", file=sys.stderr)
        else:
            result = fly_mission_sync(plan, url, telemetry_log=args.telemetry_log, telemetry_rate_hz=args.rate,
                                      **fly_kwargs)
    finally:
        if sim is not None:
            with contextlib.suppress(Exception):
                sim.stop()
    print(flight_summary(result), file=sys.stderr)
    if result.problem:
        print(f"error: {result.problem}", file=sys.stderr)
    if result.aborted == "signal":
        return 130
    return 0 if result.completed else 1


def flight_summary(result) -> str:
    """One line for a person: how far it got, how it ended, every link loss (open ones said so)."""
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
               + ", ".join(c.name for c in result.parameter_changes) if result.parameter_changes else ""))

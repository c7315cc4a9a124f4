"""Command line of the simulated vehicle: ``python -m sim vehicle`` and ``companion sim`` share these options."""

from __future__ import annotations

import argparse
import logging
import math
import signal
import sys
from pathlib import Path

from companion.errors import CompanionError
from companion.geo import GeoPoint
from sim.vehicle.autopilot import SimVehicle, VehicleConfig
from sim.vehicle.flavours import FLAVOURS
from sim.vehicle.home_drift import PX4_HOME_CORRECTION_WINDOW_S
from sim.vehicle.model import Limits
from sim.vehicle.rangefinder import DEFAULT_MAX_M, DEFAULT_MIN_M, SEES, parse_wall

log = logging.getLogger(__name__)


def _home(text: str) -> GeoPoint:
    try:
        parts = [float(p) for p in text.split(",")]
    except ValueError:
        parts = []
    if len(parts) != 3 or not (-90 <= parts[0] <= 90 and -180 <= parts[1] <= 180):
        raise argparse.ArgumentTypeError(f"--home wants LAT,LON,ALT_AMSL (e.g. 37.56638,126.97815,30), got {text!r}")
    return GeoPoint(*parts)


def _params(text: str) -> dict[str, float]:
    out = {}
    for part in filter(None, (p.strip() for p in text.split(","))):
        name, sep, value = part.partition("=")
        try:
            out[name.strip()] = float(value)
        except ValueError:
            sep = ""
        if not sep or not name.strip():
            raise argparse.ArgumentTypeError(f"--params wants NAME=VALUE[,NAME=VALUE...], got {part!r}")
    return out


def _gnss_bias(text: str) -> tuple[float, float, float]:
    try:
        parts = [float(p) for p in text.split(",")]
    except ValueError:
        parts = []
    if len(parts) != 3 or not all(math.isfinite(v) for v in parts):
        raise argparse.ArgumentTypeError(f"--gnss-bias wants EAST,NORTH,UP in metres (e.g. 1.5,0,0; a negative first "
                                         f"value as --gnss-bias=-1.5,0,0), got {text!r}")
    return parts[0], parts[1], parts[2]


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--home", type=_home, default=GeoPoint(37.56638, 126.97815, 30.0),
                   help="home LAT,LON,ALT_AMSL (default: the demo mission's takeoff point)")
    p.add_argument("--home-yaw", type=float, default=0.0, help="initial heading, degrees from north")
    p.add_argument("--autopilot", choices=sorted(FLAVOURS), default="px4", help="behave like PX4 or ArduCopter")
    p.add_argument("--speedup", type=float, default=1.0, help="simulated seconds per wall second")
    p.add_argument("--seed", type=int, default=0, help="seed for wind, GPS noise and packet loss")
    p.add_argument("--mavlink-host", default="127.0.0.1", help="where the GCS/companion listens")
    p.add_argument("--mavlink-port", type=int, default=14540,
                   help="UDP port the vehicle sends MAVLink to (PX4 SITL: 14540; connect with udp://:PORT)")
    p.add_argument("--bind-port", type=int, default=0, help="local UDP port of the vehicle (0: any free port)")
    p.add_argument("--pose-port", type=int, default=14660, help="true-pose JSON channel for sim.camera (0: off)")
    p.add_argument("--truth-log", type=Path, help="also write every true pose as JSON lines to this file")
    p.add_argument("--wind", type=float, default=0.0, help="mean wind speed, m/s")
    p.add_argument("--wind-from", type=float, help="wind direction (from), degrees; default: random by seed")
    p.add_argument("--gusts", type=float, default=0.0, help="peak gust amplitude, m/s")
    p.add_argument("--gps-noise", type=float, default=0.0, help="GPS position error std (random walk), metres")
    p.add_argument("--gnss-bias", type=_gnss_bias, default=(0.0, 0.0, 0.0), metavar="E,N,U",
                   help="GNSS bias: the estimate (telemetry, position control) is this far East,North,Up of the true "
                        "vehicle, metres; the vehicle flies its estimate, so it truly sits at minus this "
                        "(e.g. 1.5,0,0; default 0,0,0: off)")
    p.add_argument("--gnss-drift", type=float, default=0.0, metavar="M_PER_MIN",
                   help="the GNSS bias also random-walks: RMS growth per axis after one minute, metres (grows as "
                        "the square root of time; seeded by --seed; default 0: a constant bias)")
    p.add_argument("--gnss-drift-max", type=float, default=None, metavar="M",
                   help="clamp the bias's random walk to +-M metres per axis (default: unbounded)")
    p.add_argument("--rangefinder", action="store_true",
                   help="fit a forward laser rangefinder: DISTANCE_SENSOR (orientation forward) at 10 Hz, the TRUE "
                        "distance along the heading to --rangefinder-wall (no wall in range: max + 1 cm)")
    p.add_argument("--rangefinder-wall", type=parse_wall, default=None,
                   metavar="LAT,LON,LAT,LON,BASE_AMSL,HEIGHT",
                   help="the wall the rangefinder sees: both base ends, the base altitude AMSL and the height (the "
                        "SITL rig and fly --sitl pass the mission's wall)")
    p.add_argument("--rangefinder-sees", choices=SEES, default="wall",
                   help="what the forward-labelled rangefinder measures: the wall (default) or, as real ArduCopter "
                        "SITL's simulated one did, the height above the ground (a sensor mounted or configured wrong)")
    p.add_argument("--rangefinder-max", type=float, default=DEFAULT_MAX_M, metavar="M",
                   help=f"rangefinder's maximum range, metres (default {DEFAULT_MAX_M:g})")
    p.add_argument("--packet-loss", type=float, default=0.0, metavar="PCT", help="drop this percent of datagrams")
    p.add_argument("--latency-ms", type=float, default=0.0, help="added one-way link latency, wall ms")
    p.add_argument("--stream-stall", type=float, default=0.0, metavar="S",
                   help="ATTITUDE and GLOBAL_POSITION_INT each stall now and then (held back, then sent in order) "
                        "for up to S simulated seconds, so their time stamps disagree on the link by that much as "
                        "real PX4 SITL's did at speed-up 4 (up to 7 s, mostly under 1 s); 0 (default): off")
    p.add_argument("--stream-stall-every", type=float, default=30.0, metavar="S",
                   help="mean simulated seconds between one stream's stalls (default 30)")
    p.add_argument("--outage-at", type=float, metavar="S", help="link outage begins at this simulated time, s")
    p.add_argument("--outage-s", type=float, default=5.0, metavar="N", help="link outage length, wall seconds")
    p.add_argument("--gps-glitch-at", type=float, metavar="S", help="GPS jumps at this simulated time, s")
    p.add_argument("--gps-glitch-m", type=float, default=5.0, help="GPS glitch size, metres")
    p.add_argument("--gps-glitch-s", type=float, default=3.0, help="GPS glitch length, simulated seconds")
    p.add_argument("--max-mission-items", type=int, default=None,
                   help="larger uploads are refused (NO_SPACE); default the firmware's: PX4 500, ArduCopter 650")
    p.add_argument("--duration", type=float, help="exit after this much simulated time, s")
    p.add_argument("--params", type=_params, default={}, metavar="NAME=VALUE,...",
                   help="parameter values at boot, over the flavour's defaults (e.g. WP_YAW_BEHAVIOR=0)")
    p.add_argument("--max-speed", type=float, default=12.0, help="max horizontal speed, m/s")
    add_firmware_arguments(p)
    p.add_argument("--max-accel", type=float, default=4.0, help="max acceleration, m/s^2")


def add_firmware_arguments(p: argparse.ArgumentParser) -> None:
    """Firmware behaviours that end or refuse a flight (sim/vehicle/firmware.py)."""
    p.add_argument("--reboot-after-takeoff", type=float, metavar="S",
                   help="the autopilot reboots this many simulated seconds after take-off (on the ground again, "
                        "time_boot_ms from 0)")
    p.add_argument("--outage-after-takeoff", type=float, metavar="S",
                   help="link outage begins this many simulated seconds after take-off (length: --outage-s)")
    p.add_argument("--reboot-s", type=float, default=2.0, help="link silence while rebooting, wall seconds")
    p.add_argument("--geofence-max-dist", type=float, metavar="M",
                   help="PX4 GF_MAX_HOR_DIST: a mission beyond it is accepted, then its takeoff refused")
    p.add_argument("--gps-ready-after", type=float, metavar="S",
                   help="simulated seconds after boot until the estimator uses GPS (default: ArduCopter 38, PX4 0)")
    p.add_argument("--storage", type=Path,
                   help="PX4 flavour: keep the mission and its current item in this file across restarts")
    p.add_argument("--home-shift-after-takeoff", type=float, metavar="S",
                   help="PX4 flavour, with --home-shift-m: the one move of home's altitude comes this many "
                        "simulated seconds after take-off (at most 120, PX4's correction window)")
    p.add_argument("--home-shift-m", type=float, default=None, metavar="M",
                   help="PX4 flavour: move home's altitude once by M metres (up positive) instead of the default, "
                        "which moves it as real PX4 SIH does for 120 s after take-off (about 140 moves with SIH's "
                        "GPS noise, ending -0.8 .. +1.5 m off in 18 real flights); 0: home stays where it armed")
    p.add_argument("--init-s", type=float, metavar="S",
                   help="wall seconds after (re)boot until the autopilot has initialised: only HEARTBEAT is sent and "
                        "a mission upload is refused (ArduCopter: NO_SPACE, 'Only 0 items are supported'); default "
                        "ArduCopter 1, PX4 0")
    p.add_argument("--heartbeat-autopilot", type=int, metavar="N",
                   help="MAV_AUTOPILOT number the HEARTBEAT names instead of the flavour's (e.g. 0, generic: a "
                        "firmware the companion does not fly, which it must refuse)")


def firmware_config(args: argparse.Namespace) -> dict:
    return dict(reboot_after_takeoff_s=args.reboot_after_takeoff, reboot_s=args.reboot_s,
                geofence_max_dist_m=args.geofence_max_dist, gps_ready_after_s=args.gps_ready_after,
                storage=args.storage, outage_after_takeoff_s=args.outage_after_takeoff, init_s=args.init_s,
                home_shift_after_takeoff_s=args.home_shift_after_takeoff, home_shift_m=args.home_shift_m,
                heartbeat_autopilot=args.heartbeat_autopilot)


def _check_home_shift(args: argparse.Namespace) -> None:
    """An explicit home move is PX4's, within its window, and says how far; ``--home-shift-m 0`` alone keeps home."""
    shift_at, shift_m = args.home_shift_after_takeoff, args.home_shift_m
    if not FLAVOURS[args.autopilot].moves_home_in_flight and (shift_at is not None or shift_m):
        raise CompanionError(f"--home-shift-m / --home-shift-after-takeoff with --autopilot {args.autopilot}: only "
                             "PX4 moves home in flight (ArduCopter keeps it where it armed)",
                             "use --autopilot px4, or leave both options out")
    if shift_at is not None and not 0.0 <= shift_at <= PX4_HOME_CORRECTION_WINDOW_S:
        raise CompanionError(f"--home-shift-after-takeoff {shift_at:g}: PX4 moves home only within "
                             f"{PX4_HOME_CORRECTION_WINDOW_S:g} s of take-off", "use a time between 0 and 120 s")
    if shift_at is not None and shift_m is None:
        raise CompanionError(f"--home-shift-after-takeoff {shift_at:g} without --home-shift-m: how far home moves "
                             "is not given", "add e.g. --home-shift-m -1.2 (or leave both out for PX4 SIH's moves)")
    if shift_m and shift_at is None:
        raise CompanionError(f"--home-shift-m {shift_m:g} without --home-shift-after-takeoff: when home moves is not "
                             "given", "add e.g. --home-shift-after-takeoff 30 (or --home-shift-m 0 for a still home)")


def _check_gnss(args: argparse.Namespace) -> None:
    """A drift is a rate and its bound a size: neither negative nor NaN."""
    if not (math.isfinite(args.gnss_drift) and args.gnss_drift >= 0):
        raise CompanionError(f"--gnss-drift {args.gnss_drift:g} is not a rate >= 0",
                             "give metres per minute, e.g. --gnss-drift 0.5 (0: a constant bias)")
    if args.gnss_drift_max is not None and not (math.isfinite(args.gnss_drift_max) and args.gnss_drift_max > 0):
        raise CompanionError(f"--gnss-drift-max {args.gnss_drift_max:g} is not a positive size",
                             "give metres, e.g. --gnss-drift-max 2, or leave it out for an unbounded walk")


def config_from_args(args: argparse.Namespace) -> VehicleConfig:
    if not 0.0 <= args.packet_loss < 100.0:
        raise CompanionError(f"--packet-loss {args.packet_loss} is not a percentage below 100",
                             "give e.g. --packet-loss 20")
    if args.speedup <= 0:
        raise CompanionError(f"--speedup {args.speedup} must be positive", "use e.g. --speedup 10")
    if args.stream_stall < 0 or args.stream_stall_every <= 0:
        raise CompanionError(f"--stream-stall {args.stream_stall} / --stream-stall-every {args.stream_stall_every}: "
                             "a stall cannot be negative nor stalls come every 0 s",
                             "give e.g. --stream-stall 2.5 --stream-stall-every 30")
    _check_home_shift(args)
    _check_gnss(args)
    if args.rangefinder and not DEFAULT_MIN_M < args.rangefinder_max <= 650.0:
        raise CompanionError(f"--rangefinder-max {args.rangefinder_max:g} is not a rangefinder's range",
                             f"give metres above {DEFAULT_MIN_M:g} and at most 650 (DISTANCE_SENSOR's 16-bit cm)")
    if args.rangefinder and args.rangefinder_wall is None:
        log.warning("--rangefinder without --rangefinder-wall: there is nothing to see, every reading is 'none'")
    return VehicleConfig(
        home=args.home, home_yaw_deg=args.home_yaw, speedup=args.speedup, seed=args.seed, autopilot=args.autopilot,
        target=(args.mavlink_host, args.mavlink_port), bind_port=args.bind_port, pose_port=args.pose_port or None,
        truth_log=args.truth_log, wind_m_s=args.wind, gusts_m_s=args.gusts, wind_from_deg=args.wind_from,
        gps_noise_m=args.gps_noise, gnss_bias_enu_m=tuple(args.gnss_bias), gnss_drift_m_per_min=args.gnss_drift,
        gnss_drift_max_m=args.gnss_drift_max, rangefinder=args.rangefinder, rangefinder_wall=args.rangefinder_wall,
        rangefinder_max_m=args.rangefinder_max, rangefinder_sees=args.rangefinder_sees,
        packet_loss=args.packet_loss / 100.0, latency_ms=args.latency_ms,
        stream_stall_s=args.stream_stall, stream_stall_every_s=args.stream_stall_every,
        outage_at_s=args.outage_at, outage_s=args.outage_s,
        gps_glitch_at_s=args.gps_glitch_at, gps_glitch_m=args.gps_glitch_m, gps_glitch_s=args.gps_glitch_s,
        duration_s=args.duration, max_mission_items=args.max_mission_items, params=dict(args.params),
        limits=Limits(max_speed_h_m_s=args.max_speed, max_accel_m_s2=args.max_accel),
        **firmware_config(args),
    )


def run(args: argparse.Namespace) -> int:
    """Start the vehicle and run until SIGINT/SIGTERM (or ``--duration``)."""
    cfg = config_from_args(args)
    vehicle = SimVehicle(cfg)

    def _stop(signum, frame):
        vehicle.stop()

    signal.signal(signal.SIGTERM, _stop)
    signal.signal(signal.SIGINT, _stop)
    port = vehicle.link.sock.getsockname()[1]
    print(f"sim vehicle ({cfg.autopilot}): home {cfg.home.lat:.6f},{cfg.home.lon:.6f},{cfg.home.alt_amsl_m:.1f} "
          f"speedup {cfg.speedup:g}; MAVLink to {cfg.target[0]}:{cfg.target[1]} from :{port} "
          f"(connect with udp://:{cfg.target[1]}); pose channel :{cfg.pose_port or 'off'}",
          file=sys.stderr, flush=True)
    vehicle.run()
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m sim vehicle", description="Simulated MAVLink multirotor (SITL)")
    parser.add_argument("-v", "--verbose", action="store_true")
    add_arguments(parser)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO,
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    try:
        return run(args)
    except CompanionError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2

"""Fly a mission in SITL while the simulated camera records: the recording an evaluation trusts most, because
the poses come from the simulated vehicle's dynamics under the real flight code (upload, arm, mission, RTL).

    python -m sim.camera.record_flight missions/demo-facade.yaml --out recordings/demo-sitl [--fps 5] [--speedup 2]

Three processes, as on a real drone: the SITL vehicle (``python -m sim vehicle``), the camera
(``python -m sim camera --record``, fed by the vehicle's true-pose channel) and the companion's flight code
(:func:`companion.flight.fly.fly_mission`), which writes ``telemetry.jsonl`` into the same directory. Only frames
taken near the wall (the scan, not takeoff and transit) are recorded. Rendering slower than simulated time
drops frames (capture times stay exact): lower ``--fps``/``--width`` or the ``--speedup`` to keep them all.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
from dataclasses import asdict
from pathlib import Path

from companion.errors import CompanionError
from sim.camera.recording import resolve_mission
from sim.rig import SitlRig, fly_at_once_with_still_home, sitl_profile_for
from sim.vehicle.flavours import FLAVOURS

log = logging.getLogger(__name__)


def record_flight(mission_path: str | Path, out_dir: str | Path, *, seed: int = 0, width_px: int = 640,
                  fps: float = 5.0, speedup: float = 2.0, autopilot: str = "px4", progress: bool = False,
                  sim_options: dict | None = None, flight_timeout_s: float = 1800.0) -> Path:
    """Fly ``mission_path`` in SITL and record the camera; returns the recording directory."""
    from companion.flight.fly import fly_mission_sync
    from companion.mission import plan_scan

    # a recording is about frames: the simulator keeps home still and the scan starts at once, not after PX4's
    # 120 s home correction (which the simulator's PX4 flavour otherwise reproduces, as real PX4 SIH does it)
    mission, sim_options = fly_at_once_with_still_home(resolve_mission(mission_path), sim_options)
    if sim_options.get("home_shift_m") == 0 and mission.margins.home_settle_s == 0:
        log.info("recording flight: the simulator keeps home where it armed (home-shift-m 0), so the scan starts at "
                 "once (margins.home_settle_s 0; a real PX4 moves home for 120 s after take-off)")
    plan = plan_scan(mission)
    out = Path(out_dir)
    if (out / "meta.json").exists():
        raise CompanionError(f"{out} already holds a recording", "choose a new --out directory or delete it")
    if fps <= 0 or speedup <= 0:
        raise CompanionError(f"fps={fps} and speedup={speedup} must be positive", "use e.g. --fps 5 --speedup 2")
    out.mkdir(parents=True, exist_ok=True)
    rig = SitlRig(mission_path, log_dir=out, seed=seed, width_px=width_px, fps=fps, speedup=speedup,
                  autopilot=autopilot, record_dir=out, record_max_out_m=float(mission.standoff_m) * 1.5 + 1.0,
                  sim_options=sim_options)
    with rig:
        result = fly_mission_sync(plan, rig.url, telemetry_log=out / "telemetry.jsonl", progress=progress,
                                  end_action=mission.end_action, flight_timeout_s=flight_timeout_s,
                                  handle_signals=False, sitl_profile=sitl_profile_for(autopilot))
    meta_p = out / "meta.json"
    if not meta_p.exists():
        raise CompanionError("the camera wrote no recording", f"see {out / 'camera.log'}")
    meta = json.loads(meta_p.read_text())
    flight = {k: (str(v) if isinstance(v, Path) else v) for k, v in asdict(result).items()}
    meta["generator"].update({"kind": "sitl", "speedup": speedup, "autopilot": autopilot, "flight": flight})
    meta_p.write_text(json.dumps(meta, indent=1))
    if not result.completed:
        log.warning("the flight did not complete (%s); the recording holds what was flown", result.aborted)
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m sim.camera.record_flight", description=__doc__.split("\n\n")[0])
    p.add_argument("mission", type=Path)
    p.add_argument("--out", type=Path, required=True, help="recording directory (must not hold one already)")
    p.add_argument("--seed", type=int, default=0, help="scene and simulator seed")
    p.add_argument("--width", type=int, default=640, help="camera working width, px")
    p.add_argument("--fps", type=float, default=5.0, help="recorded frame rate in simulated time")
    p.add_argument("--speedup", type=float, default=2.0, help="simulated seconds per wall second")
    p.add_argument("--autopilot", choices=sorted(FLAVOURS), default="px4")
    a = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    try:
        out = record_flight(a.mission, a.out, seed=a.seed, width_px=a.width, fps=a.fps, speedup=a.speedup,
                            autopilot=a.autopilot, progress=True)
    except CompanionError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    meta = json.loads((out / "meta.json").read_text())
    print(f"recorded {meta.get('frames', 0)} frames to {out} (flight completed: "
          f"{meta['generator']['flight']['completed']})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

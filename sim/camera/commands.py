"""``companion record``: write a simulator recording (frames + ground truth) of a mission.

By default the mission is flown in SITL (vehicle + camera processes + the companion's flight code, see
``sim.camera.record_flight``); ``--fast`` instead samples the planned path with a kinematic model (no SITL,
seconds for a hundred frames), which is what tests and quick evaluations use.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from companion.resources import mission_argument


def register(sub) -> None:
    p = sub.add_parser("record", help="fly a mission in SITL with the simulated camera and write a recording "
                                      "(frames, depth, ROI masks, poses, telemetry)")
    p.add_argument("mission", type=mission_argument,
                   help="mission YAML (e.g. missions/demo-facade.yaml) or a shipped mission's name (demo-facade)")
    p.add_argument("--out", type=Path, required=True, help="recording directory (must not hold one already)")
    p.add_argument("--seed", type=int, default=0, help="scene seed (wall material, windows, background, light)")
    p.add_argument("--width", type=int, default=640, help="camera working width in px (lens and aspect kept)")
    p.add_argument("--fast", action="store_true",
                   help="no SITL: kinematic flight along the planned scan path at the camera's fps")
    p.add_argument("--max-frames", type=int, help="with --fast: stop after this many frames")
    p.add_argument("--stride", type=int, default=1, help="with --fast: keep every N-th camera frame")
    p.add_argument("--fps", type=float, default=5.0, help="SITL: recorded frame rate in simulated time")
    p.add_argument("--speedup", type=float, default=2.0, help="SITL: simulated seconds per wall second")
    p.add_argument("--autopilot", choices=["px4", "ardupilot"], default="px4", help="SITL: autopilot flavour")
    p.set_defaults(func=_record)


def _record(args: argparse.Namespace) -> int:
    if args.fast:
        from sim.camera.recording import generate_recording

        out = generate_recording(args.mission, args.out, seed=args.seed, width_px=args.width,
                                 max_frames=args.max_frames, stride=args.stride, progress=True)
    else:
        from sim.camera.record_flight import record_flight

        out = record_flight(args.mission, args.out, seed=args.seed, width_px=args.width, fps=args.fps,
                            speedup=args.speedup, autopilot=args.autopilot, progress=True)
    meta = json.loads((out / "meta.json").read_text())
    print(f"recorded {meta.get('frames', 0)} frames ({meta['camera']['width']}x{meta['camera']['height']}) "
          f"to {out}")
    return 0

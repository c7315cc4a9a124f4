"""Two checkouts' warp renderers timed on the same frames in one process, alternating which goes first, with a bit
for bit comparison of every frame: a paired measurement that resolves a few per cent at a load where two
concurrent ``camera_speed.py`` runs differ by more than that.

    python bench/camera_paired.py OTHER_CHECKOUT [--width 1280] [--every 2]

Frames: the demo mission's whole planned scan (kinematic flight, scene seed 0), one every ``--every`` seconds, each
right after a frame 1/fps earlier (tiles and patches built there, as in ``camera_speed.py --scan-every``); sensor
noise and auto exposure on (each checkout its own exposure state, fed the same frames). Prints, per checkout, the
render CPU per frame (mean and median, plain-wall frames and frames with an edge apart) and how many frames were
identical (image, z-depth, surface ids) in both.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(HERE))  # bench.camera_identity, run as a script


def _rig(root: Path, mission_path: Path, width: int):
    """A warp renderer, flight and exposure built by the ``sim`` package of checkout ``root`` (imported afresh)."""
    from bench.camera_identity import warp_rig

    return warp_rig(root, mission_path, width)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("other", type=Path, help="the other checkout's root (holds sim/camera/)")
    p.add_argument("--mission", type=Path, default=HERE / "missions/demo-facade.yaml")
    p.add_argument("--width", type=int, default=1280)
    p.add_argument("--every", type=float, default=2.0, help="one measured frame every this many seconds of scan")
    a = p.parse_args()
    rigs = {"other": _rig(a.other.resolve(), a.mission, a.width), "this": _rig(HERE, a.mission, a.width)}
    flight, fps = rigs["this"][1], rigs["this"][3]
    dt = 1.0 / fps
    cpu: dict = {k: {"plain": [], "edge": []} for k in rigs}
    same, load0 = 0, os.getloadavg()[0]
    for i, t in enumerate(np.arange(dt, flight.duration_s, a.every)):
        before, pose = flight.pose(float(t) - dt), flight.pose(float(t))
        got = {}
        for k in ("other", "this") if i % 2 else ("this", "other"):
            r, _, ae, _ = rigs[k]
            r.render(before, index=2 * i, time_s=float(t) - dt, exposure=ae)
            c0 = time.process_time()
            got[k] = f = r.render(pose, index=2 * i + 1, time_s=float(t), exposure=ae)
            spent = time.process_time() - c0
            cpu[k]["plain" if float(np.mean(f.roi_mask > 0)) > 0.99 else "edge"].append(spent)
        same += all(np.array_equal(getattr(got["other"], n), getattr(got["this"], n))
                    for n in ("image", "depth", "surface"))
    frames = sum(len(v) for v in cpu["this"].values())
    print(f"{a.width} px, {frames} frames of {a.mission.name}, load average {load0:.1f} -> {os.getloadavg()[0]:.1f}; "
          f"identical (image, depth, surfaces): {same} of {frames}")
    for k, root in (("other", a.other.resolve()), ("this", HERE)):
        parts = [f"{kind} ({len(v)}) mean {1000 * np.mean(v):.2f} / median {1000 * np.median(v):.2f} ms"
                 for kind, v in cpu[k].items() if v]
        total = [x for v in cpu[k].values() for x in v]
        print(f"{k} ({root}): render CPU per frame mean {1000 * np.mean(total):.2f} ms; " + "; ".join(parts))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

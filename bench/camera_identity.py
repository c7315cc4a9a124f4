"""Frames of two checkouts' warp renderers side by side: are images (sensor noise on), z-depth and surface ids
identical bit for bit on poses along the demo mission's planned scan (kinematic flight, scene seed 0)?

    python bench/camera_identity.py OTHER_CHECKOUT [--width 640] [--poses 16] [--no-noise]

A speed change that claims identical output is checked with this against the checkout before it (e.g.
``git -C /work/main archive HEAD | tar -x -C /tmp/main`` then ``python bench/camera_identity.py /tmp/main``).
Prints each checkout's render CPU and, per differing pose, which of the three differ and by how much. A change of
the noise model alone shows as images differing with noise and identical with ``--no-noise``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parents[1]


def warp_rig(root: Path, mission_path: Path, width: int, noise: bool = True):
    """A warp renderer, flight, exposure and the camera's fps built by the ``sim`` package of checkout ``root``
    (imported afresh from there, so two checkouts can be compared in one process)."""
    for name in [k for k in sys.modules if k == "sim" or k.startswith("sim.")]:
        del sys.modules[name]
    sys.path.insert(0, str(root))
    try:
        from companion.mission import load_mission, plan_scan
        from sim.camera.recording import camera_from_mission
        from sim.camera.render import AutoExposure
        from sim.camera.scene import Scene
        from sim.camera.trajectory import KinematicFlight, scan_path
        from sim.camera.warp_render import WarpRenderer
    finally:
        sys.path.pop(0)
    mission = load_mission(mission_path)
    plan = plan_scan(mission)
    cam = camera_from_mission(mission, width)
    scene = Scene.build(plan.frame.length_m, float(mission.facade.height_m), seed=0)
    r = WarpRenderer(scene, plan.frame, cam, exposure_s=float(mission.camera.exposure_s), seed=0, noise=noise)
    return r, KinematicFlight(plan.frame, scan_path(plan), seed=0), AutoExposure(seed=0), float(mission.camera.fps)


def _frames(root: Path, mission_path: Path, width: int, poses: int, noise: bool) -> tuple[list, float, str]:
    """Render the poses with the ``sim`` package of checkout ``root`` (imported afresh from there)."""
    r, flight, ae, _ = warp_rig(root, mission_path, width, noise)
    out = []
    c0 = time.process_time()
    for i, t in enumerate(np.linspace(0.0, flight.duration_s, poses)):
        f = r.render(flight.pose(float(t)), index=i, time_s=float(t), exposure=ae)
        out.append((f.image, f.depth, f.surface))
    return out, time.process_time() - c0, str(Path(sys.modules["sim.camera.warp_render"].__file__))


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("other", type=Path, help="the other checkout's root (holds sim/camera/)")
    p.add_argument("--mission", type=Path, default=HERE / "missions/demo-facade.yaml")
    p.add_argument("--width", type=int, default=640)
    p.add_argument("--poses", type=int, default=16, help="poses evenly spread over the scan's duration")
    p.add_argument("--no-noise", action="store_true", help="render without sensor noise (the scene and exposure)")
    a = p.parse_args()
    got = {}
    for tag, root in (("other", a.other.resolve()), ("this", HERE)):
        frames, cpu, path = _frames(root, a.mission, a.width, a.poses, not a.no_noise)
        got[tag] = frames
        print(f"{tag}: {path}, {cpu:.1f} s CPU for {a.poses} frames", flush=True)
    bad = 0
    for i, (x, y) in enumerate(zip(got["other"], got["this"], strict=True)):
        same = [np.array_equal(u, v) for u, v in zip(x, y, strict=True)]
        if not all(same):
            bad += 1
            d = np.abs(x[0].astype(np.int16) - y[0])
            print(f"pose {i}: image / depth / surface identical: {same}; image differs by up to {int(d.max())} DN "
                  f"on {int((d > 0).any(-1).sum())} pixels, mean {float(x[0].mean()):.2f} / {float(y[0].mean()):.2f} "
                  f"DN, difference std {float((x[0].astype(np.float32) - y[0]).std()):.2f} DN")
    print(f"{a.width} px, {a.poses} poses: {a.poses - bad} identical, {bad} differ")
    return 1 if bad else 0


if __name__ == "__main__":
    raise SystemExit(main())

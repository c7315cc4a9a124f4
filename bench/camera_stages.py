"""Where the warp renderer's CPU goes: per-stage CPU per frame over the whole planned scan at one width, plain-wall
frames and frames with an edge apart (the same frames as ``camera_speed.py --scan-every``).

    python bench/camera_stages.py [--mission missions/demo-facade.yaml] [--width 1280] [--every 2]

Each stage is a ``WarpRenderer`` method timed (process CPU) by a wrapper around it; nested stages are included in
their callers (``_warp`` in ``_draw_face``, which is in ``radiance_u8``), and the wrappers add a little overhead, so
read the figures against each other, not against ``camera_speed.py``'s totals. ``_draw_face`` is also split by
the face's surface (``face:far_building``, ``face:target_wall``, ...). Run it in two checkouts at the same time to
compare them under the same load.
"""

from __future__ import annotations

import argparse
import collections
import os
import sys
import time
from pathlib import Path

import cv2
import numpy as np

import sim.camera.warp_render as warp_render
from companion.mission import load_mission

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # the bench.* modules it borrows from, run as a script

STAGES = ("_radiance", "radiance_u8", "_draw_face", "_blurred", "_draw_trees", "_draw_trunks", "_draw_sky", "_expose",
          "_motion_blur", "_object_rects", "_candidates", "_warp", "_hazed", "_patch", "_level", "_rect_mask",
          "_hidden", "_polygon", "_face_extent")


def _instrument(acc: dict) -> None:
    from sim.camera.render import SURFACE_NAMES

    cls = warp_render.WarpRenderer
    for name in STAGES:
        if not hasattr(cls, name):
            continue
        fn = getattr(cls, name)
        static = isinstance(cls.__dict__.get(name), staticmethod)

        def timed(*a, _fn=fn, _name=name, **k):
            c0 = time.process_time()
            try:
                return _fn(*a, **k)
            finally:
                acc[_name] += time.process_time() - c0
                if _name == "_draw_face":  # (self, face, ...): by surface too
                    acc["face:" + SURFACE_NAMES[a[1].surface]] += time.process_time() - c0

        setattr(cls, name, staticmethod(timed) if static else timed)


def main() -> int:
    from bench.camera_speed import _camera_rig

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--mission", type=Path, default=Path("missions/demo-facade.yaml"))
    p.add_argument("--width", type=int, default=1280)
    p.add_argument("--every", type=float, default=2.0, help="one measured frame every this many seconds of scan")
    a = p.parse_args()
    acc: dict = collections.defaultdict(float)
    _instrument(acc)
    mission = load_mission(a.mission)
    _, r, flight, ae = _camera_rig(mission, a.width, 0, "warp")
    dt = 1.0 / float(mission.camera.fps)
    sums = {"plain": collections.defaultdict(float), "edge": collections.defaultdict(float)}
    count: collections.Counter = collections.Counter()
    for i, t in enumerate(np.arange(dt, flight.duration_s, a.every)):
        r.render(flight.pose(float(t) - dt), index=2 * i, time_s=float(t) - dt, exposure=ae)  # tiles, patches
        acc.clear()
        c0 = time.process_time()
        f = r.render(flight.pose(float(t)), index=2 * i + 1, time_s=float(t), exposure=ae)
        total = time.process_time() - c0
        c0 = time.process_time()
        cv2.imencode(".jpg", f.image, [cv2.IMWRITE_JPEG_QUALITY, 88])
        jpeg = time.process_time() - c0
        kind = "plain" if float(np.mean(f.roi_mask > 0)) > 0.99 else "edge"
        count[kind] += 1
        sums[kind]["render"] += total
        sums[kind]["jpeg"] += jpeg
        for k, v in acc.items():
            sums[kind][k] += v
    print(f"{warp_render.__file__}, {a.width} px, load average {os.getloadavg()[0]:.1f}; mean CPU ms per frame")
    for kind, s in sums.items():
        n = max(count[kind], 1)
        print(f"{kind} ({count[kind]} frames): " + ", ".join(f"{k} {1000 * v / n:.1f}" for k, v in
                                                             sorted(s.items(), key=lambda kv: -kv[1])))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

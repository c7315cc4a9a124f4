"""What a warp-rendered camera frame cannot go below: the per-pixel passes every frame needs, timed on the frames of
the demo scan in the same run as the whole render, so the rest (per-face work and Python) reads off beside them.

    python bench/camera_floor.py [--mission missions/demo-facade.yaml] [--width 1280] [--every 2]

Per measured frame (the whole planned scan, one frame every ``--every`` seconds, each right after a frame 1/fps
earlier, as ``camera_speed.py --scan-every``): the renderer's ``render`` CPU, then on that frame's own data the
passes a frame of this design always pays: one full-frame bilinear ``warpPerspective`` of the wall's cached BGRA
patch (the wall face-on), its BGRA -> BGR conversion, the frame mean (auto exposure), gain + noise (one
``addWeighted``) and the JPEG encode at the live stream's quality 88. Mean CPU ms per frame, plain-wall frames and
frames with an edge apart, and the load average.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import cv2
import numpy as np

from companion.mission import load_mission

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # the bench.* modules it borrows from, run as a script


def _cpu(fn, repeat: int = 3) -> float:
    """Least process CPU of ``repeat`` calls (seconds): the pass's own cost, least disturbed by the load."""
    best = float("inf")
    for _ in range(repeat):
        c0 = time.process_time()
        fn()
        best = min(best, time.process_time() - c0)
    return best


def floor_passes(renderer, image: np.ndarray) -> dict:
    """CPU of each fixed per-pixel pass for a frame of ``image``'s size (the wall's patch as the warp source)."""
    h, w = image.shape[:2]
    cache = renderer._patch_cache  # face index -> (range, (BGRA patch, ...)); face 0 is the target wall
    patch = (cache[0] if 0 in cache else next(iter(cache.values())))[1][0]
    s = min(patch.shape[1] / w, patch.shape[0] / h, 1.0) * 0.98
    Hm = np.array([[1.0 / s, 0.01, 0.0], [-0.01, 1.0 / s, 0.0], [1e-7, 1e-7, 1.0]])  # near face-on, as flown
    bgra = cv2.warpPerspective(patch, Hm, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    flat = image.reshape(h, -1)
    noise = np.random.default_rng(0).integers(0, 31, flat.shape, dtype=np.uint8)
    return {
        "warp": _cpu(lambda: cv2.warpPerspective(patch, Hm, (w, h), flags=cv2.INTER_LINEAR,
                                                 borderMode=cv2.BORDER_REPLICATE)),
        "bgra_to_bgr": _cpu(lambda: cv2.cvtColor(bgra, cv2.COLOR_BGRA2BGR)),
        "mean": _cpu(lambda: cv2.mean(image)),
        "gain_noise": _cpu(lambda: cv2.addWeighted(flat, 1.05, noise, 0.4, -6.0)),
        "jpeg_q88": _cpu(lambda: cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 88])),
    }


def main() -> int:
    from bench.camera_speed import _camera_rig

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--mission", type=Path, default=Path("missions/demo-facade.yaml"))
    p.add_argument("--width", type=int, default=1280)
    p.add_argument("--every", type=float, default=2.0, help="one measured frame every this many seconds of scan")
    a = p.parse_args()
    mission = load_mission(a.mission)
    _, r, flight, ae = _camera_rig(mission, a.width, 0, "warp")
    dt = 1.0 / float(mission.camera.fps)
    rows: dict[str, list[dict]] = {"plain": [], "edge": []}
    load0 = os.getloadavg()[0]
    for i, t in enumerate(np.arange(dt, flight.duration_s, a.every)):
        r.render(flight.pose(float(t) - dt), index=2 * i, time_s=float(t) - dt, exposure=ae)
        pose = flight.pose(float(t))
        c0 = time.process_time()
        f = r.render(pose, index=2 * i + 1, time_s=float(t), exposure=ae)
        render = time.process_time() - c0
        kind = "plain" if float(np.mean(f.roi_mask > 0)) > 0.99 else "edge"
        rows[kind].append({"render": render, **floor_passes(r, f.image)})
    print(f"{a.width} px, {sum(len(v) for v in rows.values())} frames of {a.mission}, load average {load0:.1f} "
          f"-> {os.getloadavg()[0]:.1f}; mean CPU ms per frame")
    for kind, got in rows.items():
        if not got:
            continue
        m = {k: 1000 * float(np.mean([g[k] for g in got])) for k in got[0]}
        fixed = m["warp"] + m["bgra_to_bgr"] + m["mean"] + m["gain_noise"]
        print(f"{kind} ({len(got)} frames): render {m['render']:.1f} + JPEG {m['jpeg_q88']:.1f} = "
              f"{m['render'] + m['jpeg_q88']:.1f}; fixed passes in the render {fixed:.1f} (warp {m['warp']:.1f}, "
              f"BGRA->BGR {m['bgra_to_bgr']:.1f}, mean {m['mean']:.1f}, gain+noise {m['gain_noise']:.1f}); floor "
              f"with JPEG {fixed + m['jpeg_q88']:.1f}; the rest (faces, Python) {m['render'] - fixed:.1f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

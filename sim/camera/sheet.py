"""Contact sheet of simulated frames at the building's edges (wall ends, roof line, ground), with the truth
(ROI mask, depth) of the first: the picture to look at before trusting any figure computed from recordings.

    python -m sim.camera.sheet missions/demo-facade.yaml --out docs/img/camera-contact-sheet.png
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np

from sim.camera.recording import camera_from_mission, resolve_mission
from sim.camera.render import Renderer
from sim.camera.scene import Scene
from sim.camera.trajectory import KinematicFlight, scan_path


def _label(img: np.ndarray, text: str) -> np.ndarray:
    out = img.copy()
    cv2.rectangle(out, (0, 0), (out.shape[1], 22), (0, 0, 0), -1)
    cv2.putText(out, text, (6, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 255), 1, cv2.LINE_AA)
    return out


def _depth_vis(depth: np.ndarray) -> np.ndarray:
    d = np.where(np.isfinite(depth), depth, np.inf)
    inv = np.clip(4.0 / np.maximum(d, 0.1), 0, 1)  # disparity-like: 1 at 4 m, 0 at infinity
    return cv2.applyColorMap((inv * 255).astype(np.uint8), cv2.COLORMAP_INFERNO)


def contact_sheet(mission, *, seed: int = 0, width_px: int = 640) -> np.ndarray:
    mission = resolve_mission(mission)
    from companion.mission import plan_scan

    plan = plan_scan(mission)
    cam = camera_from_mission(mission, width_px)
    scene = Scene.build(plan.frame.length_m, float(mission.facade.height_m), seed=seed)
    r = Renderer(scene, plan.frame, cam, exposure_s=float(mission.camera.exposure_s), seed=seed)
    path = scan_path(plan)
    flight = KinematicFlight(plan.frame, path, gimbal_pitch_deg=float(mission.gimbal_pitch_deg), seed=seed)
    # times at which the flight passes chosen waypoints: first strip top/middle/bottom, last strip, middle
    starts = [s.t0 for s in flight.segments]
    ends = [s.t0 + s.duration for s in flight.segments]
    moving = [i for i, s in enumerate(flight.segments) if not s.hold]
    first, last = moving[0], moving[-1]
    mid = moving[len(moving) // 2]
    shots = [
        ("left end, roof line", starts[first] + 0.1),
        ("left end, mid height", (starts[first] + ends[first]) / 2),
        ("left end, near ground", ends[first] - 0.1),
        ("mid wall", (starts[mid] + ends[mid]) / 2),
        ("right end, roof line", ends[last] - 0.1 if path[-1].up_m > path[-2].up_m else starts[last] + 0.1),
        ("right end, mid height", (starts[last] + ends[last]) / 2),
        ("right end, near ground", starts[last] + 0.1 if path[-1].up_m > path[-2].up_m else ends[last] - 0.1),
    ]
    tiles = []
    first_frame = None
    for i, (name, t) in enumerate(shots):
        f = r.render(flight.pose(t), index=i, time_s=t)
        if first_frame is None:
            first_frame = f
        roi = 100.0 * float((f.roi_mask > 0).mean())
        tiles.append(_label(f.image, f"{name}  t={t:.1f}s  ROI {roi:.0f}%"))
    mask = cv2.cvtColor(first_frame.roi_mask, cv2.COLOR_GRAY2BGR)
    tiles.insert(1, _label(mask, "truth: ROI mask (target facade)"))
    tiles.insert(2, _label(_depth_vis(first_frame.depth), "truth: depth (4 m bright, sky black)"))
    rows = [np.hstack(tiles[k : k + 3]) for k in range(0, 9, 3)]
    return np.vstack(rows)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m sim.camera.sheet", description=__doc__.split("\n\n")[0])
    p.add_argument("mission", type=Path)
    p.add_argument("--out", type=Path, default=Path("docs/img/camera-contact-sheet.png"))
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--width", type=int, default=640)
    a = p.parse_args(argv)
    sheet = contact_sheet(a.mission, seed=a.seed, width_px=a.width)
    a.out.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(a.out), sheet)
    print(f"wrote {a.out} ({sheet.shape[1]}x{sheet.shape[0]})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

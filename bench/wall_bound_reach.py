"""Can the mission's wall bound tell the chain's background-only frames from a sliver of wall at the wall's end?

For each pass (validation or held-out, ``bench/mask_sequence.py``'s ``pass_spec``: 4 m, 640 px, frames in capture
order as ``bench/mask_real.py``'s chain masks them), every background-only frame's wall bound
(``companion/depth/wall_bound.py``: the mission's wall projected from every camera centre within 2 sigma of the
pose, 1.5 m along and across the wall, 0.5 m up) from the exact pose: how many of those bounds are not empty (the
wall may be in view, so a rule keeping such frames would keep them), and how far past the wall's end the frames
are (the frame's edge past the wall's end). No network: the renders and the geometry only.

    python bench/wall_bound_reach.py --passes val-b0309-120,val-b0169-40,val-coruna-120,val-montana-40
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(1, str(Path(__file__).resolve().parents[1]))

from mask_sequence import pass_spec  # noqa: E402

from companion.depth.wall_bound import WallExtent, frontal_view, wall_bound  # noqa: E402
from sim.camera.photo_scene import PhotoPassRenderer  # noqa: E402


def reach(name: str, frames: int, background_frames: int, width: int) -> tuple[int, int, float]:
    """(background-only frames, those whose 2-sigma wall bound is not empty, the farthest of them past the point
    where the wall leaves the view, metres)."""
    spec = pass_spec(name, frames, background_frames, width)
    renderer = PhotoPassRenderer(spec)
    wall = WallExtent(spec.wall.width_m, spec.wall.height_m)
    count = bounded = 0
    farthest = 0.0
    for i in range(len(renderer)):
        frame = renderer.render(i)
        if frame.roi_mask.any():
            continue
        count += 1
        view = frontal_view(spec.camera.fx, spec.camera.width, spec.camera.height, frame.along_m, spec.standoff_m,
                            frame.up_m)
        bound = wall_bound(view, wall)
        if bound is None or bound.any():
            bounded += 1
            farthest = max(farthest, frame.along_m - renderer.half_view_m - spec.wall.width_m)
    return count, bounded, farthest


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--passes", required=True, help="comma list of validation or held-out passes")
    ap.add_argument("--frames", type=int, default=250)
    ap.add_argument("--background-frames", type=int, default=16)
    ap.add_argument("--width", type=int, default=640)
    args = ap.parse_args(argv)
    print("| pass | background-only frames | wall bound not empty | farthest of them past where the wall leaves "
          "the view |")
    print("|---|---|---|---|")
    for name in (p.strip() for p in args.passes.split(",") if p.strip()):
        count, bounded, farthest = reach(name, args.frames, args.background_frames, args.width)
        print(f"| {name} | {count} | {bounded} | {farthest:.2f} m |", flush=True)


if __name__ == "__main__":
    main()

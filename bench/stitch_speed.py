"""Stitching speed at full camera resolution: N keyframes at 3840x2160 (the paper stitched 35 such images in
about 38 min on a Xeon E5-2630 v4). Every frame of the recording is a keyframe; the true overlap of consecutive
frames is printed so the input can be compared with the paper's (Rth = 80 %).

    python -c "from sim.camera.recording import generate_recording; generate_recording(
        'missions/demo-facade.yaml', '/tmp/rec4k', stride=20, width_px=3840, max_frames=35)"
    python bench/stitch_speed.py --recording /tmp/rec4k --out /tmp/stitch_speed
"""

from __future__ import annotations

import argparse
import json
import platform
import resource
import sys
import time
from pathlib import Path

import numpy as np

from companion.stitch import StitchConfig, stitch
from companion.stitch.inputs import load_recording_input


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--recording", required=True)
    ap.add_argument("--out", default="/tmp/stitch_speed")
    ap.add_argument("--mm-per-px", type=float, default=None, help="map scale (default native)")
    ap.add_argument("--pose-noise-m", type=float, default=0.3)
    ap.add_argument("--attitude-noise-deg", type=float, default=0.5)
    args = ap.parse_args(argv)
    from sim.camera.recording import load_recording

    rec = load_recording(args.recording)
    frames = list(range(len(rec)))
    ov = [rec.true_overlap(i, i + 1) for i in range(len(rec) - 1)]
    inp = load_recording_input(
        Path(args.recording), frames=frames, pose_noise_m=args.pose_noise_m, attitude_noise_deg=args.attitude_noise_deg
    )
    t0 = time.perf_counter()
    res = stitch(inp, args.out, StitchConfig(mm_per_px=args.mm_per_px), progress=False)
    dt = time.perf_counter() - t0
    out = {
        "machine": f"{platform.machine()} {platform.system()}, python {sys.version.split()[0]}",
        "keyframes": len(frames),
        "image_size": [rec.width, rec.height],
        "true_overlap_consecutive": {"median": float(np.median(ov)), "min": float(np.min(ov))},
        "total_s": dt,
        "timing_s": res.report["timing_s"],
        "map_px": [res.grid.width, res.grid.height],
        "mm_per_px": res.mm_per_px,
        "pairs": f"{res.report['pairs_accepted']}/{res.report['pairs_tried']}",
        "local_residual_px": res.report["alignment"]["local_residual_px"],
        "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
    }
    print(json.dumps(out, indent=1, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())

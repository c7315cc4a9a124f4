"""Stitching speed at full camera resolution: N keyframes at 3840x2160 (the paper stitched 35 such images in
about 38 min on a Xeon E5-2630 v4), the OpenCV renderer side by side with the per-pixel numpy renderer it
replaced, in one run on the same keyframes.

Every frame of the recording is a keyframe; the true overlap of consecutive frames is printed so the input can
be compared with the paper's (Rth = 80 %). Each renderer runs in its own process (its own peak memory). The
first run computes features and pairs; the reference run starts from a copy of that cache, so both align the
same pairs and their maps can be compared pixel by pixel (printed: the largest and mean difference where both
drew). The machine is shared: compare the ratio of the two render times, not absolute times across runs.

    python -c "from sim.camera.recording import generate_recording; generate_recording(
        'missions/demo-facade.yaml', '/tmp/rec4k', stride=20, width_px=3840, max_frames=35)"
    python bench/stitch_speed.py --recording /tmp/rec4k --out /tmp/stitch_speed
"""

from __future__ import annotations

import argparse
import json
import platform
import resource
import shutil
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np

from companion.stitch import StitchConfig, stitch
from companion.stitch.inputs import load_recording_input


def run_one(args) -> dict:
    from sim.camera.recording import load_recording

    rec = load_recording(args.recording)
    frames = list(range(len(rec)))
    ov = [rec.true_overlap(i, i + 1) for i in range(len(rec) - 1)]
    inp = load_recording_input(
        Path(args.recording), frames=frames, pose_noise_m=args.pose_noise_m, attitude_noise_deg=args.attitude_noise_deg
    )
    t0 = time.perf_counter()
    res = stitch(inp, args.out, StitchConfig(mm_per_px=args.mm_per_px, renderer=args.renderer), progress=False)
    dt = time.perf_counter() - t0
    return {
        "renderer": args.renderer,
        "machine": f"{platform.machine()} {platform.system()}, python {sys.version.split()[0]}, cv2 {cv2.__version__}",
        "keyframes": len(frames),
        "image_size": [rec.width, rec.height],
        "true_overlap_consecutive": {"median": float(np.median(ov)), "min": float(np.min(ov))},
        "total_s": round(dt, 1),
        "timing_s": res.report["timing_s"],
        "render": res.report["render"],
        "map_px": [res.grid.width, res.grid.height],
        "mm_per_px": res.mm_per_px,
        "pairs": f"{res.report['pairs_accepted']}/{res.report['pairs_tried']}",
        "local_residual_px": res.report["alignment"]["local_residual_px"],
        "coverage_fraction": res.coverage_fraction,
        "peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024),
    }


def _map_tiles(out: Path) -> dict[str, np.ndarray]:
    if (out / "map.png").exists():
        img = cv2.imread(str(out / "map.png"))
        cov = cv2.imread(str(out / "coverage.png"), cv2.IMREAD_GRAYSCALE)
        return {"map": np.dstack((img, cov))}
    return {p.name: cv2.imread(str(p), cv2.IMREAD_UNCHANGED) for p in sorted((out / "tiles").glob("*.png"))}


def compare_maps(a: Path, b: Path) -> dict:
    """Largest and mean grey-level difference where both maps drew, and pixels covered by only one."""
    ta, tb = _map_tiles(a), _map_tiles(b)
    worst, total, n, cov_diff = 0, 0.0, 0, 0
    for name, x in ta.items():
        y = tb[name]
        both = (x[..., 3] > 0) & (y[..., 3] > 0)
        cov_diff += int(np.count_nonzero((x[..., 3] > 0) != (y[..., 3] > 0)))
        d = np.abs(x[..., :3].astype(np.int16) - y[..., :3].astype(np.int16)).max(axis=2)[both]
        if d.size:
            worst, total, n = max(worst, int(d.max())), total + float(d.sum()), n + d.size
    return {"max_diff": worst, "mean_diff": round(total / max(n, 1), 5), "coverage_px_differing": cov_diff}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--recording", required=True)
    ap.add_argument("--out", default="/tmp/stitch_speed")
    ap.add_argument("--mm-per-px", type=float, default=None, help="map scale (default native)")
    ap.add_argument("--pose-noise-m", type=float, default=0.3)
    ap.add_argument("--attitude-noise-deg", type=float, default=0.5)
    ap.add_argument("--renderers", default="warp,pullback", help="run these, in this order (first: fresh cache)")
    ap.add_argument("--renderer", default=None, help=argparse.SUPPRESS)  # one run in this process
    args = ap.parse_args(argv)
    if args.renderer:
        print(json.dumps(run_one(args), default=float))
        return 0
    out = Path(args.out)
    shutil.rmtree(out, ignore_errors=True)
    runs = []
    for k, renderer in enumerate(args.renderers.split(",")):
        run_out = out / renderer
        if k > 0:  # the same features and pairs as the first run: the maps differ only by the renderer
            shutil.copytree(out / args.renderers.split(",")[0] / "cache", run_out / "cache")
        cmd = [sys.executable, __file__, "--recording", args.recording, "--out", str(run_out), "--renderer", renderer]
        cmd += ["--pose-noise-m", str(args.pose_noise_m), "--attitude-noise-deg", str(args.attitude_noise_deg)]
        if args.mm_per_px:
            cmd += ["--mm-per-px", str(args.mm_per_px)]
        r = json.loads(subprocess.run(cmd, check=True, capture_output=True, text=True).stdout.strip().splitlines()[-1])
        runs.append(r)
        print(json.dumps(r, indent=1, default=float))
    if len(runs) >= 2:
        names = args.renderers.split(",")
        diff = compare_maps(out / names[0], out / names[1])
        ratio = runs[1]["timing_s"]["render"] / max(runs[0]["timing_s"]["render"], 1e-9)
        print(
            f"render: {names[0]} {runs[0]['timing_s']['render']:.1f} s, {names[1]} {runs[1]['timing_s']['render']:.1f}"
            f" s ({ratio:.1f}x); keyframe decodes {runs[0]['render']['keyframe_decodes']} vs "
            f"{runs[1]['render']['keyframe_decodes']}; total {runs[0]['total_s']:.1f} s ({names[0]}, fresh cache); "
            f"maps: largest difference {diff['max_diff']} grey levels, mean {diff['mean_diff']}, "
            f"{diff['coverage_px_differing']} px covered by only one"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""The spools of a finished ``bench/stitch_eval.py --passes`` run stitched again by this checkout's code and scored
the same way, beside the run's own rows (issue 15): the maps depend only on the spool, so a stitcher change is
compared with the code that made the run on exactly the same keyframes, masks and telemetry. The features and
pairs come from the run's cache (only valid when this checkout's feature and matching code is the run's: say so
where the figures are recorded); the stages after matching run again.

    python bench/stitch_photo_restitch.py /tmp/sr/runA /tmp/sr/runB [PASS or PASS/VARIANT/MASK, comma list]

Reads RUN.log (the run's printed rows: ``stitch_eval.py ... --out RUN > RUN.log``), prints one JSON line per spool:
A (the run's row) and B (this code).
"""

from __future__ import annotations

import json
import shutil
import sys
import time
from dataclasses import replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from stitch_photo_passes import RenderedPass, grid_of_report, score_map, truth_grid_for, wall_truth  # noqa: E402

from companion.stitch import StitchConfig, stitch  # noqa: E402
from companion.stitch.inputs import load_input  # noqa: E402

SCORES = ("ssim", "coverage", "background_inliers", "connected", "shift_median_mm")


def scene(name: str, frames: int, width: int) -> RenderedPass:
    """The pass's renderer (no gate: the keyframes are the spool's), as stitch_eval rendered it."""
    from checkout import use_checkout_shared_data

    from sim.camera.model import CameraModel
    from sim.camera.photo_passes import RECIPES, build_pass
    from sim.camera.photo_scene import PhotoPassRenderer

    spec = build_pass(RECIPES[name], root=use_checkout_shared_data(),
                      frames=frames, background_frames=max(2, round(frames * 22 / 250)))
    cam = spec.camera
    spec = replace(spec, camera=CameraModel(width, round(cam.height * width / cam.width), cam.hfov_deg))
    return RenderedPass(name, spec, PhotoPassRenderer(spec), [], [], [], [])


def restitch(rp: RenderedPass, spool: Path, old: Path, dest: Path, *, image_only: bool) -> dict:
    lines = (spool / "manifest.jsonl").read_text().splitlines()
    frames = [json.loads(line)["index"] for line in lines if line.strip()]  # the pass's frames (write_spool)
    for sub in ("features", "pairs"):
        if (old / "cache" / sub).is_dir() and not (dest / "cache" / sub).exists():
            shutil.copytree(old / "cache" / sub, dest / "cache" / sub)
    t0 = time.process_time()
    res = stitch(load_input(spool), dest, StitchConfig(use_poses=not image_only), progress=False)
    grid = truth_grid_for(rp, rp.spec.standoff_m / rp.spec.camera.K[0, 0]) if image_only else grid_of_report(res.report)
    score = score_map(res.map_image, res.coverage, wall_truth(rp, frames, grid), rectified=not image_only)
    return {**score, "connected": len(res.report["keyframes_used"]), "cpu_s": round(time.process_time() - t0, 1)}


def main(argv: list[str]) -> int:
    run, out = Path(argv[0]), Path(argv[1])
    only = set(argv[2].split(",")) if len(argv) > 2 else None
    rows = [json.loads(line) for line in run.with_suffix(".log").read_text().splitlines()
            if line.startswith("{")]
    rps: dict[str, RenderedPass] = {}
    for a in (r for r in rows if r.get("method") == "ours"):
        name, variant, mask = a["pass"], a["variant"], a["mask"]
        if only and name not in only and f"{name}/{variant}/{mask}" not in only:
            continue
        rp = rps.setdefault(name, scene(name, 80, 640))
        b = restitch(rp, run / name / f"spool-{variant}-{mask}", run / name / f"ours-{variant}-{mask}",
                     out / name / f"ours-{variant}-{mask}", image_only=variant == "image-only")
        print(json.dumps({"pass": name, "variant": variant, "mask": mask, "frames": a["frames"],
                          "A": {k: a.get(k) for k in SCORES}, "B": {k: b.get(k) for k in SCORES},
                          "B_cpu_s": b["cpu_s"]}, default=float), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

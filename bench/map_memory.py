"""Peak memory of one Dask worker making one face's map at growing map sizes, up to a gigapixel (issue 28, SCALE.md).

The face is tests/site_spools.py's face 0 (a 12-keyframe main flight and its re-fly at ``--size``), stitched at each
``--mm-per-px`` in turn: the finer the scale, the larger the map (the keyframes are drawn magnified), while the
work before the render stays the same, so what grows is the render, the map's files, the viewer's tile pyramid
and the COG. Each size runs as `companion site` runs it: a fresh embedded LocalCluster of one worker process (one
thread, OpenCV limited to it), the keyframe feature tasks then the face's task (stitch, viewer, COG), into a fresh
folder. Printed per size: the map's pixels, the worker's peak RSS (``ru_maxrss`` of the worker process: the whole
job on that worker; with ``--workers 2`` each worker's), the job's wall time and the face's stage times, the tiles
and bytes written.

    PYTHONPATH=. python bench/map_memory.py --out /tmp/map_memory --mm-per-px 0.3 0.085 --max-map-px 2e9
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import shutil
import sys
import time
from dataclasses import replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from companion.site.engine import EngineSpec, open_engine  # noqa: E402
from companion.site.facade import FacadeTask  # noqa: E402
from companion.site.spools import plan_site  # noqa: E402
from companion.stitch.config import StitchConfig  # noqa: E402
from tests.site_spools import SiteShape, make_face  # noqa: E402


def _peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # Linux: KiB


def _size_mb(path: Path) -> float:
    return sum(p.stat().st_size for p in Path(path).rglob("*") if p.is_file()) / 1e6


def run_face(spools: list[Path], out: Path, cfg: StitchConfig, cog: bool, workers: int = 1) -> dict:
    shutil.rmtree(out, ignore_errors=True)
    plan = plan_site(spools)
    tasks = [FacadeTask(job, out / job.name, cfg, cog=cog) for job in plan.facades]
    engine = open_engine(EngineSpec(workers=workers))
    try:
        t = time.perf_counter()
        outcomes = list(engine.run(tasks))
        wall = time.perf_counter() - t
        peaks = engine.client.run(_peak_rss_mb)
        cpu = engine.client.run(time.process_time)
    finally:
        engine.close()
    (o,) = outcomes
    if o.status != "done":
        raise SystemExit(f"the face failed: {o.problem} (fix: {o.fix})")
    report = json.loads((o.out_dir / "report.json").read_text())
    w, h = o.size_px
    tiles = o.out_dir / "tiles"
    return {
        "mm_per_px": o.mm_per_px,
        "map_px": [w, h],
        "megapixels": round(w * h / 1e6, 1),
        "worker_peak_rss_mb": round(max(peaks.values())),
        "each_worker_peak_rss_mb": sorted(round(v) for v in peaks.values()),
        "each_worker_cpu_s": sorted(round(v, 1) for v in cpu.values()),
        "render_tasks": report["render"].get("render_tasks"),
        "job_wall_s": round(wall, 1),
        "worker_cpu_s": round(sum(cpu.values()), 1),
        "face_task_s": o.seconds,
        "stages_s": report["timing_s"],
        "stitch_tiles": len(list(tiles.glob("tile_*.png"))) if tiles.is_dir() else 0,
        "in_memory": "map" in o.files,
        "cog_mb": round((o.out_dir / "map_cog.tif").stat().st_size / 1e6, 1) if "cog" in o.files else None,
        "written_mb": round(_size_mb(o.out_dir), 1),
        "coverage": o.coverage_fraction,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, default=Path("/tmp/map_memory"))
    ap.add_argument("--size", default="640x480", help="keyframe size WxH (4:3)")
    ap.add_argument("--mm-per-px", type=float, nargs="+", default=[0.3, 0.085], help="map scales, one run each")
    ap.add_argument("--max-map-px", type=float, default=2e9, help="StitchConfig.max_map_px for the runs")
    ap.add_argument("--no-cog", action="store_true", help="leave the COG out")
    ap.add_argument("--workers", type=int, default=1, help="worker processes of the embedded cluster (one thread each)")
    ap.add_argument("--keep", action="store_true", help="keep each size's map folder (default: removed after)")
    args = ap.parse_args()
    w, h = (int(v) for v in args.size.split("x"))
    shutil.rmtree(args.out, ignore_errors=True)
    spools = list(make_face(args.out / "spools", 0, SiteShape(width=w, height=h)))
    print(f"{platform.node()}: {len(os.sched_getaffinity(0))} cores, "
          f"{os.sysconf('SC_PAGE_SIZE') * os.sysconf('SC_PHYS_PAGES') / 2**30:.0f} GiB, load {os.getloadavg()}; "
          f"face 0 of tests/site_spools.py at {w}x{h}: {len(spools)} spools")
    base = StitchConfig(max_map_px=args.max_map_px)
    for mm in args.mm_per_px:
        load = os.getloadavg()[0]
        r = run_face(spools, args.out / f"mm{mm:g}", replace(base, mm_per_px=mm), cog=not args.no_cog,
                     workers=args.workers)
        print(f"{mm:g} mm/px (load at start {load:.2f}): {json.dumps(r)}", flush=True)
        if not args.keep:
            shutil.rmtree(args.out / f"mm{mm:g}", ignore_errors=True)
    print(f"load at the end {os.getloadavg()}")


if __name__ == "__main__":
    main()

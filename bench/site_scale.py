"""A site on one Dask worker against two, side by side in one run on the same spools (issue 28, docs/SCALE.md).

The site is tests/site_spools.py's building: ``--faces`` faces, each a main flight that misses a corner and a
re-fly of it (12 keyframes a face at ``--size``). Each round runs the site on an embedded LocalCluster of one
worker, then of two (one thread each, OpenCV limited to it), each into a fresh folder (no cache), alternating
so that a load change on a shared machine hits both. Printed per run: the cluster's start, the job's wall time,
every face's task time, the stitcher's stage times per keyframe (from each face's report.json), each worker's
peak memory, and the data a task moves (the pickled task and result through the scheduler; the spools read and
the map folder written on the shared path), the tasks by kind (features, facade, match_batch, render_batch: count,
mean compute time, pairs per pair task) and, once, what a pair task moves (its pickled size, the feature files it
reads). Then the speed-up, two workers against one, per round.

    PYTHONPATH=. python bench/site_scale.py --out /tmp/site_scale --faces 4 --size 640x480 --rounds 2
"""

from __future__ import annotations

import argparse
import json
import os
import pickle
import platform
import resource
import shutil
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from companion.site.engine import EngineSpec, open_engine  # noqa: E402
from companion.site.facade import FacadeTask  # noqa: E402
from companion.site.spools import plan_site  # noqa: E402
from companion.stitch.config import StitchConfig  # noqa: E402
from companion.stitch.merge import merge_spools  # noqa: E402
from companion.stitch.pairs import PairBatch, match_batch  # noqa: E402
from companion.stitch.worker import stitch  # noqa: E402
from tests.site_spools import SiteShape, make_site  # noqa: E402


def _size_mb(path: Path) -> float:
    return sum(p.stat().st_size for p in Path(path).rglob("*") if p.is_file()) / 1e6


def _peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # Linux: KiB


def _noop(i: int) -> int:
    return i


def task_overhead_ms(n: int = 200) -> float:
    """Milliseconds per task of Dask itself: ``n`` empty tasks on a 2-worker embedded cluster, submitted at once."""
    engine = open_engine(EngineSpec(workers=2))
    try:
        engine.client.gather(engine.client.map(_noop, range(10)))  # warm up
        t = time.perf_counter()
        engine.client.gather(engine.client.map(_noop, range(n), pure=False))
        return 1000 * (time.perf_counter() - t) / n
    finally:
        engine.close()


class _Recording:
    """A pair runner in this process that records each pair task's pickled size and the feature files it reads."""

    def __init__(self, slots: int):
        self.slots, self.batches = slots, []

    def start(self, fn, items):
        for batch in items:
            self.batches.append(batch)
            fn(batch)
        return lambda: None


def pair_task_sizes(main: Path, refly: Path, out: Path, slots: int = 2) -> dict:
    """One face stitched in this process with its pairs as tasks (as a face task on ``slots`` worker threads cuts
    them): per pair task, the pairs, the pickled task and the feature files it reads."""
    shutil.rmtree(out, ignore_errors=True)
    rec = _Recording(slots)
    stitch(merge_spools([main, refly])[0], out, StitchConfig(workers=1), progress=False, pair_tasks=rec)
    feature_files = {p.name.split("-")[0]: p.stat().st_size for p in (out / "cache" / "features").glob("*.npz")}

    def reads(b: PairBatch) -> int:
        return sum(feature_files.get(f"kf{kf.index:06d}", 0) for kf in b.keyframes.values())

    pairs = [sum(len(g) for _, g in b.groups) for b in rec.batches]
    sizes = [len(pickle.dumps((match_batch, b))) for b in rec.batches]
    return {"tasks": len(rec.batches), "pairs": sum(pairs), "pairs_per_task": pairs,
            "task_kb": round(sum(sizes) / len(sizes) / 1e3, 2), "task_kb_max": round(max(sizes) / 1e3, 2),
            "reads_kb": round(sum(map(reads, rec.batches)) / len(rec.batches) / 1e3, 1),
            "pair_file_kb": round(sum(p.stat().st_size for p in (out / "cache" / "pairs").glob("*.npz"))
                                  / max(1, sum(pairs)) / 1e3, 2)}


def _kinds(stream: list[dict]) -> dict:
    """Tasks by kind (their key's prefix): how many and their mean compute time on the workers."""
    kinds: dict[str, list[float]] = {}
    for t in stream:
        name = str(t["key"]).split("-")[0]
        compute = sum(s["stop"] - s["start"] for s in t.get("startstops", ()) if s.get("action") == "compute")
        kinds.setdefault(name, []).append(compute)
    return {k: (len(v), round(1000 * sum(v) / len(v), 1)) for k, v in sorted(kinds.items())}


def run_site(spools: list[Path], out: Path, workers: int) -> dict:
    """One run of the site on ``workers`` worker processes; every figure the comparison prints."""
    shutil.rmtree(out, ignore_errors=True)
    plan = plan_site(spools)
    tasks = [FacadeTask(job, out / job.name, StitchConfig()) for job in plan.facades]
    t0 = time.perf_counter()
    engine = open_engine(EngineSpec(workers=workers))
    from dask.distributed import get_task_stream

    t1 = time.perf_counter()
    with get_task_stream(client=engine.client) as stream:
        outcomes = list(engine.run(tasks))
    t2 = time.perf_counter()
    peaks = engine.client.run(_peak_rss_mb)
    cpu = engine.client.run(time.process_time)  # fresh worker processes: all the CPU each used for the job
    engine.close()
    stages: dict[str, float] = {}
    keyframes = 0
    for o in outcomes:
        report = json.loads((o.out_dir / "report.json").read_text())
        keyframes += len(report["keyframes_used"])
        for stage, s in report["timing_s"].items():
            stages[stage] = stages.get(stage, 0.0) + s
    return {
        "workers": workers,
        "start_s": t1 - t0,
        "run_s": t2 - t1,
        "task_s": sorted(round(o.seconds, 2) for o in outcomes),
        "task_cpu_s": sorted(round(o.cpu_seconds, 2) for o in outcomes),
        "failed": [o.name for o in outcomes if o.status != "done"],
        "keyframes": keyframes,
        "stage_ms_per_keyframe": {k: round(1000 * v / keyframes, 1) for k, v in stages.items()},
        "worker_peak_rss_mb": sorted(round(v) for v in peaks.values()),
        "worker_cpu_s": round(sum(cpu.values()), 1),
        "worker_cpu_split": sorted(round(v, 1) for v in cpu.values()),
        "tasks": _kinds(stream.data),
        "task_pickle_kb": round(max(len(pickle.dumps(t)) for t in tasks) / 1e3, 2),
        "result_pickle_kb": round(max(len(pickle.dumps(o)) for o in outcomes) / 1e3, 2),
        "spools_read_mb_per_face": round(sum(_size_mb(s) for s in spools) / len(tasks), 2),
        "written_mb_per_face": round(_size_mb(out) / len(tasks), 2),
    }


def _print(r: dict) -> None:
    per_face = sum(r["task_s"]) / len(r["task_s"])
    print(f"  {r['workers']} worker(s): cluster start {r['start_s']:.1f} s, job {r['run_s']:.1f} s, "
          f"task s {r['task_s']} (mean {per_face:.2f} s/face, {sum(r['task_s']) / r['keyframes']:.3f} s/keyframe), "
          f"failed {r['failed'] or 'none'}")
    print(f"    CPU s: face tasks {r['task_cpu_s']}; all workers' processes {r['worker_cpu_s']} "
          f"(per worker {r['worker_cpu_split']}) "
          f"({r['worker_cpu_s'] / r['keyframes']:.3f} CPU s/keyframe, keyframe feature tasks and Dask included)")
    print(f"    stages ms/keyframe {r['stage_ms_per_keyframe']}; worker peak RSS MB {r['worker_peak_rss_mb']}")
    print("    tasks (count, mean compute ms): " + ", ".join(f"{k} {n} x {ms} ms" for k, (n, ms) in r["tasks"].items()))
    print(f"    moved per task: task {r['task_pickle_kb']} kB + result {r['result_pickle_kb']} kB through the "
          f"scheduler; spools read {r['spools_read_mb_per_face']} MB, map folder written "
          f"{r['written_mb_per_face']} MB on the shared path")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, default=Path("/tmp/site_scale"))
    ap.add_argument("--faces", type=int, default=4)
    ap.add_argument("--size", default="640x480", help="keyframe size WxH (4:3)")
    ap.add_argument("--rounds", type=int, default=2)
    args = ap.parse_args()
    w, h = (int(v) for v in args.size.split("x"))
    shutil.rmtree(args.out, ignore_errors=True)
    spools = make_site(args.out / "spools", faces=args.faces, shape=SiteShape(width=w, height=h))
    print(f"{platform.node()}: {len(os.sched_getaffinity(0))} cores, load {os.getloadavg()}; "
          f"{args.faces} faces x 12 keyframes at {w}x{h}, {len(spools)} spools")
    print(f"Dask's own cost per task (empty tasks, 2 workers): {task_overhead_ms():.2f} ms")
    sizes = pair_task_sizes(spools[0], spools[args.faces], args.out / "pair_tasks")
    print(f"pair tasks of face 0 as a face task on 2 worker threads cuts them: {sizes['tasks']} tasks, "
          f"{sizes['pairs']} pairs ({sizes['pairs_per_task']} a task); each task {sizes['task_kb']} kB pickled "
          f"(max {sizes['task_kb_max']} kB) and {sizes['reads_kb']} kB of feature files read, result a count; "
          f"{sizes['pair_file_kb']} kB a pair written to the pair cache")
    for k in range(args.rounds):
        print(f"round {k + 1} (load {os.getloadavg()[0]:.2f}):")
        one = run_site(spools, args.out / "one", 1)
        _print(one)
        two = run_site(spools, args.out / "two", 2)
        _print(two)
        print(f"  speed-up, two workers against one: job {one['run_s'] / two['run_s']:.2f}x, with the cluster's "
              f"start {(one['start_s'] + one['run_s']) / (two['start_s'] + two['run_s']):.2f}x; on free cores "
              f"(CPU of the busier worker against one worker's): "
              f"{one['worker_cpu_s'] / max(two['worker_cpu_split']):.2f}x")
    print(f"load at the end {os.getloadavg()}")


if __name__ == "__main__":
    main()

"""One face's map as one task: the stitcher on the face's spools, then a completion marker, written last.

Why a marker and not report.json alone: a site rerun with the same ``--out`` must tell a face that is done *for
these spools and settings* from one made before a re-fly was added or the scale changed. The marker holds a key of
the inputs (each spool's manifest and spool.json as they are now, the settings) and the face's summary; the site
skips a face whose marker has today's key and stitches every other one (the stitcher's content-keyed caches make
that cheap). This module imports no Dask: the same function runs in this process or on any worker.
"""

from __future__ import annotations

import hashlib
import json
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

from companion.errors import CompanionError
from companion.files import write_atomic
from companion.site.cog import write_cog
from companion.site.spools import FacadeJob
from companion.spool.layout import MANIFEST, META
from companion.stitch.canvas import TileRunner
from companion.stitch.config import StitchConfig
from companion.stitch.merge import merge_spools
from companion.stitch.pairs import PairRunner
from companion.stitch.worker import stitch

MARKER = "site_done.json"  # in the face's folder; written after everything else of the face


@dataclass(frozen=True)
class FacadeTask:
    """What a worker needs to make one face's map: the face, its output folder (on a path the worker reads and
    writes), the settings, and how many threads it may use (0: all the machine's cores)."""

    job: FacadeJob
    out_dir: Path
    config: StitchConfig
    threads: int = 0
    cog: bool = True  # also write the map as a Cloud Optimized GeoTIFF (cog.py)


@dataclass(frozen=True)
class FacadeOutcome:
    """A face's result as the site index shows it: ``status`` is "done" (made now), "skipped" (done before with
    the same inputs) or "failed" (``problem`` and ``fix`` say why)."""

    name: str
    out_dir: Path
    spools: tuple[str, ...]
    status: str
    coverage_fraction: float | None = None
    mm_per_px: float | None = None
    size_px: tuple[int, int] | None = None
    keyframes: int = 0
    uncovered_areas_m: tuple[dict, ...] = ()
    seconds: float = 0.0
    cpu_seconds: float = 0.0  # the worker process's CPU time for the task (all its threads): load-independent cost
    problem: str | None = None
    fix: str | None = None
    files: dict[str, str] = field(default_factory=dict)

    def as_dict(self) -> dict:
        d = asdict(self)
        d["out_dir"] = str(self.out_dir)
        d["uncovered_areas_m"] = list(self.uncovered_areas_m)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> FacadeOutcome:
        d = dict(d)
        d["out_dir"] = Path(d["out_dir"])
        d["spools"] = tuple(d["spools"])
        d["uncovered_areas_m"] = tuple(d.get("uncovered_areas_m", ()))
        d["size_px"] = tuple(d["size_px"]) if d.get("size_px") else None
        return cls(**d)


def inputs_key(task: FacadeTask) -> str:
    """A key of everything the face's map depends on: each spool's manifest (size, time) and spool.json, the
    settings, whether a COG is asked for. The thread count is not in it: it does not change the map."""
    parts = [json.dumps(asdict(task.config), sort_keys=True, default=str), f"cog={task.cog}"]
    for spool in task.job.spools:
        parts.append(str(Path(spool).resolve()))
        for name in (MANIFEST, META):
            path = Path(spool) / name
            if path.is_file():
                st = path.stat()
                parts.append(f"{name}:{st.st_size}:{st.st_mtime_ns}")
    return hashlib.sha1("|".join(parts).encode()).hexdigest()[:20]


def done_before(task: FacadeTask) -> FacadeOutcome | None:
    """The face's outcome from its marker when it was made with these inputs (then it is skipped), else None."""
    path = task.out_dir / MARKER
    try:
        marker = json.loads(path.read_text())
        if marker.get("inputs_key") != inputs_key(task):
            return None
        return replace(FacadeOutcome.from_dict(marker["outcome"]), status="skipped", seconds=0.0, cpu_seconds=0.0)
    except (OSError, ValueError, KeyError, TypeError):
        return None  # no marker, or a torn / older one: make the face again


def build_facade(task: FacadeTask, tiles: TileRunner | None = None, pair_tasks: PairRunner | None = None
                  ) -> FacadeOutcome:
    """Make one face's map in ``task.out_dir`` (as `companion stitch` of its spools would) and write its marker
    last. A user-facing problem (a damaged spool, another camera) is returned as a failed outcome, not raised, so
    the site's other faces go on and a cluster does not retry what cannot succeed. ``tiles``: where a map kept as
    tiles is drawn (the cluster's render tasks; None: this process); ``pair_tasks``: where the pairs are matched
    (the cluster's pair tasks; None: this process)."""
    start, cpu = time.perf_counter(), time.process_time()
    spools = tuple(str(s) for s in task.job.spools)
    base = FacadeOutcome(task.job.name, task.out_dir, spools, "failed")
    (task.out_dir / MARKER).unlink(missing_ok=True)  # the folder is in flux until the new marker is written
    _limit_threads(task.threads)
    cfg = replace(task.config, workers=task.threads) if task.threads else task.config
    try:
        inp, _ = merge_spools(list(task.job.spools))
        res = stitch(inp, task.out_dir, cfg, progress=False, tiles=tiles, pair_tasks=pair_tasks)
        res = replace(res, map_image=None, coverage=None)  # an in-memory map's pixels: written, not held for the COG
        files = dict(res.files)
        if task.cog and (cog := write_cog(task.out_dir, files, task.threads)) is not None:
            files["cog"] = str(cog)
    except CompanionError as exc:
        return replace(base, problem=exc.problem, fix=exc.fix, seconds=time.perf_counter() - start)
    outcome = replace(
        base,
        status="done",
        coverage_fraction=float(res.coverage_fraction),
        mm_per_px=None if res.mm_per_px is None else float(res.mm_per_px),
        size_px=(int(res.grid.width), int(res.grid.height)),
        keyframes=len(res.report.get("keyframes_used", [])),
        uncovered_areas_m=tuple(res.report.get("uncovered_areas_m", [])),
        seconds=round(time.perf_counter() - start, 3),
        cpu_seconds=round(time.process_time() - cpu, 3),
        files={k: str(Path(v).relative_to(task.out_dir)) for k, v in files.items() if _inside(v, task.out_dir)},
    )
    marker = {"inputs_key": inputs_key(task), "outcome": outcome.as_dict()}
    write_atomic(task.out_dir / MARKER, json.dumps(marker, indent=1), durable=True)
    return outcome


def _inside(path: str, folder: Path) -> bool:
    try:
        Path(path).relative_to(folder)
        return True
    except ValueError:
        return False


def _limit_threads(threads: int) -> None:
    """On a worker given ``threads`` cores, OpenCV's own thread pool uses that many too (by default it takes every
    core of the machine, so two workers on two cores would fight over them)."""
    if threads > 0:
        import cv2

        cv2.setNumThreads(threads)

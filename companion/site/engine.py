"""Where a site's face tasks run: in this process, on an embedded Dask cluster, or on an existing one.

Why Dask (``dask.distributed``): it is the engine an inspection firm may already run (`dask scheduler` and
`dask worker` on its machines, or Kubernetes/SLURM deployments of them), it reruns the tasks of a worker that dies,
and it needs nothing on this side but a client. The default is a ``LocalCluster`` of worker processes sized to
this machine (one per core, one thread each): no server to start. ``scheduler`` sends the same tasks to an
existing cluster; ``workers=0`` keeps everything in this process (the companion computer, small jobs). The task
is the same function everywhere (``facade.build_facade``), so the maps are the same.

Dask is imported only when a cluster is used: single-process mode works without it.
"""

from __future__ import annotations

import importlib.util
import logging
import os
from collections.abc import Callable, Iterator
from dataclasses import dataclass, replace
from pathlib import Path

from companion.errors import CompanionError
from companion.site.facade import FacadeOutcome, FacadeTask, build_facade
from companion.site.keyframe_tasks import extract_features, keyframe_tasks

log = logging.getLogger(__name__)

WORKER_WAIT_S = 60.0  # how long an existing cluster may take to show its first worker


@dataclass(frozen=True)
class EngineSpec:
    """``workers``: processes of the embedded cluster (None: one per core; 0: no cluster, this process);
    ``scheduler``: an existing cluster's address (tcp://HOST:8786) or scheduler file, instead of an embedded one."""

    workers: int | None = None
    scheduler: str | None = None

    @property
    def single_process(self) -> bool:
        return self.scheduler is None and self.workers == 0


class SingleProcess:
    """The tasks one after another in this process."""

    description = "this process"
    dashboard: str | None = None
    threads = 0  # the stitcher's own default: every core

    def run(self, tasks: list[FacadeTask], on_task: Callable[[int], None] | None = None) -> Iterator[FacadeOutcome]:
        for task in tasks:
            outcome = build_facade(task)
            if on_task:
                on_task(len(tasks))
            yield outcome

    def close(self) -> None:
        pass


class DaskEngine:
    """The tasks on a Dask cluster, results in the order they finish."""

    def __init__(self, client, cluster=None, *, split_features: bool = True):
        self.client, self.cluster = client, cluster
        self.split_features = split_features  # each keyframe's features a task of its own, before its face
        workers = client.scheduler_info().get("workers", {})
        self.threads = min((w.get("nthreads", 1) for w in workers.values()), default=1)
        kind = "embedded local cluster" if cluster is not None else f"cluster at {client.scheduler.address}"
        self.description = f"{kind}, {len(workers)} worker(s) x {self.threads} thread(s)"
        self.dashboard = _dashboard(client)

    def run(self, tasks: list[FacadeTask], on_task: Callable[[int], None] | None = None) -> Iterator[FacadeOutcome]:
        """Faces' outcomes as they finish; ``on_task(total)`` after every task (keyframe or face) is done."""
        from dask.distributed import as_completed

        futures, by_key = [], {}
        for task in tasks:
            task = replace(task, threads=self.threads)
            # a key of its own per run: a rerun of the site is new work, not a result the scheduler remembers
            run = os.urandom(4).hex()
            features = [
                self.client.submit(extract_features, kt, key=f"features-{task.job.name}-{kt.keyframe.index}-{run}",
                                   pure=False)
                for kt in keyframe_tasks(task)
            ] if self.split_features else []
            fut = self.client.submit(_after, task, *features, key=f"facade-{task.job.name}-{run}", pure=False)
            futures += [*features, fut]
            by_key[fut.key] = task
        for fut in as_completed(futures):
            if on_task:
                on_task(len(futures))
            if fut.key in by_key:
                yield _result(fut, by_key[fut.key])

    def close(self) -> None:
        """Ends the client (and the embedded cluster). Its shutdown races (a worker's last heartbeat to a closed
        scheduler) are logged by Dask as errors with tracebacks although nothing is wrong: not shown."""
        quiet = logging.getLogger("distributed")
        level = quiet.level
        quiet.setLevel(logging.CRITICAL)
        try:
            self.client.close()
            if self.cluster is not None:
                self.cluster.close()
        finally:
            quiet.setLevel(level)


def _after(task: FacadeTask, *_features: str | None) -> FacadeOutcome:
    """The face's task, run once its keyframes' feature tasks are done (their results are not needed: they
    filled the face's feature cache); its pairs are matched by pair tasks and a map kept as tiles is drawn by
    render tasks, of their own."""
    runner = ClusterTasks()
    return build_facade(task, tiles=runner, pair_tasks=runner)


class ClusterTasks:
    """The pair and render tasks of a face task, on the cluster it runs on, both writing to the shared output path.

    ``start``: ``pairs.match_batch`` per run of keyframes, writing each pair to the face's pair cache; the face task
    does not wait on them (it matches the same pairs from the other end and cancels what is left), so it keeps its
    thread: a worker whose thread is free takes part of the matching, and no other face starts in its place.
    ``map``: ``canvas.render_batch`` per run of tiles, writing its tiles; the face task secedes from its worker's
    thread while they run (``worker_client``), so a worker of one thread draws tiles too, and waits for them
    holding no thread."""

    def __init__(self):
        from dask.distributed import get_client

        self.slots = max(1, sum(get_client().nthreads().values()))

    def start(self, fn, items: list):
        from dask.distributed import get_client

        client = get_client()
        # before any face or keyframe task still queued, as the render tasks; submitted without seceding: the face
        # task goes on matching on its own thread and never blocks on these
        futures = client.map(fn, items, pure=False, priority=10)

        def cancel() -> None:
            client.cancel(futures)

        return cancel

    def map(self, fn, items: list):
        from dask.distributed import as_completed, worker_client

        with worker_client() as client:
            # before any face or keyframe task still queued: a worker's freed thread matches / draws for this face
            # rather than start another face (whose state would then be held beside this one's)
            futures = client.map(fn, items, pure=False, priority=10)
            for fut in as_completed(futures):
                yield fut.result()
                fut.release()


def _result(fut, task: FacadeTask) -> FacadeOutcome:
    """The task's outcome; a task the cluster could not run (an exception outside the stitcher's own errors, a
    task whose workers kept dying) is a failed face, named, not the end of the job."""
    try:
        return fut.result()
    except Exception as exc:  # noqa: BLE001 - any failure of one face must leave the others going
        fix = ("install companion (this version) on every worker, with the spools and --out on a path they all "
               "read" if isinstance(exc, ModuleNotFoundError | FileNotFoundError)
               else "see the worker's log; rerun the site with the same --out to retry the faces not done")
        return FacadeOutcome(task.job.name, task.out_dir, tuple(str(s) for s in task.job.spools), "failed",
                             problem=f"the task failed on the cluster: {type(exc).__name__}: {exc}", fix=fix)


def _dashboard(client) -> str | None:
    """The dashboard's address, when the scheduler serves one (it needs bokeh installed where it runs)."""
    port = client.scheduler_info().get("services", {}).get("dashboard")
    if not port:
        return None
    host = client.scheduler.address.split("://")[-1].rsplit(":", 1)[0]
    return f"http://{host}:{port}/status"


def default_workers() -> int:
    """One worker process per core this process may use."""
    return max(1, len(os.sched_getaffinity(0)))


def open_engine(spec: EngineSpec) -> SingleProcess | DaskEngine:
    """The engine ``spec`` asks for, started (close it when done)."""
    if spec.single_process:
        return SingleProcess()
    try:
        from dask.distributed import Client, LocalCluster
    except ImportError as exc:
        raise CompanionError(f"Dask is not installed ({exc})",
                             "pip install 'dask[distributed]', or run in this process with --single-process") from None
    if logging.getLogger().level > logging.DEBUG:  # (not with -v) Dask's INFO lines, every worker's start and
        logging.getLogger("distributed").setLevel(logging.ERROR)  # stop, its shutdown chatter, bury the job's own
    if spec.scheduler is None:
        cluster = LocalCluster(n_workers=spec.workers or default_workers(), threads_per_worker=1, processes=True,
                               dashboard_address=":0", silence_logs=logging.CRITICAL)
        engine = DaskEngine(Client(cluster), cluster)
        if importlib.util.find_spec("bokeh") is None:  # the address answers, but only "install bokeh"
            log.info("no Dask dashboard: it needs bokeh (pip install 'bokeh>=3.1')")
            engine.dashboard = None
        return engine
    return DaskEngine(_connect(Client, spec.scheduler))


def _connect(client_type, scheduler: str):
    fix = ("start the scheduler (`dask scheduler`) and workers (`dask worker ADDRESS`), give its address "
           "(tcp://HOST:8786) or its scheduler file (--scheduler-file); or leave --scheduler out for a local cluster")
    try:
        if Path(scheduler).is_file():
            client = client_type(scheduler_file=scheduler, timeout="20s")
        else:
            client = client_type(scheduler, timeout="20s")
    except (OSError, TimeoutError, ValueError) as exc:
        raise CompanionError(f"cannot reach the Dask scheduler at {scheduler} ({exc})", fix) from None
    try:
        client.wait_for_workers(1, timeout=WORKER_WAIT_S)
    except TimeoutError:
        client.close()
        raise CompanionError(f"the Dask scheduler at {scheduler} has no worker after {WORKER_WAIT_S:.0f} s",
                             "start workers: `dask worker ADDRESS` on machines that see the spools' path") from None
    return client

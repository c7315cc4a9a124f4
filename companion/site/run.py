"""A site job from start to end: group the spools, skip the faces already done, run the others, write the index.

Why faults are handled here and not left to the first exception: on a site of forty faces one damaged spool or
one face that cannot be stitched must not cost the other thirty-nine. Bad spools and failed faces are collected,
written into site.json/index.html beside the faces that worked, and returned; the command then exits non-zero
naming each of them with its fix.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

from companion.errors import CompanionError
from companion.site.engine import EngineSpec, open_engine
from companion.site.facade import FacadeOutcome, FacadeTask, done_before
from companion.site.index import site_record, write_index
from companion.site.progress import SiteProgress
from companion.site.spools import BadSpool, plan_site
from companion.stitch.config import StitchConfig

log = logging.getLogger("companion.site")


@dataclass(frozen=True)
class SiteResult:
    out_dir: Path
    facades: tuple[FacadeOutcome, ...]  # in the order of the site's faces
    bad_spools: tuple[BadSpool, ...]
    engine: str
    dashboard: str | None
    files: dict[str, str]

    @property
    def failed(self) -> tuple[FacadeOutcome, ...]:
        return tuple(o for o in self.facades if o.status == "failed")


def build_site(spools: list[str | Path], out_dir: str | Path, config: StitchConfig | None = None,
               engine: EngineSpec | None = None, *, progress: bool = True, cog: bool = True) -> SiteResult:
    """Every face's map in ``out_dir/<face>/`` and the site's index; faces done before with the same inputs are
    skipped. Raises only when nothing can be done at all (no readable spool, no engine)."""
    out = Path(out_dir)
    plan = plan_site(spools)
    for bad in plan.bad_spools:
        log.warning("spool %s left out: %s (fix: %s)", bad.path, bad.problem, bad.fix)
    if not plan.facades:
        reasons = "; ".join(f"{b.path}: {b.problem}" for b in plan.bad_spools) or "no spool given"
        raise CompanionError(f"no spool of the site can be stitched ({reasons})",
                             "give keyframe spool directories (each has manifest.jsonl and spool.json)")
    tasks = [FacadeTask(job, out / job.name, config or StitchConfig(), cog=cog) for job in plan.facades]
    done = {t.job.name: o for t in tasks if (o := done_before(t)) is not None}
    todo = [t for t in tasks if t.job.name not in done]
    runner = open_engine(engine or EngineSpec()) if todo else None  # before the bar: a refusal is said plainly
    description = runner.description if runner else "nothing to run: every facade was done"
    dashboard = runner.dashboard if runner else None
    out.mkdir(parents=True, exist_ok=True)
    bar = SiteProgress(len(tasks), show=progress)
    outcomes = dict(done)
    try:
        for outcome in done.values():
            bar.finished(outcome)
        if runner:
            log.info("running %d facade task(s) on %s%s", len(todo), description,
                     f"; dashboard: {dashboard}" if dashboard else "")
            for outcome in runner.run(todo, on_task=bar.task_done):
                outcomes[outcome.name] = outcome
                bar.finished(outcome)
    finally:
        bar.close()
        if runner:
            runner.close()
    ordered = tuple(outcomes[t.job.name] for t in tasks)
    files = write_index(out, site_record(list(ordered), plan.bad_spools, out, description))
    return SiteResult(out, ordered, plan.bad_spools, description, dashboard, files)

"""The whole job's progress: faces done of the total, with an ETA, on the terminal and as lines in a log.

Why both: a person at a terminal watches the bar; a job on a server is read afterwards from its log, where a
redrawn bar is useless and one line per finished face (with the ETA at that moment) is what tells how it went.
"""

from __future__ import annotations

import logging
import time

from companion.progress import progress_bar
from companion.site.facade import FacadeOutcome

log = logging.getLogger("companion.site")


def eta_s(done: int, total: int, elapsed_s: float) -> float | None:
    """Seconds left at the mean time per face so far (None before the first face is done)."""
    if done <= 0:
        return None
    return elapsed_s / done * max(0, total - done)


class SiteProgress:
    """Counts finished faces; ``show`` draws the tqdm bar (it has its own ETA), log lines are written always."""

    def __init__(self, total: int, *, show: bool = True):
        self.total, self.done = total, 0
        self.tasks_done, self.tasks_total = 0, 0  # every task (keyframes' and faces'), as the engine reports them
        self.start = time.perf_counter()
        self.bar = progress_bar(total=total, desc="facades", unit="facade", disable=not show)

    def task_done(self, total: int) -> None:
        """One more task of ``total`` is done (shown beside the faces' count)."""
        self.tasks_done, self.tasks_total = self.tasks_done + 1, total
        self.bar.set_postfix_str(f"tasks {self.tasks_done}/{total}")

    def finished(self, outcome: FacadeOutcome) -> None:
        self.done += 1
        self.bar.update(1)
        elapsed = time.perf_counter() - self.start
        left = eta_s(self.done, self.total, elapsed)
        what = {"done": f"done in {outcome.seconds:.1f} s", "skipped": "already done (skipped)",
                "failed": f"FAILED: {outcome.problem}"}[outcome.status]
        tasks = f", tasks {self.tasks_done}/{self.tasks_total}" if self.tasks_total else ""
        log.log(logging.WARNING if outcome.status == "failed" else logging.INFO,
                "facade %s %s; %d/%d facades%s, elapsed %.0f s, ETA %s", outcome.name, what, self.done, self.total,
                tasks, elapsed, "-" if left is None else f"{left:.0f} s")

    def close(self) -> None:
        self.bar.close()

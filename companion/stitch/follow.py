"""Follow mode: re-stitch while the spool fills, so the engineer sees the map grow during the flight.

Each pass re-reads the manifest; features and pair registrations of keyframes already seen come from the
on-disk cache, so a pass costs the new keyframes' matching plus one global adjustment and render. The spool
signals the end of the flight by creating ``<spool>/CLOSED`` (docs/STITCH.md); without it the loop stops
after ``idle_timeout_s`` without new keyframes.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from pathlib import Path

from companion.errors import CompanionError
from companion.spool.layout import CLOSED, MANIFEST
from companion.spool.reader import load_spool
from companion.stitch.worker import StitchConfig, StitchResult, stitch

log = logging.getLogger(__name__)


def follow(
    spool: str | Path,
    out_dir: str | Path,
    config: StitchConfig | None = None,
    *,
    poll_s: float = 2.0,
    min_new: int = 1,
    idle_timeout_s: float = 600.0,
    progress: bool = False,
    on_update: Callable[[StitchResult], None] | None = None,
    sleep: Callable[[float], None] = time.sleep,
    debug_dir: str | Path | None = None,
) -> StitchResult | None:
    """Stitches every time ``min_new`` keyframes have arrived; returns the last result (None if never >= 2)."""
    spool = Path(spool)
    done_n, last_change, last = 0, time.monotonic(), None
    while True:
        closed = (spool / CLOSED).exists()
        try:
            inp = load_spool(spool)
        except CompanionError as exc:
            if not (spool / MANIFEST).exists() and not closed:
                inp = None  # the spool is not started yet
            else:
                raise exc
        n = len(inp.keyframes) if inp else 0
        if n > done_n:
            last_change = time.monotonic()
        if n >= 2 and (n - done_n >= min_new or (closed and n > done_n)):
            last = stitch(inp, out_dir, config, progress=progress, debug_dir=debug_dir)
            done_n = n
            log.info("map updated: %d keyframes, coverage %.1f %%", n, 100 * last.coverage_fraction)
            if on_update:
                on_update(last)
        if closed and n == done_n:
            return last
        if time.monotonic() - last_change > idle_timeout_s:
            log.info("no new keyframes for %.0f s: stopping", idle_timeout_s)
            return last
        sleep(poll_s)

"""One CPU core kept busy by another process while a bench runs (issue 17: figures 'with one core busy')."""

from __future__ import annotations

import contextlib
import multiprocessing
from collections.abc import Iterator


def _spin() -> None:
    while True:
        pass


@contextlib.contextmanager
def busy_core(enabled: bool) -> Iterator[None]:
    """Runs a spinning process for the duration of the block when ``enabled``; always stops it afterwards."""
    spinner = multiprocessing.Process(target=_spin, daemon=True) if enabled else None
    if spinner is not None:
        spinner.start()
    try:
        yield
    finally:
        if spinner is not None:
            spinner.terminate()
            spinner.join()

"""Progress bars that suit both a terminal and a log a companion computer keeps.

On a terminal a tqdm bar redraws in place with carriage returns, which is what a person watching wants. Written to
a file, a pipe or a service journal, those redraws pile up (megabytes of ``\\r``-separated bars per flight) and
break warnings in the middle. ``progress_bar`` returns a tqdm configured for where its output goes: unchanged on a
terminal; otherwise plain-ASCII lines, one per ``log_interval_s`` at most (tqdm's own ``mininterval``), plus the
first and the final count, each a complete line, so warnings between them stay one line each.
"""

from __future__ import annotations

import re
import sys
from typing import IO

from tqdm import tqdm

LOG_INTERVAL_S = 5.0  # seconds between progress lines when the output is not a terminal
_ESCAPE = re.compile(r"\x1b\[[0-9;]*[A-Za-z]")  # cursor moves tqdm uses for stacked bars


def is_terminal(stream: IO[str] | None) -> bool:
    """True when ``stream`` is an interactive terminal (a closed or odd stream counts as not one)."""
    isatty = getattr(stream, "isatty", None)
    try:
        return bool(isatty is not None and isatty())
    except (ValueError, OSError):
        return False


class LineWriter:
    """A file for tqdm that turns every redraw into one complete line (no carriage returns, no cursor moves)."""

    def __init__(self, stream: IO[str]):
        self.stream = stream

    def write(self, text: str) -> int:
        text = _ESCAPE.sub("", str(text)).replace("\r", "\n")
        lines = [line.rstrip() for line in text.split("\n")]
        out = "".join(line + "\n" for line in lines if line)
        if out:
            self.stream.write(out)  # one write: a log line from another thread cannot land inside it
        return len(text)

    def flush(self) -> None:
        flush = getattr(self.stream, "flush", None)
        if flush is not None:
            flush()


class _LogBar(tqdm):
    """tqdm for logs: a new postfix or description shows with the next timed line, not as a line of its own."""

    def set_postfix(self, ordered_dict=None, refresh=True, **kwargs):
        super().set_postfix(ordered_dict, refresh=False, **kwargs)

    def set_postfix_str(self, s="", refresh=True):
        super().set_postfix_str(s, refresh=False)

    def set_description(self, desc=None, refresh=True):
        super().set_description(desc, refresh=False)

    def set_description_str(self, desc=None, refresh=True):
        super().set_description_str(desc, refresh=False)


def progress_bar(
    iterable=None, *, file: IO[str] | None = None, log_interval_s: float = LOG_INTERVAL_S, **kwargs
) -> tqdm:
    """A tqdm bar (same arguments as ``tqdm``) for the output it writes to (default: standard error).

    Not a terminal: a line every ``log_interval_s`` seconds at most, ASCII, always left in place at the end (the
    final count is what a log reader needs), never stacked with cursor moves.
    """
    stream = file if file is not None else sys.stderr
    if is_terminal(stream):
        return tqdm(iterable, file=stream, **kwargs)
    kwargs.update(
        file=LineWriter(stream),
        mininterval=log_interval_s,
        maxinterval=max(log_interval_s, kwargs.get("maxinterval", 10.0)),
        ascii=True,
        leave=True,
        position=0,
        dynamic_ncols=False,
    )
    return _LogBar(iterable, **kwargs)

"""mavsdk's own log lines (its C++ core) routed into Python's logging, one whole record each.

Why: mavsdk's core writes its lines straight to the process's standard error, with colour escapes even into a file
or journal, from its own threads and unsynchronised with Python's logging; in a pilot's log they came spliced into
ours (a stray ``390)`` left from ``(mavsdk_impl.cpp:390)``). Routed through ``logging`` they are whole lines under
the ``mavsdk`` logger with our format, at their own level, and ``-v`` shows mavsdk's debug lines as it does ours.
"""

from __future__ import annotations

import atexit
import logging

import mavsdk

log = logging.getLogger("mavsdk")

LEVELS = {mavsdk.LogLevel.DEBUG: logging.DEBUG, mavsdk.LogLevel.INFO: logging.INFO,
          mavsdk.LogLevel.WARN: logging.WARNING, mavsdk.LogLevel.ERROR: logging.ERROR}
_routed = False


def mavsdk_line(level, message: str, file: str | None, line: int) -> bool:
    """mavsdk's log callback: one logging record per line; True tells mavsdk not to print it itself."""
    where = f" ({file.rsplit('/', 1)[-1]}:{line})" if file else ""
    log.log(LEVELS.get(level, logging.INFO), "%s%s", message.rstrip(), where)
    return True


def route_mavsdk_log() -> None:
    """Route mavsdk's lines into ``logging`` (once per process; undone at exit, before the interpreter that the
    callback needs is gone)."""
    global _routed
    if _routed:
        return
    mavsdk.log_subscribe(mavsdk_line)
    atexit.register(mavsdk.log_unsubscribe)
    _routed = True

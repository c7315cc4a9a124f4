"""Serves a map folder over HTTP on this computer (``companion view``): the page works from file:// too, but a
browser on another machine or a locked-down browser that refuses file:// pages reads it from here."""

from __future__ import annotations

import functools
import logging
from http.server import SimpleHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

from companion.errors import CompanionError

log = logging.getLogger(__name__)


class _Handler(SimpleHTTPRequestHandler):
    """Static files of one folder; requests go to the debug log, not to the terminal (hundreds of tiles)."""

    def log_message(self, format: str, *args) -> None:  # noqa: A002 - the stdlib's signature
        log.debug("%s " + format, self.address_string(), *args)


def make_server(directory: str | Path, host: str = "127.0.0.1", port: int = 8000) -> ThreadingHTTPServer:
    """A server for ``directory`` bound to ``host:port`` (port 0: any free port); call ``serve_forever``."""
    handler = functools.partial(_Handler, directory=str(directory))
    try:
        return ThreadingHTTPServer((host, port), handler)
    except OSError as exc:
        raise CompanionError(
            f"cannot serve on {host}:{port} ({exc.strerror or exc})",
            "pass another --port (0 picks a free one), or open viewer.html directly from the folder",
        ) from exc

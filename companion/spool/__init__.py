"""Durable keyframe hand-off to the stitching worker."""

from companion.spool.layout import SpoolEntry
from companion.spool.reader import StitchInput, load_spool
from companion.spool.writer import KeyframeSpool, SpoolFullError

__all__ = ["KeyframeSpool", "SpoolEntry", "SpoolFullError", "StitchInput", "load_spool"]

"""Durable keyframe hand-off to the stitching worker."""

from companion.spool.writer import KeyframeSpool, SpoolEntry, SpoolFullError

__all__ = ["KeyframeSpool", "SpoolEntry", "SpoolFullError"]

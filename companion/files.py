"""File helpers every stage shares: atomic (optionally durable) writes and JSON-lines reading.

Atomic: a file appears under its final name complete or not at all (written to a temporary name beside it, then
renamed), so a crash, a full disk or a reader polling the folder never sees half a file. Durable (``durable=True``)
adds fsync of the file and of its folder before returning, for what must survive a power cut: the keyframe spool
and the reports a run ends with. Caches and previews skip the fsync (it costs milliseconds per file).
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
from collections.abc import Iterator
from pathlib import Path

TEMP_GLOB = ".*.tmp*"  # what a crash can leave behind: ``.<stem>.tmp<suffix>``


def temp_path(path: Path) -> Path:
    """The temporary name beside ``path``; it keeps the suffix, so writers that pick the format by extension (OpenCV,
    numpy's .npz) still write the same format."""
    return path.with_name(f".{path.stem}.tmp{path.suffix}")


def fsync_dir(path: Path) -> None:
    """Make a rename or a new file in ``path`` durable (POSIX: the directory entry is fsynced separately)."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


@contextlib.contextmanager
def atomic_path(path: str | Path, *, durable: bool = False) -> Iterator[Path]:
    """Yields a temporary path to write ``path`` through (for writers that take a file name: ``cv2.imwrite``,
    ``np.savez``, ``torch.save``); on success it is renamed onto ``path``, on failure removed."""
    path = Path(path)
    tmp = temp_path(path)
    try:
        yield tmp
        if durable:
            with open(tmp, "rb") as fh:
                os.fsync(fh.fileno())
        os.replace(tmp, path)
        if durable:
            fsync_dir(path.parent)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def write_atomic(path: str | Path, data: bytes | str, *, durable: bool = False) -> Path:
    """Write ``data`` (text is UTF-8) to ``path`` atomically; fsynced when ``durable``."""
    path = Path(path)
    with atomic_path(path, durable=durable) as tmp:
        tmp.write_bytes(data.encode("utf-8") if isinstance(data, str) else data)
    return path


def append_durable(path: str | Path, line: str) -> None:
    """Append one line and fsync it: once this returns the line survives a crash (a crash during it can leave a
    torn last line, which :func:`read_jsonl` skips)."""
    with open(path, "ab") as fh:
        fh.write((line.rstrip("\n") + "\n").encode("utf-8"))
        fh.flush()
        os.fsync(fh.fileno())


def read_jsonl(path: str | Path, *, skip_bad: bool = True) -> list[dict]:
    """All records of a JSON-lines file, blank lines ignored. A line that is not JSON (the torn last line a crash
    mid-append leaves) is skipped, or raises ``json.JSONDecodeError`` when ``skip_bad`` is False."""
    rows = []
    with open(path, encoding="utf-8", errors="replace") as fh:
        for line in fh:
            if not line.strip():
                continue
            try:
                rows.append(json.loads(line))
            except json.JSONDecodeError:
                if not skip_bad:
                    raise
    return rows


class NewOutput:
    """What a command is about to create in its output ``folder``, so that a failed run takes back exactly that:
    the folder itself when this run made it, else only the entries of its top level that were not there before
    (a user's own files, and files this run overwrote, stay). Why: a failed `cull --out` or `export colmap` left
    empty or half-made folders behind, which the next run, or the user, took for results."""

    def __init__(self, folder: str | Path):
        self.folder = Path(folder)
        self.existed = self.folder.exists()
        self.before = set(self.folder.iterdir()) if self.existed and self.folder.is_dir() else set()

    def remove_created(self) -> None:
        if not self.existed:
            shutil.rmtree(self.folder, ignore_errors=True)
            return
        if not self.folder.is_dir():
            return
        for entry in set(self.folder.iterdir()) - self.before:
            if entry.is_dir() and not entry.is_symlink():
                shutil.rmtree(entry, ignore_errors=True)
            else:
                entry.unlink(missing_ok=True)


@contextlib.contextmanager
def removed_on_failure(folder: str | Path) -> Iterator[Path]:
    """Run a command's writes into ``folder``; if they raise (an error, Ctrl-C), what they created there is removed
    (:class:`NewOutput`) and the exception goes on."""
    output = NewOutput(folder)
    try:
        yield output.folder
    except BaseException:
        output.remove_created()
        raise

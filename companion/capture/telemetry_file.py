"""A user's ``--telemetry`` file checked line by line before it is culled against, so a wrong file is an error that
names the file, the line and the format expected, not a traceback (or a silent "0 keyframes").

What users hand over by mistake: the same data pretty-printed (one JSON document over many lines), a JSON array,
a CSV export, a MAVLink .tlog / ArduPilot .bin, a log of someone else's tool with other key names. The format is
``companion fly --telemetry-log``'s (companion/flight/telemetry_log.py): one JSON object per line, each with the
keys of ``Pose.to_json``; a position or attitude may be null (no fix yet), a key may not be missing.

One leniency, for the flight's own logs: a line that starts as an object but is not JSON, after good rows, is the
torn row a crash mid-write leaves (at the end, or in the middle when the next flight appended to the same log:
its first row is then glued to the torn one), skipped with a warning naming its line.
"""

from __future__ import annotations

import json
import logging
import math
from pathlib import Path

from companion.errors import CompanionError
from companion.records import Pose

log = logging.getLogger(__name__)

REQUIRED_KEYS = ("t_boot_s", "lat", "lon", "alt_amsl_m", "roll_deg", "pitch_deg", "yaw_deg")
FORMAT_FIX = ("give the log `companion fly --telemetry-log FILE` wrote: JSON lines, one object per line with "
              f"{', '.join(REQUIRED_KEYS)} (numbers, or null before a fix), e.g. "
              '{"t_boot_s": 12.3, "lat": 37.5664, "lon": 126.978, "alt_amsl_m": 33.0, "roll_deg": 0.1, '
              '"pitch_deg": -0.2, "yaw_deg": 0.0, ...}')


def load_telemetry_file(path: Path) -> list[dict]:
    """Every row of a telemetry log, checked; raises CompanionError (file, line, what is expected) on the first
    line that is not a row of that format, and when no row holds a usable sample (time, position and attitude)."""
    path = Path(path)
    if not path.is_file():
        raise CompanionError(f"telemetry log {path} does not exist", "pass the --telemetry-log of the flight")
    try:
        lines = path.read_text(encoding="utf-8", errors="replace").splitlines()
    except OSError as exc:
        raise CompanionError(f"cannot read telemetry log {path} ({exc.strerror})", "check the file") from exc
    numbered = [(n, line.strip()) for n, line in enumerate(lines, start=1) if line.strip()]
    if not numbered:
        raise CompanionError(f"telemetry log {path} is empty", FORMAT_FIX)
    rows = []
    for k, (number, text) in enumerate(numbered):
        try:
            row = json.loads(text)
        except json.JSONDecodeError:
            if rows and text.startswith("{"):
                log.warning("telemetry log %s line %d is a torn row (a crash mid-write): skipped", path, number)
                continue
            raise CompanionError(_not_json(path, number, text, first=k == 0), FORMAT_FIX) from None
        rows.append(_checked_row(path, number, row))
    usable = sum(Pose.from_json(row) is not None for row in rows)
    if usable == 0:
        raise CompanionError(
            f"telemetry log {path} holds no usable sample: none of its {len(rows)} rows has a time, a position "
            f"fix and an attitude (each has a null among {', '.join(REQUIRED_KEYS)})",
            "use the log of a flight that had a GNSS fix while the frames were taken (rows before the fix are null)")
    return rows


def _not_json(path: Path, number: int, text: str, *, first: bool) -> str:
    """Why a line is not a JSON row, in the words of the mistake it most likely is."""
    shown = text if len(text) <= 60 else text[:57] + "..."
    if first and text in ("{", "[") or (first and text.startswith(("[{", "{\""))):
        return (f"telemetry log {path} line {number} is not a whole JSON object: the file looks like one "
                f"pretty-printed JSON document or array ({shown!r}), not JSON lines")
    if first and "," in text and not text.startswith(("{", "[")):
        return f"telemetry log {path} line {number} is not JSON: the file looks like CSV ({shown!r})"
    return f"telemetry log {path} line {number} is not JSON: {shown!r}"


def _checked_row(path: Path, number: int, row: object) -> dict:
    """``row`` when it is an object with every required key, each a number or null."""
    where = f"telemetry log {path} line {number}"
    if not isinstance(row, dict):
        kind = {list: "a JSON array", str: "a string", bool: "true/false"}.get(type(row), f"the value {row!r}")
        raise CompanionError(f"{where} is {kind}, not a JSON object", FORMAT_FIX)
    missing = [key for key in REQUIRED_KEYS if key not in row]
    if missing:
        raise CompanionError(f"{where} lacks {', '.join(missing)} (it has {', '.join(list(row)[:8]) or 'no keys'})",
                             FORMAT_FIX)
    for key in REQUIRED_KEYS:
        value = row[key]
        if value is not None and (isinstance(value, bool) or not isinstance(value, int | float)
                                  or not math.isfinite(value)):
            raise CompanionError(f"{where}: {key} is {value!r}, not a number", FORMAT_FIX)
    return row

"""`companion cull --telemetry FILE` with a wrong file: an error naming the file, the line and the format expected
(exit 2, no traceback), and nothing written; the flight's own logs (a torn last line included) still load."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from companion.capture.telemetry_file import load_telemetry_file
from companion.cli import main

ROW = {"t_wall": 1.7e9, "t_boot_s": 10.0, "lat": 37.56646, "lon": 126.978, "alt_amsl_m": 33.0, "rel_alt_m": 3.0,
       "roll_deg": 0.0, "pitch_deg": 0.0, "yaw_deg": 0.0}


def _rows(n: int = 5) -> list[dict]:
    return [{**ROW, "t_boot_s": 10.0 + i / 10} for i in range(n)]


def _cull(tmp_path: Path, text: str, capsys) -> tuple[int, str]:
    frames = tmp_path / "frames"
    frames.mkdir(exist_ok=True)
    cv2.imwrite(str(frames / "0000.jpg"), np.full((60, 80, 3), 90, np.uint8))
    log = tmp_path / "flight.json"
    log.write_text(text)
    code = main(["cull", str(frames), "--telemetry", str(log), "--out", str(tmp_path / "spool"), "--no-mask",
                 "--no-mission"])
    err = capsys.readouterr().err
    assert not (tmp_path / "spool").exists()  # refused before anything was written
    assert "Traceback" not in err
    return code, err


def _fix_says_the_format(err: str) -> None:
    assert "fix: give the log `companion fly --telemetry-log FILE` wrote: JSON lines, one object per line" in err


@pytest.mark.parametrize(("text", "says"), [
    (json.dumps(_rows(2), indent=2), "line 1 is not a whole JSON object: the file looks like one pretty-printed "
                                     "JSON document or array ('['), not JSON lines"),
    (json.dumps(ROW, indent=1), "line 1 is not a whole JSON object: the file looks like one pretty-printed"),
    ("t_boot_s,lat,lon,alt\n10.0,37.5,126.9,33\n",
     "line 1 is not JSON: the file looks like CSV ('t_boot_s,lat,lon,alt')"),
    (json.dumps(ROW) + "\n[1, 2]\n" + json.dumps(ROW) + "\n", "line 2 is a JSON array, not a JSON object"),
    (json.dumps(ROW) + "\n\n" + json.dumps({"time": 1, "lat": 2}) + "\n", "line 3 lacks t_boot_s, lon, alt_amsl_m"),
    (json.dumps({**ROW, "lat": "37.5N"}) + "\n", "line 1: lat is '37.5N', not a number"),
    (json.dumps(ROW) + "\nnot json\n" + json.dumps(ROW) + "\n", "line 2 is not JSON: 'not json'"),
])
def test_malformed_telemetry_is_an_error_naming_file_line_and_format(tmp_path, capsys, text, says):
    code, err = _cull(tmp_path, text, capsys)
    assert code == 2
    assert f"error: telemetry log {tmp_path / 'flight.json'} {says}" in err, err
    _fix_says_the_format(err)


def test_telemetry_without_a_usable_sample_says_so(tmp_path, capsys):
    no_fix = [{**row, "lat": None, "lon": None, "alt_amsl_m": None} for row in _rows(4)]
    code, err = _cull(tmp_path, "".join(json.dumps(r) + "\n" for r in no_fix), capsys)
    assert code == 2 and "holds no usable sample: none of its 4 rows has a time, a position fix and an attitude" in err
    assert "fix: use the log of a flight that had a GNSS fix" in err
    code, err = _cull(tmp_path, "\n\n", capsys)
    assert code == 2 and "flight.json is empty" in err
    _fix_says_the_format(err)


def test_the_flights_own_log_loads_torn_rows_skipped(tmp_path):
    log = tmp_path / "t.jsonl"
    rows = "".join(json.dumps(r) + "\n" for r in _rows(3))
    log.write_text(rows + '{"t_boot_s": 10.3, "la')  # a crash mid-write
    assert [r["t_boot_s"] for r in load_telemetry_file(log)] == [10.0, 10.1, 10.2]
    log.write_text(rows + '{"t_boot_s": 10.3, "la' + rows)  # ... and the next flight appended to the same log
    assert [r["t_boot_s"] for r in load_telemetry_file(log)] == [10.0, 10.1, 10.2, 10.1, 10.2]

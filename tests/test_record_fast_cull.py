"""`companion record --fast` writes the telemetry log `companion fly` writes, so `companion cull` runs on it as is."""

from __future__ import annotations

import io
import json
import math
from pathlib import Path

from companion.cli import main
from companion.flight.telemetry_log import TelemetryRecorder
from companion.spool.layout import CULL_REPORT, MANIFEST

SMALL_WALL = Path(__file__).parent / "data" / "small-wall.yaml"


def _fly_row_keys() -> set[str]:
    """The columns of a row the flight code writes (``companion fly --telemetry-log``)."""
    rec = TelemetryRecorder(vehicle=None)
    rec._file = io.StringIO()
    rec._write_row(12.345, 37.5, 127.0, 40.0, 10.0, (0.1, 0.2, 0.0))
    return set(json.loads(rec._file.getvalue()))


def test_cull_runs_on_a_fast_recording_and_tags_true_poses(tmp_path):
    rec, spool = tmp_path / "rec", tmp_path / "spool"
    assert main(["record", str(SMALL_WALL), "--out", str(rec), "--fast", "--width", "160",
                 "--max-frames", "30", "--stride", "10"]) == 0
    rows = [json.loads(x) for x in (rec / "telemetry.jsonl").read_text().splitlines()]
    assert set(rows[0]) == _fly_row_keys()
    truth = [json.loads(x) for x in (rec / "truth.jsonl").read_text().splitlines()]
    t_boot = [r["t_boot_s"] for r in rows]
    assert t_boot[0] <= truth[0]["capture_time_s"] and t_boot[-1] >= truth[-1]["capture_time_s"]
    assert all(round(t * 1000) == t * 1000 for t in t_boot)  # whole milliseconds, as time_boot_ms

    # The recording as it is: its frame folder and its telemetry log, no offsets or glue.
    assert main(["cull", str(rec / "frames"), "--telemetry", str(rec / "telemetry.jsonl"), "--out", str(spool),
                 "--mission", str(SMALL_WALL), "--no-mask"]) == 0
    keyframes = [json.loads(x) for x in (spool / MANIFEST).read_text().splitlines()]
    report = json.loads((spool / CULL_REPORT).read_text())
    assert len(keyframes) >= 4 and report["frames_in"] == 30 and report["stale_pose"] == 0, report
    m_per_deg_lat = 111_000.0
    m_per_deg_lon = m_per_deg_lat * math.cos(math.radians(37.5665))
    for kf in keyframes:
        true = truth[kf["index"]]
        pose = kf["pose"]
        assert kf["capture_time_s"] == true["capture_time_s"]
        north = (pose["lat"] - true["pose"]["lat"]) * m_per_deg_lat
        east = (pose["lon"] - true["pose"]["lon"]) * m_per_deg_lon
        assert math.hypot(north, east) < 0.02 and abs(pose["alt_amsl_m"] - true["pose"]["alt_amsl_m"]) < 0.01
        assert abs((pose["yaw_deg"] - true["pose"]["yaw_deg"] + 180) % 360 - 180) < 0.1

"""SITL end to end: a facade scan flown with live culling (real simulator processes, MAVLink, camera stream).

Checks against the simulator's ground truth: every keyframe is tagged with a pose within 0.2 m / 1 deg of the
vehicle's true pose at its capture time, and consecutive keyframes overlap by at least Rth - 3 points unless the
gate itself flagged the pair (low overlap / gap) during the flight.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pymap3d
import pytest

from companion.onboard.live import run_live_scan
from sim.camera.recording import load_recording
from sim.rig import SitlRig

pytestmark = pytest.mark.sitl

SMALL_WALL = """
name: small-wall
facade:
  start: {lat: 37.56650, lon: 126.97800}
  end:   {lat: 37.56650, lon: 126.97809}
  ground_alt_amsl_m: 30.0
  height_m: 5.0
standoff_m: 4.0
overlap: 0.80
side_overlap: 0.5
camera: {width_px: 3840, height_px: 2160, hfov_deg: 69.0, fps: 30, exposure_s: 0.002}
pattern: vertical
takeoff: {lat: 37.56642, lon: 126.97805}
transit_alt_m: 9.0
margins: {ends_m: 1.0, roof_m: 1.0, bottom_clearance_m: 1.5}
end_action: land
geofence: {max_alt_m: 40.0, max_distance_m: 100.0}
"""


def _truth(path: Path):
    rows = [json.loads(x) for x in path.read_text().splitlines() if x.strip()]
    t = np.array([r["t_s"] for r in rows])
    return t, rows


def _true_at(t_all, rows, t):
    k = int(np.searchsorted(t_all, t))
    a, b = rows[max(k - 1, 0)], rows[min(k, len(rows) - 1)]
    s = 0.0 if b["t_s"] == a["t_s"] else (t - a["t_s"]) / (b["t_s"] - a["t_s"])

    def lerp(key):
        return a[key] + s * (b[key] - a[key])

    yaw = a["yaw_deg"] + s * ((b["yaw_deg"] - a["yaw_deg"] + 180) % 360 - 180)
    return lerp("lat"), lerp("lon"), lerp("alt_amsl_m"), lerp("roll_deg"), lerp("pitch_deg"), yaw


def test_live_culling_in_sitl_meets_overlap_and_tagging_accuracy(tmp_path):
    mission = tmp_path / "small.yaml"
    mission.write_text(SMALL_WALL)
    rec_dir, truth_log, spool = tmp_path / "rec", tmp_path / "truth.jsonl", tmp_path / "spool"
    with SitlRig(
        mission, log_dir=tmp_path / "logs", speedup=1.5, fps=3, record_dir=rec_dir, truth_log=truth_log
    ) as rig:
        res = run_live_scan(rig.plan, rig.url, rig.capture, spool, progress=False, handle_signals=False,
                            end_action="land", flight_timeout_s=600)  # fmt: skip
    assert res.flight.completed and res.flight.landed and res.flight.disarmed
    assert res.capture_error is None
    lines = [json.loads(x) for x in (spool / "manifest.jsonl").read_text().splitlines()]
    assert len(lines) >= 5, res.stats.as_dict()

    # Tagging accuracy against the vehicle's true pose at each keyframe's capture time.
    t_all, rows = _truth(truth_log)
    pos_err, att_err = [], []
    for kf in lines:
        pose = kf["pose"]
        assert pose is not None, f"keyframe {kf['index']} has no pose"
        lat, lon, alt, roll, pitch, yaw = _true_at(t_all, rows, kf["capture_time_s"])
        e, n, u = pymap3d.geodetic2enu(pose["lat"], pose["lon"], pose["alt_amsl_m"], lat, lon, alt)
        pos_err.append(math.sqrt(e * e + n * n + u * u))
        dyaw = abs((pose["yaw_deg"] - yaw + 180) % 360 - 180)
        att_err.append(max(dyaw, abs(pose["roll_deg"] - roll), abs(pose["pitch_deg"] - pitch)))
    assert max(pos_err) <= 0.2, f"position errors {sorted(pos_err)[-3:]}"
    assert max(att_err) <= 1.0, f"attitude errors {sorted(att_err)[-3:]}"

    # True overlap of consecutive keyframes (from the recording's geometry) meets Rth - 3 points, or was flagged.
    rec = load_recording(rec_dir)
    truth_lines = [json.loads(x) for x in (rec_dir / "truth.jsonl").read_text().splitlines() if x.strip()]
    by_frame = {int(t["source_frame"]): i for i, t in enumerate(truth_lines)}
    flagged, checked = 0, 0
    for prev, cur in zip(lines, lines[1:], strict=False):
        if prev["index"] not in by_frame or cur["index"] not in by_frame:
            continue  # a keyframe taken away from the wall (not recorded)
        checked += 1
        true = rec.true_overlap(by_frame[prev["index"]], by_frame[cur["index"]])
        gate_flagged = cur["gap_before"] or cur["overlap_to_previous"] is None or cur["overlap_to_previous"] < 80.0
        if gate_flagged:
            flagged += 1
        else:
            assert true >= 0.77, f"keyframes {prev['index']}->{cur['index']}: true overlap {true:.3f} not flagged"
    assert checked >= 4 and flagged <= checked // 2, (checked, flagged, res.stats.as_dict())

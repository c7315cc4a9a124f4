"""SITL end to end: a facade scan flown with live culling (real simulator processes, MAVLink, camera stream).

Checks against the simulator's ground truth: every keyframe is tagged with a pose within 0.2 m / 1 deg of the
vehicle's true pose at its capture time, and consecutive keyframes overlap by at least Rth - 3 points unless the
gate itself flagged the pair (low overlap / gap) during the flight.

The flight is tests/data/small-wall.yaml without PX4's 121 s home-settle hold, on a simulated vehicle told to keep
home still (tests/small_wall.py): the scan starts at once, about 55 s simulated, flown at a speed-up of 2.
"""

from __future__ import annotations

import datetime
import json
import shutil
import subprocess
from pathlib import Path

import pytest

from companion.onboard.live import run_live_scan
from companion.spool.layout import MANIFEST, META
from sim.evaluate_live import TruthTrack, keyframe_overlaps, tagging_errors
from sim.rig import SitlRig
from tests.small_wall import small_wall_scan_at_once

pytestmark = pytest.mark.sitl


def _exiftool_each(paths: list[Path]) -> list[dict]:
    """exiftool's tags (``-j -n -G1``, as tests/test_outputs_exif.py reads them) for every image, from one exiftool
    run: a run per keyframe costs a Perl start-up each, about 20 s for a flight's 30-40 keyframes on a loaded
    machine."""
    tool = shutil.which("exiftool")
    if tool is None:
        pytest.fail("exiftool is not installed: apt-get install -y libimage-exiftool-perl (scripts/bootstrap.sh)")
    out = subprocess.run([tool, "-j", "-n", "-G1", *map(str, paths)], capture_output=True, text=True, check=True)
    by_file = {Path(t["SourceFile"]).resolve(): t for t in json.loads(out.stdout)}
    return [by_file[Path(p).resolve()] for p in paths]


def test_live_culling_in_sitl_meets_overlap_and_tagging_accuracy(tmp_path):
    mission, still_home = small_wall_scan_at_once(tmp_path)
    rec_dir, truth_log, spool = tmp_path / "rec", tmp_path / "truth.jsonl", tmp_path / "spool"
    # Ground truth is recorded for the scan (frames within 4.5 m of the wall): the overlap guarantee is about the
    # scan legs at the standoff, not the approach, whose frames differ in scale.
    rig = SitlRig(mission, log_dir=tmp_path / "logs", speedup=2, fps=3, record_dir=rec_dir, truth_log=truth_log,
                  record_max_out_m=4.5, sim_options=still_home)  # fmt: skip
    with rig:
        res = run_live_scan(rig.plan, rig.url, rig.capture, spool, progress=False, handle_signals=False,
                            end_action="land", flight_timeout_s=600)  # fmt: skip
    assert res.flight.completed and res.flight.landed and res.flight.disarmed
    assert res.capture_error is None
    lines = [json.loads(x) for x in (spool / MANIFEST).read_text().splitlines()]
    assert len(lines) >= 5, res.stats.as_dict()

    # Tagging accuracy against the vehicle's true pose at each keyframe's capture time.
    assert all(kf["pose"] is not None for kf in lines), "a keyframe without a pose"
    errors = tagging_errors(lines, TruthTrack(truth_log))
    assert max(e.position_m for e in errors) <= 0.2, sorted(e.position_m for e in errors)[-3:]
    assert max(e.attitude_deg for e in errors) <= 1.0, sorted(e.attitude_deg for e in errors)[-3:]

    # True overlap of consecutive keyframes (from the recording's geometry) meets Rth - 3 points, or was flagged.
    pairs = keyframe_overlaps(lines, rec_dir)
    for p in pairs:
        assert p.flagged or p.true_overlap >= 0.77, f"keyframes {p.prev}->{p.cur}: true {p.true_overlap:.3f} unflagged"
    flagged = sum(p.flagged for p in pairs)
    assert len(pairs) >= 4 and flagged <= len(pairs) // 2, (len(pairs), flagged, res.stats.as_dict())

    # The keyframe images as photogrammetry tools read them (docs/OUTPUTS.md): capture times on the flight's wall
    # clock with sub-seconds, the exact focal, a horizontal camera (exiftool; tests/test_outputs_exif.py has more).
    flown = [json.loads(x)["t_wall"] for x in res.telemetry_log.read_text().splitlines()]
    focal_px = json.loads((spool / META).read_text())["camera"]["K"][0][0]
    images = [spool / kf["image"] for kf in lines]
    for kf, t in zip(lines, _exiftool_each(images), strict=True):
        when = datetime.datetime.strptime(t["Composite:SubSecDateTimeOriginal"], "%Y:%m:%d %H:%M:%S.%f%z")
        assert min(flown) - 1.0 <= when.timestamp() <= max(flown) + 1.0, (kf["image"], when)
        assert t["ExifIFD:FocalLength"] * t["ExifIFD:FocalPlaneXResolution"] == pytest.approx(focal_px, rel=1e-4)
        assert t["XMP-Camera:Pitch"] == 90

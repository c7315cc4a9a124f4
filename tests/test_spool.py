"""Keyframe spool: tags, atomic manifest, resume without duplicates, crash safety, disk full."""

from __future__ import annotations

import errno
import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from PIL.ExifTags import GPS, IFD, Base

from companion.files import TEMP_GLOB
from companion.records import Frame, GateDecision, GateReason, Keyframe, Pose
from companion.spool import KeyframeSpool, SpoolFullError
from companion.spool import writer as spool_writer
from companion.spool.exif import read_xmp
from companion.spool.layout import CLOSED, MANIFEST, META


def _keyframe(index: int, lat=37.5665123, lon=126.9781234) -> Keyframe:
    rng = np.random.default_rng(index)
    image = rng.integers(0, 255, (120, 160, 3), dtype=np.uint8)
    mask = np.zeros((120, 160), np.uint8)
    mask[:, :100] = 255
    pose = Pose(
        time_s=12.5 + index,
        lat=lat,
        lon=lon,
        alt_amsl_m=41.25,
        relative_alt_m=11.25,
        roll_deg=1.5,
        pitch_deg=-2.0,
        yaw_deg=359.0,
        gimbal_pitch_deg=0.0,
        mission_item=5,
    )
    decision = GateDecision(overlap_to_previous=81.5, inliers=150, reason=GateReason.OVERLAP)
    return Keyframe(Frame(index, 1_700_000_000.123 + index, image), pose, mask, decision)


def _dms_to_deg(dms) -> float:
    return sum(float(v) / 60**k for k, v in enumerate(dms))


def test_keyframe_files_and_tags(tmp_path):
    spool = KeyframeSpool(tmp_path, meta={"camera": {"width_px": 3840, "height_px": 2160, "hfov_deg": 69.0}})
    assert not (tmp_path / META).exists()  # written with the first keyframe, at its real size
    entry = spool.append(_keyframe(7))
    assert json.loads((tmp_path / META).read_text())["camera"] == {
        "width_px": 160,
        "height_px": 120,
        "hfov_deg": 69.0,
    }
    jpeg = (tmp_path / entry.image).read_bytes()
    with Image.open(tmp_path / entry.image) as im:
        exif = im.getexif()
    gps = exif.get_ifd(IFD.GPSInfo)
    assert _dms_to_deg(gps[GPS.GPSLatitude]) == pytest.approx(37.5665123, abs=1e-7)
    assert _dms_to_deg(gps[GPS.GPSLongitude]) == pytest.approx(126.9781234, abs=1e-7)
    assert float(gps[GPS.GPSAltitude]) == pytest.approx(41.25)
    assert exif.get_ifd(IFD.Exif)[Base.SubsecTimeOriginal] == "123"
    xmp = read_xmp(jpeg)
    assert 'drone-dji:FlightYawDegree="-1.00"' in xmp and 'Camera:Pitch="90.00"' in xmp  # horizontal camera
    assert "GimbalPitchDegree" not in xmp  # DJI's gimbal convention only for DJI makes (test_outputs_exif.py)
    assert entry.mask == entry.image.replace(".jpg", "_mask.png")
    side = json.loads((tmp_path / entry.sidecar).read_text())
    assert side["overlap_to_previous"] == 81.5 and side["inliers"] == 150 and side["pose"]["mission_item"] == 5
    assert '"reason": "overlap"' in (tmp_path / entry.sidecar).read_text()  # the enum is written as its string
    # The stitching worker reads exactly this spool.
    from companion.spool.reader import load_spool

    inp = load_spool(tmp_path)
    assert [k.index for k in inp.keyframes] == [7] and inp.keyframes[0].pose is not None


def test_resume_skips_duplicates_and_cuts_torn_line(tmp_path):
    spool = KeyframeSpool(tmp_path)
    for i in (1, 5, 9):
        spool.append(_keyframe(i))
    with open(tmp_path / MANIFEST, "ab") as fh:
        fh.write(b'{"index": 13, "image": "kf_0000')  # crash mid-append
    again = KeyframeSpool(tmp_path)
    assert [e.index for e in again.entries] == [1, 5, 9]
    assert again.append(_keyframe(5)) is None
    again.append(_keyframe(13))
    again.close()
    assert (tmp_path / CLOSED).exists()
    KeyframeSpool(tmp_path)  # reopening for a resumed flight: not closed any more
    assert not (tmp_path / CLOSED).exists()
    lines = (tmp_path / MANIFEST).read_text().splitlines()
    assert [json.loads(x)["index"] for x in lines] == [1, 5, 9, 13]


def test_disk_full_is_a_clear_error_and_loses_nothing(tmp_path, monkeypatch):
    spool = KeyframeSpool(tmp_path)
    spool.append(_keyframe(1))

    def full(path, data, **kw):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(spool_writer, "write_atomic", full)
    with pytest.raises(SpoolFullError, match="disk full") as exc:
        spool.append(_keyframe(2))
    assert "free space" in exc.value.fix
    assert [json.loads(x)["index"] for x in (tmp_path / MANIFEST).read_text().splitlines()] == [1]


CRASH_WRITER = textwrap.dedent(
    """
    import sys, time
    sys.path.insert(0, {tests!r})
    from test_spool import _keyframe
    from companion.spool import KeyframeSpool
    spool = KeyframeSpool({out!r})
    for i in range(1000):
        if spool.append(_keyframe(i)) is not None:
            print(i, flush=True)  # reported only after the manifest line is durable
    """
)


def test_kill_9_mid_write_loses_no_reported_keyframe(tmp_path):
    script = CRASH_WRITER.format(tests=str(Path(__file__).parent), out=str(tmp_path))
    reported: list[int] = []
    for kill_after in (0.05, 0.17):  # after the first reported keyframe (start-up time varies with machine load)
        proc = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True)
        first = proc.stdout.readline()
        time.sleep(kill_after)
        os.kill(proc.pid, signal.SIGKILL)
        out, _ = proc.communicate()
        reported += [int(x) for x in (first + out).split()]
    assert reported, "the writer never reported a keyframe before being killed"
    spool = KeyframeSpool(tmp_path)
    indices = [e.index for e in spool.entries]
    assert len(indices) == len(set(indices))  # resumed without duplicates
    assert set(reported) <= set(indices)  # nothing reported was lost
    for e in spool.entries:  # every manifest entry has complete files
        assert (tmp_path / e.image).stat().st_size > 0 and (tmp_path / e.mask).exists()
        json.loads((tmp_path / e.sidecar).read_text())
    assert not list(tmp_path.glob(TEMP_GLOB))

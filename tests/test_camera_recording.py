"""Recordings: the fast generator writes the documented layout and the loader returns consistent truth."""

from __future__ import annotations

import json

import numpy as np
import pytest

from companion.errors import CompanionError
from companion.mission import load_mission
from sim.camera.recording import RecordingWriter, generate_recording, load_recording

MISSION = "missions/demo-facade.yaml"


@pytest.fixture(scope="module")
def rec(tmp_path_factory):
    out = tmp_path_factory.mktemp("rec") / "demo"
    path = generate_recording(MISSION, out, seed=3, width_px=256, max_frames=12, stride=6)
    return load_recording(path)


def test_layout_and_shapes(rec):
    p = rec.path
    assert len(rec) == 12
    for sub, ext in (("frames", "jpg"), ("depth", "npy"), ("masks", "png")):
        assert len(list((p / sub).glob(f"*.{ext}"))) == 12
    lines = (p / "truth.jsonl").read_text().splitlines()
    assert [json.loads(x)["index"] for x in lines] == list(range(12))
    assert rec.width == 256 and rec.height == 144
    img, depth, mask = rec.image(0), rec.depth(0), rec.roi_mask(0)
    assert img.shape == (144, 256, 3) and img.dtype == np.uint8
    assert depth.shape == (144, 256) and depth.dtype == np.float32
    assert mask.shape == (144, 256) and set(np.unique(mask)) <= {0, 255}
    assert rec.K.shape == (3, 3) and rec.meta["mission"] == "demo-facade"
    assert np.load(p / "depth" / "000000.npy").dtype == np.float16


def test_capture_times_follow_fps_and_stride(rec):
    times = np.array([rec.capture_time(i) for i in range(len(rec))])
    assert np.allclose(np.diff(times), 6 / 30.0)
    assert rec.frame_record(3).capture_time_s == times[3]


def test_first_frames_see_facade_and_background(rec):
    # the scan starts at the top of the wall's left end: facade, roof line and background in one frame
    m = rec.roi_mask(0) > 0
    d = rec.depth(0)
    assert 0.1 < m.mean() < 0.9
    assert np.isinf(d).any()  # sky
    assert np.nanmax(d[m]) < 8.0  # the facade is near (standoff 4 m)
    far = d[~m & np.isfinite(d)]
    assert np.median(far) > 8.0  # background is much farther


def test_roi_depth_is_standoff(rec):
    d, m = rec.depth(5), rec.roi_mask(5) > 0
    pose = rec.camera_pose(5)
    _, out, _ = rec.frame.enu_to_facade(*pose.position_enu)
    # facing the wall squarely (small wobble): facade depth ~ the camera's distance to the wall
    assert np.median(d[m]) == pytest.approx(float(out), rel=0.03)
    assert float(out) == pytest.approx(load_mission(MISSION).standoff_m, abs=0.2)


def test_true_overlap_is_consistent(rec):
    assert rec.true_overlap(4, 4) == pytest.approx(1.0, abs=1e-6)
    o = [rec.true_overlap(4, j) for j in range(4, 12)]
    assert all(a >= b - 1e-6 for a, b in zip(o, o[1:], strict=False))  # moving away along one strip
    assert 0.0 <= rec.true_overlap(0, 11) < rec.true_overlap(0, 1) <= 1.0
    assert rec.true_overlap(4, 6, wall_only=True) <= 1.0


def test_facade_texture_is_the_wall(rec):
    tex = rec.facade_texture(mm_per_px=50)
    assert tex.image.shape[1] == pytest.approx(tex.length_m * 1000 / 50, abs=1)
    assert tex.image.shape[0] == pytest.approx(12.0 * 1000 / 50, abs=1)
    assert tex.image.std() > 5


def test_bad_inputs_raise_companion_errors(rec, tmp_path):
    with pytest.raises(CompanionError):
        load_recording(tmp_path / "nothing")
    with pytest.raises(CompanionError):
        rec.image(len(rec))
    with pytest.raises(CompanionError):
        RecordingWriter(rec.path, {})
    with pytest.raises(CompanionError):
        generate_recording(MISSION, tmp_path / "x", stride=0)


def test_companion_record_fast_cli(tmp_path, capsys):
    from companion.cli import main

    out = tmp_path / "cli"
    assert main(["record", MISSION, "--out", str(out), "--fast", "--max-frames", "4", "--stride", "30",
                 "--width", "160"]) == 0
    assert "recorded 4 frames (160x90)" in capsys.readouterr().out
    assert len(load_recording(out)) == 4
    assert main(["record", MISSION, "--out", str(out), "--fast"]) == 2  # refuses to overwrite

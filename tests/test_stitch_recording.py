"""The worker on a simulator recording: poses, intrinsics and facade come from the recording's truth."""

from __future__ import annotations

from pathlib import Path

import pytest

from companion.stitch import StitchConfig, load_input, stitch
from evaluation.stitch.evaluate import map_accuracy, truth_on_grid
from sim.camera import recording

MISSION = Path(__file__).resolve().parents[1] / "missions" / "demo-facade.yaml"


@pytest.fixture(scope="module")
def rec_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("rec") / "demo"
    return recording.generate_recording(MISSION, d, stride=20, max_frames=10, width_px=640)


def test_recording_with_exact_poses_lands_on_the_wall_texture(rec_dir, tmp_path):
    inp = load_input(rec_dir)
    assert inp.source == "recording" and inp.has_poses and len(inp.keyframes) == 10
    res = stitch(inp, tmp_path, StitchConfig(), progress=False)
    rec = recording.load_recording(rec_dir)
    tex = rec.facade_texture()
    truth = truth_on_grid(tex.image, tex.mm_per_px / 1000, tex.height_m, res.grid, pixel_centre=0.5)
    acc = map_accuracy(res.map_image, res.coverage, truth, res.grid.m_per_px)
    assert acc["patches"] >= 10
    assert acc["median_px"] < 1.5  # exact poses: the map sits where the wall is
    assert acc["rel_median_px"] < 0.5
    assert res.report["map"]["rectified_to_facade"]
    assert res.mm_per_px == pytest.approx(4.0 / rec.K[0, 0] * 1000, rel=0.1)

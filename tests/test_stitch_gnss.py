"""The map stands on the images, telemetry is a prior (issue 15 item 2): a real facade photo as the wall, one
strip of 640 px keyframes, telemetry with GNSS-like noise on every keyframe (0.5 m, 2 degrees) and a 1.5 m jump
on two keyframes in the middle of the strip. The map must be as sharp and seamless as with exact poses, and
report.json must say how well the map is anchored and which keyframes' telemetry the images outvoted."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from companion.stitch import load_input, stitch
from evaluation.stitch.evaluate import map_accuracy, register_to_truth, truth_on_grid
from evaluation.stitch.synthetic import TelemetryErrors, make_spool, wall_for_texture

ROOT = Path(__file__).resolve().parents[1]
PHOTO = ROOT.parent / "shared" / "data" / "real-facades" / "facades" / "strecha_entry-P10" / "images"
PHOTO = PHOTO / "entry-P10_0004.jpg"
JUMPED = (4, 6)  # keyframe positions the 1.5 m jump applies to (of 9, the middle of the strip)


@pytest.fixture(scope="module")
def wall():
    img = cv2.imread(str(PHOTO), cv2.IMREAD_COLOR)
    assert img is not None, f"the real facade photo is missing: {PHOTO}"
    texture = np.ascontiguousarray(img[460:900])  # a 14 m x 3 m band of the baroque entrance at 6.84 mm/px
    return texture, wall_for_texture(texture, 14000 / texture.shape[1])


def _stitch(wall, tmp_path, errors: TelemetryErrors):
    texture, w = wall
    d = tmp_path / "spool"
    # one strip at 4 m: 640x360 keyframes, 80 % overlap, the image height just spans the wall
    truth = make_spool(d, w, width=640, height=360, standoff_m=4.0, overlap=0.8, margin_m=0.05, texture=texture,
                       errors=errors, seed=5)
    res = stitch(load_input(d), tmp_path / "map", progress=False)
    t = truth_on_grid(texture, w.texture_mm_per_px / 1000, w.height_m, res.grid)
    warped, cov = register_to_truth(res.map_image, t)
    acc = map_accuracy(warped, cov, t, res.grid.m_per_px)
    wall_px = truth_on_grid(np.full(texture.shape[:2], 255, np.uint8), w.texture_mm_per_px / 1000, w.height_m,
                            res.grid) > 127
    _, drawn = register_to_truth(res.map_image, t, erode_px=1)
    acc["wall_covered"] = np.count_nonzero(drawn[wall_px]) / np.count_nonzero(wall_px)
    return res, truth, acc


@pytest.fixture(scope="module")
def exact(wall, tmp_path_factory):
    return _stitch(wall, tmp_path_factory.mktemp("exact"), TelemetryErrors())


@pytest.fixture(scope="module")
def gnss(wall, tmp_path_factory):
    return _stitch(wall, tmp_path_factory.mktemp("gnss"), TelemetryErrors(0.5, 2.0, (1.5, 0.0), JUMPED))


def test_noise_and_a_jump_give_the_map_of_exact_poses(exact, gnss):
    res0, truth, acc0 = exact
    res, _, acc = gnss
    assert len(truth["views"]) == 9
    assert acc0["ssim"] > 0.95
    assert acc["ssim"] > 0.95 and acc["ssim"] > acc0["ssim"] - 0.01  # no seams, no ghosting: the same map
    assert acc["rel_p95_px"] < 1.0
    assert len(res.report["keyframes_used"]) == 9 and res.report["pairs_accepted"] >= 8
    assert acc0["wall_covered"] > 0.99
    assert acc["wall_covered"] > 0.99  # a map GNSS puts off is not cut at the wall's ends


def test_report_says_how_well_the_map_is_anchored_and_which_telemetry_was_outvoted(exact, gnss):
    anchor0 = exact[0].report["anchor"]
    anchor = gnss[0].report["anchor"]
    assert anchor0["offset_m"]["max"] < 0.05 and not anchor0["outvoted"]  # exact poses: images agree
    named = {o["index"] for o in anchor["outvoted"]}
    assert named and named <= set(range(*JUMPED))  # the jump is named (noise may hide part of it), nothing else
    assert all(o["offset_m"] > 1.0 for o in anchor["outvoted"])
    assert anchor["offset_m"]["max"] > 1.0
    assert 0.05 < anchor["relative_sigma_m"] < 0.5  # the images against the telemetry
    # where the map sits on the wall: the strip ends 5 cm past the wall's ends, too little to see them, so along
    # the wall the place is GNSS's (a non-RTK bias of a metre or two, issue 26), and the sigma says so
    assert "start" not in gnss[0].report["placement"]["anchored_by"]
    assert anchor["placement_sigma_m"] > 1.5
    assert anchor["keyframes"] == 9

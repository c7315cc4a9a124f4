"""Low-texture walls: the stitcher extracts features as the gate does (CLAHE + SIFT contrast 0.01), so a pass
over real plain cladding (a real UAV photo as the wall texture, tests read it from ../shared) is connected end
to end from the images alone (`--no-poses`), where plain SIFT finds almost nothing to match."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest

from companion.spool.layout import SpoolEntry
from companion.stitch import StitchConfig, load_input, stitch
from companion.stitch.config import STITCH_FEATURES
from companion.stitch.features import detect
from evaluation.stitch.synthetic import make_spool, wall_for_texture

ROOT = Path(__file__).resolve().parents[1]
PHOTO = ROOT.parent / "shared" / "data" / "real-uav-facade" / "DJI_0977_rgb.JPG"


@pytest.fixture(scope="module")
def plain_spool(tmp_path_factory):
    img = cv2.imread(str(PHOTO), cv2.IMREAD_COLOR)
    assert img is not None, f"the real plain-wall photo is missing: {PHOTO}"
    h, w = img.shape[:2]
    # plain grey cladding: left half (no window), a 0.4 m band below the on-screen date, 1 mm per pixel
    texture = np.ascontiguousarray(img[h // 2 - 200 : h // 2 + 200, : w // 2])
    wall = wall_for_texture(texture, 1.0)
    d = tmp_path_factory.mktemp("plain")
    f_px = 320 / np.tan(np.radians(35.0))
    truth = make_spool(
        d, wall, width=640, height=360, standoff_m=f_px / 1000, overlap=0.6, margin_m=0.02, texture=texture
    )
    return d, truth


def test_plain_sift_finds_almost_nothing_on_plain_cladding_and_the_shared_extraction_does(plain_spool):
    d, _ = plain_spool
    img = cv2.imread(str(d / SpoolEntry.for_frame(2).image))
    mask = cv2.imread(str(d / SpoolEntry.for_frame(2).mask), cv2.IMREAD_GRAYSCALE)
    plain = detect(img, mask, replace(STITCH_FEATURES, contrast_threshold=0.04, equalize=False))
    shared = detect(img, mask)
    assert len(plain.keypoints) < 100
    assert len(shared.keypoints) > 10 * max(len(plain.keypoints), 20)


def test_image_only_mode_connects_the_plain_wall_end_to_end(plain_spool, tmp_path):
    d, truth = plain_spool
    res = stitch(load_input(d), tmp_path, StitchConfig(use_poses=False, cells=(8, 4)), progress=False)
    rep = res.report
    assert len(rep["keyframes_used"]) == len(truth["views"]) >= 10
    assert rep["pairs_accepted"] >= len(truth["views"]) - 1
    assert rep["alignment"]["local_residual_px"]["median"] < 1.0
    # end to end: the map spans the whole wall (images alone: the map's scale comes from the standoff)
    span_m = rep["map"]["along_m"][1] - rep["map"]["along_m"][0]
    assert span_m > 0.95 * truth["wall"].length_m

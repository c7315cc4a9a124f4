"""The stitcher as named stages: each stage's record is typed and frozen, the stages run one by one give the
same map as ``stitch()``, and ``--debug-dir`` leaves each stage's decisions where a person can read them."""

from __future__ import annotations

import dataclasses
import json

import cv2
import numpy as np
import pytest

from companion.cli import main
from companion.matching import MatcherSettings
from companion.stitch import StitchConfig, Stitcher, load_input
from companion.stitch.align import AlignedKeyframes
from companion.stitch.canvas import RenderedMap
from companion.stitch.features import Features, KeyframeFeatures
from companion.stitch.layout import MapLayout
from companion.stitch.pairs import PairSettings, RegisteredPairs, match_pair
from companion.stitch.priors import PlanePriors
from companion.stitch.report import StitchReport, StitchRun
from companion.stitch.wall_anchor import WallPlacement
from companion.stitch.wall_distance import WallDistance
from evaluation.stitch.synthetic import SyntheticWall, make_spool

CONFIG = StitchConfig(cells=(8, 4))


@pytest.fixture(scope="module")
def spool(tmp_path_factory):
    d = tmp_path_factory.mktemp("spool")
    make_spool(d, SyntheticWall(length_m=6.0, height_m=3.0, seed=4), pose_noise_m=0.1, seed=4)
    return d


@pytest.fixture(scope="module")
def debug_run(spool, tmp_path_factory):
    out, debug = tmp_path_factory.mktemp("out"), tmp_path_factory.mktemp("debug")
    rc = main(["stitch", str(spool), "--out", str(out), "--cells", "8x4", "--debug-dir", str(debug), "--quiet"])
    assert rc == 0
    return out, debug, json.loads((out / "report.json").read_text())


def test_stages_one_by_one_give_typed_frozen_records_and_the_same_map(spool, tmp_path, debug_run):
    st = Stitcher(CONFIG, progress=False)
    inp = load_input(spool)
    found = st.features(inp, tmp_path)
    priors = st.priors(found)
    pairs = st.pairs(found, priors, tmp_path)
    wall, priors = st.wall_distance(found, priors, pairs)
    aligned = st.alignment(found, priors, pairs)
    found = st.wall_check(found, aligned, tmp_path)  # every stage of Stitcher.stitch, in its order: none left out
    aligned, placement = st.placement(found, priors, aligned, wall)
    layout = st.mesh(found, priors, aligned)
    rendered = st.render(found, aligned, layout, tmp_path)
    records = (found, priors, pairs, wall, aligned, placement, layout, rendered)
    kinds = (KeyframeFeatures, PlanePriors, RegisteredPairs, WallDistance, AlignedKeyframes, WallPlacement, MapLayout,
             RenderedMap)
    for record, kind in zip(records, kinds, strict=True):
        assert isinstance(record, kind)
        with pytest.raises(dataclasses.FrozenInstanceError):
            record.__setattr__(dataclasses.fields(record)[0].name, None)
    with pytest.raises(dataclasses.FrozenInstanceError):
        pairs.results[0].accepted = False  # the alignment stage marks outliers on copies, never in place
    assert len(found.features) == len(inp.keyframes) and priors.use_poses
    assert len(layout.placed) == len(inp.keyframes)
    res = st.report(StitchRun(found.input, CONFIG, priors.use_poses, aligned, layout, rendered, {}, wall, placement),
                    tmp_path)
    assert set(res.report) == {f.name for f in dataclasses.fields(StitchReport)}
    _, _, cli_report = debug_run
    # the CLI run (stitch() with the same settings) made the same map
    assert res.report["pairs_accepted"] == cli_report["pairs_accepted"]
    assert res.report["alignment"]["local_residual_px"] == cli_report["alignment"]["local_residual_px"]
    assert res.coverage_fraction == pytest.approx(cli_report["coverage_fraction"], abs=1e-4)


def test_debug_dir_holds_each_stages_decisions(debug_run):
    out, debug, report = debug_run
    features = json.loads((debug / "1-features" / "features.json").read_text())
    assert len(features["keyframes"]) == len(report["keyframes_used"])
    assert all(k["keypoints"] > 100 for k in features["keyframes"])

    pairs = json.loads((debug / "2-pairs" / "pairs.json").read_text())
    assert len(pairs["pairs"]) == report["pairs_tried"]
    accepted = [p for p in pairs["pairs"] if p["accepted"]]
    assert accepted and all(p["inliers"] >= 15 for p in accepted)
    drawing = cv2.imread(str(debug / "2-pairs" / f"{accepted[0]['a']:06d}-{accepted[0]['b']:06d}.jpg"))
    assert drawing is not None and drawing.shape[1] == 2 * 640  # the two keyframes side by side

    alignment = json.loads((debug / "3-alignment" / "alignment.json").read_text())
    last = alignment["rounds"][-1]
    assert last["transfer_rms_px"] == pytest.approx(report["alignment"]["transfer_rms_after_px"], abs=1e-3)
    assert len(last["pair_residual_px"]) == report["pairs_accepted"]
    assert all(np.asarray(k["plane_from_normalised"]).shape == (3, 3) for k in alignment["keyframes"])

    mesh = json.loads((debug / "4-mesh" / "mesh.json").read_text())
    assert mesh["grid"]["size"] == [report["map"]["width_px"], report["map"]["height_px"]]
    assert np.asarray(mesh["keyframes"][0]["vertices_map_px"]).shape == (4 + 1, 8 + 1, 2)
    picture = cv2.imread(str(debug / "4-mesh" / "mesh.png"))
    assert picture is not None and picture.any()

    coverage = cv2.imread(str(debug / "5-render" / "coverage.png"), cv2.IMREAD_GRAYSCALE)
    drawn = cv2.imread(str(out / "coverage.png"), cv2.IMREAD_GRAYSCALE)
    assert coverage.shape == drawn.shape  # the map is under the preview width: the preview is the map's size
    assert json.loads((debug / "5-render" / "render.json").read_text())["coverage_fraction"] == pytest.approx(
        report["coverage_fraction"], abs=1e-4
    )


def test_no_debug_dir_writes_nothing_beside_the_map(spool, tmp_path):
    Stitcher(CONFIG, progress=False).stitch(load_input(spool), tmp_path / "out")
    assert not any(p.name.startswith(("1-", "2-", "3-", "4-", "5-")) for p in tmp_path.rglob("*"))


def test_a_pair_registers_the_same_whatever_ran_before():
    """FLANN's kd-trees draw from OpenCV's global RNG: unseeded, a pair's matches depended on what ran before it
    (the previous pair's RANSAC, or nothing when that pair came from the cache), so a follow-mode pass and a
    one-shot stitch of the same keyframes could differ."""
    rng = np.random.default_rng(0)
    pts = rng.uniform(20, 1900, (3000, 2)).astype(np.float32)
    desc = rng.random((3000, 128)).astype(np.float32)
    noisy = (desc + rng.normal(0, 0.25, desc.shape)).astype(np.float32)  # approximate search matters here
    fi = Features(pts, desc, (1920, 1080), np.full(3000, 100.0, np.float32))
    fj = Features(pts + np.float32([40.0, 5.0]), noisy, (1920, 1080), np.full(3000, 100.0, np.float32))
    results = []
    for history in (1, 2, 3):
        cv2.setRNGSeed(history)  # whatever used OpenCV's RNG before this pair
        r = match_pair(0, 1, fi, fj, settings=PairSettings(matching=MatcherSettings(ratio=0.8)))
        results.append((r.matches, r.inliers, r.accepted))
    assert results[0][0] > 1000 and results[0][2]
    assert results[1] == results[0] and results[2] == results[0]

"""End-to-end tests of the stitching worker on synthetic walls with exact ground truth."""

from __future__ import annotations

import json
import shutil

import cv2
import numpy as np
import pytest

from companion.cli import main
from companion.errors import CompanionError
from companion.records import Frame, Keyframe, Pose
from companion.spool.layout import MANIFEST, META
from companion.spool.writer import KeyframeSpool
from companion.stitch import load_input, stitch
from companion.stitch.features import Features
from companion.stitch.follow import follow
from companion.stitch.pairs import PairSettings, match_pair
from evaluation.stitch.evaluate import map_accuracy, truth_on_grid
from evaluation.stitch.synthetic import SyntheticWall, make_spool
from tests.hole_wall import HOLE, WALL


@pytest.fixture(scope="module")
def spool(hole_wall_spool):
    """tests/hole_wall.py's spool (the wall, with the patch ``HOLE`` masked as background in every keyframe)."""
    return hole_wall_spool


@pytest.fixture(scope="module")
def result(hole_wall_map):
    """Its map, stitched once per session with the default settings (tests/conftest.py); read-only."""
    return hole_wall_map


def _accuracy(res, truth):
    t = truth_on_grid(truth["texture"], WALL.texture_mm_per_px / 1000, WALL.height_m, res.grid)
    return map_accuracy(res.map_image, res.coverage, t, res.grid.m_per_px)


def test_map_is_accurate_against_the_wall_texture(spool, result):
    _, truth = spool
    acc = _accuracy(result, truth)
    assert acc["patches"] > 40
    assert acc["median_px"] < 0.5 and acc["p95_px"] < 1.5
    assert acc["ssim"] > 0.9
    gsd_mm = 4.0 / truth["camera"].focal_px * 1000
    assert result.mm_per_px == pytest.approx(gsd_mm, rel=0.05)
    rep = result.report
    assert rep["pairs_accepted"] >= len(truth["views"]) - 1
    assert rep["alignment"]["local_residual_px"]["median"] < 0.5
    assert rep["map"]["rectified_to_facade"]


def test_background_is_never_drawn_and_the_hole_is_reported_as_relief(result):
    """The patch every keyframe shows and masks out (a portal, a recess, glass) is relief: seen, not the flat wall,
    so not a re-fly area (a re-fly at the same standoff would mask it out again; issue 26 item 5)."""
    g = result.grid
    x0, y0 = g.to_px(np.array([HOLE[0] + 0.05, HOLE[3] - 0.05])).astype(int)
    x1, y1 = g.to_px(np.array([HOLE[1] - 0.05, HOLE[2] + 0.05])).astype(int)
    assert result.coverage[y0:y1, x0:x1].max() == 0
    assert result.map_image[y0:y1, x0:x1].max() == 0
    assert 0.9 < result.coverage_fraction < 0.99

    def at_hole(areas):
        return [a for a in areas
                if a["along_min_m"] < 4.0 < a["along_max_m"] and a["up_min_m"] < 2.0 < a["up_max_m"]
                and a["area_m2"] < 1.0]

    assert at_hole(result.report["relief_areas_m"]), result.report["relief_areas_m"]
    assert not at_hole([a.as_dict() for a in result.uncovered]), result.uncovered


def test_a_patch_no_keyframe_shows_is_a_refly_area_not_relief(missing_patch_map):
    _, truth, map_dir = missing_patch_map  # flown at 2 m, the patch HOLE in no keyframe; `companion stitch`'s map
    report = json.loads((map_dir / "report.json").read_text())
    assert len(truth["views"]) >= 10
    hits = [a for a in report["uncovered_areas_m"]
            if a["along_min_m"] < 4.0 < a["along_max_m"] and a["up_min_m"] < 2.0 < a["up_max_m"]]
    assert hits and not report["relief_areas_m"]


def test_outputs_on_disk(result):
    files = result.files
    for key in ("map", "coverage", "preview", "report"):
        assert (result.out_dir / files[key].split("/")[-1]).exists()
    rep = json.loads((result.out_dir / "report.json").read_text())
    # every keyframe shows the whole wall around it: no re-fly area, not even a sliver at the wall's ends (the wall
    # check cut 5-10 cm at the left end, where the wall's edge runs along the first strip's vertical motion)
    assert rep["relief_areas_m"] and not rep["uncovered_areas_m"] and rep["map"]["mm_per_px"] > 0
    preview = cv2.imread(files["preview"])
    assert preview.shape[0] > result.grid.height  # the scale-bar strip is appended below the map


def test_resume_uses_the_cache_and_gives_the_same_map(spool, result, tmp_path):
    d, _ = spool
    out = tmp_path / "out"
    shutil.copytree(result.out_dir, out)
    again = stitch(load_input(d), out, progress=False)
    assert again.report["timing_s"]["features"] < 0.5 * max(result.report["timing_s"]["features"], 0.2)
    assert np.array_equal(again.map_image, result.map_image)


def test_tiled_output_matches_in_memory(result, hole_wall_tiled):
    tiled = hole_wall_tiled  # the same spool stitched with tile_px=128, max_in_memory_px=1000 (tests/conftest.py)
    tiles_dir = tiled.out_dir / "tiles"
    assert tiled.map_image is None and tiled.files["tiles"]
    tiles = sorted(tiles_dir.glob("*.png"))
    assert len(tiles) == -(-result.grid.width // 128) * -(-result.grid.height // 128)
    assert tiled.coverage_fraction == pytest.approx(result.coverage_fraction, abs=1e-9)
    t = cv2.imread(str(tiles_dir / "tile_y0000128_x0000256.png"), cv2.IMREAD_UNCHANGED)
    # each tile warps from its own origin: sample positions can differ in the last float bit (<= 1 grey level)
    diff = np.abs(t[..., :3].astype(int) - result.map_image[128:256, 256:384]).max(axis=2)
    assert diff.max() <= 1 and np.count_nonzero(diff) < 0.01 * diff.size
    assert np.array_equal(t[..., 3], result.coverage[128:256, 256:384])


def test_without_telemetry_the_images_alone_give_a_consistent_map(tmp_path):
    d = tmp_path / "spool"
    truth = make_spool(d, WALL, with_poses=False)
    res = stitch(load_input(d), tmp_path / "out", progress=False)
    assert not res.report["telemetry_prior"]
    assert res.mm_per_px == pytest.approx(4.0 / truth["camera"].focal_px * 1000, rel=0.05)  # standoff scale
    assert res.report["alignment"]["local_residual_px"]["p95"] < 1.5
    assert len(res.report["keyframes_used"]) == len(truth["views"])


def test_noisy_telemetry_on_a_repetitive_facade_still_gives_a_seamless_map(tmp_path):
    wall = SyntheticWall(length_m=8.0, height_m=4.0, windows=True, seed=3)
    d = tmp_path / "spool"
    truth = make_spool(d, wall, pose_noise_m=0.15, yaw_noise_deg=0.5, seed=3)
    res = stitch(load_input(d), tmp_path / "out", progress=False)
    t = truth_on_grid(truth["texture"], wall.texture_mm_per_px / 1000, wall.height_m, res.grid)
    acc = map_accuracy(res.map_image, res.coverage, t, res.grid.m_per_px)
    assert acc["rel_median_px"] < 0.6 and acc["rel_p95_px"] < 1.5  # seams: no ghosting, no window slips
    assert acc["ssim_registered"] > 0.95
    assert acc["median_mm"] < 150  # absolute placement is only as good as the telemetry (0.15 m noise)


def test_affine_fallback_when_a_homography_cannot_be_trusted():
    rng = np.random.default_rng(0)
    pts = rng.uniform(20, 600, (60, 2)).astype(np.float32)
    desc = rng.random((60, 128)).astype(np.float32)
    shifted = pts + np.float32([30.0, -10.0])
    fi = Features(pts, desc, (640, 360), np.full(60, 100.0, np.float32))
    fj = Features(shifted, desc, (640, 360), np.full(60, 110.0, np.float32))
    r = match_pair(0, 1, fi, fj, settings=PairSettings(min_inliers=1000))
    assert r.accepted and r.model == "affine"
    assert np.allclose(r.H[:2, 2], [30.0, -10.0], atol=0.5)
    assert r.lum_ratio == pytest.approx(np.log(100 / 110), abs=1e-6)


def _write(spool_dir, lines):
    (spool_dir / MANIFEST).write_text("".join(json.dumps(x) + "\n" for x in lines))


def test_bad_inputs_give_clear_errors(spool, tmp_path):
    d, _ = spool
    lines = [json.loads(x) for x in (d / MANIFEST).read_text().splitlines()]
    bad = tmp_path / "bad"
    shutil.copytree(d, bad)
    _write(bad, lines[:1])
    with pytest.raises(CompanionError, match="at least 2 keyframes"):
        stitch(load_input(bad), tmp_path / "o1", progress=False)
    _write(bad, [lines[0], lines[0]])
    with pytest.raises(CompanionError, match="appears twice"):
        load_input(bad)
    _write(bad, [lines[0], {**lines[1], "image": "frames/nope.jpg"}])
    missing = load_input(bad)  # a damaged spool is not fatal: the keyframe is skipped and named
    assert [kf.index for kf in missing.keyframes] == [lines[0]["index"]]
    assert "nope.jpg is missing" in missing.skipped[0].reason
    with pytest.raises(CompanionError, match="neither a keyframe spool"):
        load_input(tmp_path)


def test_torn_last_manifest_line_is_ignored(spool, tmp_path):
    d, _ = spool
    torn = tmp_path / "torn"
    shutil.copytree(d, torn)
    text = (torn / MANIFEST).read_text()
    (torn / MANIFEST).write_text(text + '{"index": 99, "ima')
    assert len(load_input(torn).keyframes) == len(text.splitlines())


def test_blank_keyframes_without_telemetry_are_refused(tmp_path):
    spool = KeyframeSpool(tmp_path / "spool")
    for k in range(3):
        blank = Frame(k, 1_780_000_000.0 + k, np.full((360, 640, 3), 128, np.uint8))
        spool.append(Keyframe(blank, None, np.full((360, 640), 255, np.uint8)))
    with pytest.raises(CompanionError, match="no two keyframes could be registered"):
        stitch(load_input(tmp_path / "spool"), tmp_path / "out", progress=False)


def _keyframes_of(spool_dir) -> list[Keyframe]:
    """The keyframes of a spool, to be spooled again (a flight's keyframes arriving one by one)."""
    lines = [json.loads(x) for x in (spool_dir / MANIFEST).read_text().splitlines()]
    return [Keyframe(Frame(x["index"], x["capture_time_s"], cv2.imread(str(spool_dir / x["image"]))),
                     Pose.from_json(x["pose"]), cv2.imread(str(spool_dir / x["mask"]), cv2.IMREAD_GRAYSCALE))
            for x in lines]


def test_follow_mode_updates_as_keyframes_arrive(spool, tmp_path):
    d, _ = spool
    keyframes = _keyframes_of(d)
    live = KeyframeSpool(tmp_path / "live", meta=json.loads((d / META).read_text()))
    for kf in keyframes[:4]:
        live.append(kf)
    updates = []

    def fake_sleep(_):  # the rest of the flight, then its end
        for kf in keyframes[4:]:
            live.append(kf)
        live.close()

    last = follow(live.dir, tmp_path / "out", poll_s=0, sleep=fake_sleep, on_update=updates.append)
    assert [len(u.report["keyframes_used"]) for u in updates] == [4, len(keyframes)]
    assert last is updates[-1]


def test_cli_one_shot(spool, result, tmp_path, capsys):
    d, _ = spool
    # resumed from the session map's features and pairs (the cache is keyed by the files and every setting: what
    # the CLI asks differently is computed again); the CLI's own alignment, wall check, mesh, render and report
    shutil.copytree(result.out_dir / "cache" / "features", tmp_path / "cache" / "features")
    shutil.copytree(result.out_dir / "cache" / "pairs", tmp_path / "cache" / "pairs")
    assert main(["stitch", str(d), "--out", str(tmp_path), "--quiet", "--cells", "8x4"]) == 0
    out = capsys.readouterr().out
    assert "mm/px" in out and "coverage" in out
    assert (tmp_path / "map.png").exists()
    assert main(["stitch", str(tmp_path / "missing"), "--out", str(tmp_path)]) == 2
    with pytest.raises(SystemExit):
        main(["stitch", str(d), "--out", str(tmp_path), "--cells", "sixteen"])

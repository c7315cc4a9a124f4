"""A damaged spool still gives a map: keyframes whose files are missing or damaged are skipped and named.

One 32-keyframe spool carries every kind of damage an SD card or a crash leaves (a JPEG cut short, a JPEG of
garbage, a missing image, a mask of the wrong size, an unreadable manifest line); `companion stitch` must map
everything else, name each bad keyframe in its warnings and in report.json, and fail only when nothing is left.
"""

from __future__ import annotations

import json
import shutil

import cv2
import numpy as np
import pytest

from companion.cli import main
from companion.errors import CompanionError
from companion.spool.layout import MANIFEST, SpoolEntry
from companion.stitch import StitchConfig, load_input, stitch
from companion.stitch.features import read_image
from evaluation.stitch.synthetic import SyntheticWall, make_spool

WALL = SyntheticWall(length_m=12.0, height_m=4.0, seed=5)
TRUNCATED, GARBAGE, MISSING, BAD_MASK = 5, 11, 17, 23


@pytest.fixture(scope="module")
def damaged(tmp_path_factory):
    d = tmp_path_factory.mktemp("spool")
    make_spool(d, WALL, width=320, height=180, overlap=0.8)
    lines = (d / MANIFEST).read_text().splitlines()
    assert len(lines) >= 30
    jpg = (d / SpoolEntry.for_frame(TRUNCATED).image).read_bytes()
    (d / SpoolEntry.for_frame(TRUNCATED).image).write_bytes(jpg[: len(jpg) // 2])  # a torn write
    (d / SpoolEntry.for_frame(GARBAGE).image).write_bytes(np.random.default_rng(0).bytes(5000))
    (d / SpoolEntry.for_frame(MISSING).image).unlink()
    cv2.imwrite(str(d / SpoolEntry.for_frame(BAD_MASK).mask), np.full((90, 160), 255, np.uint8))
    # a bad sector in the middle of the manifest: one line unreadable (the keyframe after BAD_MASK)
    lines[BAD_MASK + 1] = lines[BAD_MASK + 1][:20] + "\x00\x00" + lines[BAD_MASK + 1][22:]
    (d / MANIFEST).write_text("\n".join(lines) + "\n")
    return d, len(lines)


@pytest.fixture(scope="module")
def run(damaged, tmp_path_factory):
    d, n = damaged
    out = tmp_path_factory.mktemp("out")
    import contextlib
    import io

    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        rc = main(["stitch", str(d), "--out", str(out), "--quiet", "--cells", "4x3"])
    return rc, buf.getvalue(), json.loads((out / "report.json").read_text()), out, n


def _skipped(report):
    return {s["index"]: s["reason"] for s in report["keyframes_skipped"]}


def test_the_map_is_made_from_every_good_keyframe(run):
    rc, _, report, out, n = run
    assert rc == 0
    assert (out / "map.png").exists()
    bad = {TRUNCATED, GARBAGE, MISSING, BAD_MASK, BAD_MASK + 1}
    assert sorted(report["keyframes_used"]) == [k for k in range(n) if k not in bad]
    assert report["keyframes_in"] == n
    assert report["coverage_fraction"] > 0.95  # neighbours overlap 80 %: the gaps are covered by them


def test_a_jpeg_cut_short_is_skipped_and_named(run):
    _, stdout, report, _, _ = run
    reason = _skipped(report)[TRUNCATED]
    assert f"{TRUNCATED:06d}.jpg" in reason and "truncated" in reason
    assert f"warning: keyframe {TRUNCATED} skipped" in stdout
    assert any(f"keyframe {TRUNCATED} skipped" in w for w in report["warnings"])


def test_a_jpeg_of_garbage_is_skipped_and_named(run):
    _, stdout, report, _, _ = run
    reason = _skipped(report)[GARBAGE]
    assert f"{GARBAGE:06d}.jpg" in reason and "cannot decode" in reason
    assert f"warning: keyframe {GARBAGE} skipped" in stdout


def test_a_missing_image_is_skipped_and_named(run):
    _, stdout, report, _, _ = run
    reason = _skipped(report)[MISSING]
    assert f"{MISSING:06d}.jpg" in reason and "missing" in reason
    assert f"warning: keyframe {MISSING} skipped" in stdout


def test_a_mask_of_the_wrong_size_is_skipped_and_named(run):
    _, stdout, report, _, _ = run
    reason = _skipped(report)[BAD_MASK]
    assert f"{BAD_MASK:06d}_mask.png" in reason and "160x90" in reason
    assert f"warning: keyframe {BAD_MASK} skipped" in stdout


def test_an_unreadable_manifest_line_is_skipped_and_named(run):
    _, _, report, _, _ = run
    reason = _skipped(report)[None]
    assert f"manifest.jsonl:{BAD_MASK + 2}" in reason and "not valid JSON" in reason


def test_no_usable_keyframe_left_is_an_error_that_names_them(damaged, tmp_path):
    d, _ = damaged
    only_bad = tmp_path / "bad"
    shutil.copytree(d, only_bad)
    lines = (only_bad / MANIFEST).read_text().splitlines()
    (only_bad / MANIFEST).write_text("\n".join(lines[k] for k in (TRUNCATED, GARBAGE, BAD_MASK)) + "\n")
    with pytest.raises(CompanionError, match="no usable keyframe is left") as err:
        stitch(load_input(only_bad), tmp_path / "out", StitchConfig(cells=(4, 3)), progress=False)
    assert f"keyframe {TRUNCATED} skipped" in err.value.problem
    assert main(["stitch", str(only_bad), "--out", str(tmp_path / "out2"), "--quiet"]) == 2
    assert not (tmp_path / "out2" / "map.png").exists()


def test_one_good_keyframe_left_still_gives_its_map(damaged, tmp_path):
    d, _ = damaged
    spool = tmp_path / "one"
    shutil.copytree(d, spool)
    lines = (spool / MANIFEST).read_text().splitlines()
    (spool / MANIFEST).write_text("\n".join(lines[k] for k in (0, GARBAGE)) + "\n")
    res = stitch(load_input(spool), tmp_path / "out", StitchConfig(cells=(4, 3)), progress=False)
    assert res.report["keyframes_used"] == [0]
    assert 0.0 < res.coverage_fraction < 0.5


def test_read_image_refuses_a_truncated_jpeg_that_opencv_would_decode(tmp_path):
    img = np.random.default_rng(1).integers(0, 255, (120, 160, 3), dtype=np.uint8)
    ok, data = cv2.imencode(".jpg", img)
    cut = tmp_path / "cut.jpg"
    cut.write_bytes(data.tobytes()[: len(data) * 2 // 3])
    assert cv2.imread(str(cut)) is not None  # OpenCV fills the missing part with grey: no error on its own
    with pytest.raises(CompanionError, match="truncated"):
        read_image(cut, cv2.IMREAD_COLOR, "keyframe image")
    whole = tmp_path / "whole.jpg"
    whole.write_bytes(data.tobytes())
    assert read_image(whole, cv2.IMREAD_COLOR, "keyframe image").shape == img.shape

"""A JPEG cut short (OpenCV decodes it, grey below the cut) is refused by every reader through one decode path, and
named: the image-folder camera of `companion cull` (cull report, summary, warnings), `companion mask`, the stitcher."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from companion.capture.sources import ImageFolderSource
from companion.cli import main
from companion.errors import CompanionError
from companion.image_files import TRUNCATED, jpeg_truncated, read_image_file
from companion.spool.layout import CULL_REPORT
from companion.stitch.features import read_image
from evaluation.keyframes.synthetic import render, sweep, textured_wall

FIXTURES = Path(__file__).parent / "depth_fixtures"


def _cut(path: Path, keep: float = 0.06) -> None:
    """Keep the first ``keep`` of the file: OpenCV still decodes it, mostly grey (the issue's 94 %-grey frame)."""
    data = path.read_bytes()
    path.write_bytes(data[: max(int(len(data) * keep), 700)])


def _frames(folder: Path, n: int) -> Path:
    folder.mkdir(parents=True)
    tex = textured_wall(1400, 400, seed=3)
    for i, view in enumerate(sweep(tex, n, 14, 240, 180, y=200)):
        cv2.imwrite(str(folder / f"{i:04d}.jpg"), render(tex, view))
    return folder


def test_one_decode_path_refuses_a_cut_jpeg_that_opencv_decodes(tmp_path):
    img = np.random.default_rng(1).integers(0, 255, (120, 160, 3), dtype=np.uint8)
    whole = tmp_path / "whole.jpg"
    cv2.imwrite(str(whole), img)
    cut = tmp_path / "cut.jpg"
    shutil.copy(whole, cut)
    _cut(cut, 0.5)
    assert cv2.imread(str(cut)) is not None  # the old readers took it
    read = read_image_file(cut)
    assert read.image is None and read.problem == TRUNCATED and read.describe() == f"cut.jpg: {TRUNCATED}"
    assert jpeg_truncated(cut.read_bytes()) and not jpeg_truncated(whole.read_bytes())
    assert read_image_file(whole).ok and read_image_file(tmp_path / "missing.jpg").problem.startswith("cannot be read")
    (tmp_path / "png.png").write_bytes(cv2.imencode(".png", img)[1].tobytes())
    assert read_image_file(tmp_path / "png.png").ok  # not a JPEG: no marker to look for
    with pytest.raises(CompanionError, match="truncated"):  # the stitcher reads through the same function
        read_image(cut, cv2.IMREAD_COLOR, "keyframe image")


def test_image_folder_skips_and_names_a_cut_jpeg(tmp_path):
    folder = _frames(tmp_path / "rec", n=5)
    _cut(folder / "0002.jpg")
    assert cv2.imread(str(folder / "0002.jpg")) is not None
    src = ImageFolderSource(folder, fps=10.0)
    frames = list(src)
    assert [f.index for f in frames] == [0, 1, 3, 4]  # never delivered, so never a parallax reference
    assert src.stats.corrupt == 1 and src.stats.corrupt_files == [f"0002.jpg: {TRUNCATED}"]


def test_cull_counts_and_names_the_cut_frame(tmp_path, capsys):
    frames = _frames(tmp_path / "frames", n=12)
    _cut(frames / "0005.jpg")
    log = tmp_path / "telemetry.jsonl"
    row = {"t_boot_s": 0.0, "lat": 37.56646, "lon": 126.978, "alt_amsl_m": 33.0, "rel_alt_m": 3.0,
           "roll_deg": 0.0, "pitch_deg": 0.0, "yaw_deg": 0.0}
    log.write_text("".join(json.dumps({**row, "t_boot_s": i / 10, "lon": 126.978 + i * 1e-7}) + "\n"
                           for i in range(20)))
    spool = tmp_path / "spool"
    main(["cull", str(frames), "--telemetry", str(log), "--out", str(spool), "--no-mask", "--no-mission",
          "--fps", "10"])
    printed = capsys.readouterr()
    assert "(1 corrupt," in printed.out and f"0005.jpg: {TRUNCATED}" in printed.out, printed.out
    report = json.loads((spool / CULL_REPORT).read_text())
    assert report["corrupt"] == 1 and report["corrupt_files"] == [f"0005.jpg: {TRUNCATED}"]
    assert report["frames_in"] == 11
    assert any("0005.jpg" in w and "corrupt" in w for w in report["warnings"]), report["warnings"]


def test_mask_names_the_cut_photo_and_why(tmp_path, capsys):
    photos = tmp_path / "photos"
    photos.mkdir()
    shutil.copy(FIXTURES / "DJI_0977_rgb_640.jpg", photos / "good.jpg")
    shutil.copy(FIXTURES / "DJI_0981_rgb_640.jpg", photos / "cut.jpg")
    _cut(photos / "cut.jpg")
    out = tmp_path / "masks"
    assert main(["mask", str(photos), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert f"cut.jpg: {TRUNCATED}" in err and "fix:" in err, err
    assert sorted(p.name for p in out.iterdir()) == ["good_mask.png"]

"""`companion mask`: OpenDroneMap-named 8-bit masks for any photos, unreadable photos named, the rest written."""

from __future__ import annotations

import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from companion.cli import main
from companion.depth.photomask import mask_name, mask_photos
from companion.depth.roi import RoiResult
from companion.errors import CompanionError

FIXTURES = Path(__file__).parent / "depth_fixtures"


class _FarMasker:
    """Stands in for a masker that finds no near surface (the whole photo is far background)."""

    def mask(self, tagged):
        h, w = tagged.frame.image.shape[:2]
        return None, RoiResult(np.zeros((h, w), np.uint8), True, False, 0.0, 1, 0, float("nan"), 0.1, 0.02)


def test_cli_writes_odm_named_masks_and_names_the_unreadable_photo(tmp_path, capsys):
    photos = tmp_path / "photos"
    photos.mkdir()
    shutil.copy(FIXTURES / "DJI_0977_rgb_640.jpg", photos / "DJI_0977.JPG")
    shutil.copy(FIXTURES / "DJI_0981_rgb_640.jpg", photos / "b.png.jpg")
    (photos / "broken.jpg").write_bytes(b"\xff\xd8 not really a jpeg")
    out = tmp_path / "masks"
    code = main(["mask", str(photos), "--out", str(out)])
    printed = capsys.readouterr()
    assert code == 2  # one photo could not be read: non-zero exit ...
    assert "broken.jpg" in printed.err and "fix:" in printed.err
    assert sorted(p.name for p in out.iterdir()) == ["DJI_0977_mask.png", "b.png_mask.png"]  # ... the rest written
    mask = cv2.imread(str(out / "DJI_0977_mask.png"), cv2.IMREAD_UNCHANGED)
    image = cv2.imread(str(photos / "DJI_0977.JPG"))
    assert mask.dtype == np.uint8 and mask.ndim == 2 and mask.shape == image.shape[:2]
    assert set(np.unique(mask)) <= {0, 255} and mask.mean() > 100
    assert "DJI_0977.JPG: ROI" in printed.out and "%" in printed.out


def test_photo_with_no_near_surface_gets_an_all_zero_mask(tmp_path):
    src = FIXTURES / "DJI_0977_rgb_640.jpg"
    results = mask_photos([src], tmp_path, masker=_FarMasker())
    assert results[0].no_near_surface and results[0].roi_fraction == 0.0
    mask = cv2.imread(str(tmp_path / mask_name(src)), cv2.IMREAD_UNCHANGED)
    assert mask.shape == cv2.imread(str(src)).shape[:2] and not mask.any()


def test_same_stem_twice_is_refused_before_writing(tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    a.mkdir()
    b.mkdir()
    for d in (a, b):
        shutil.copy(FIXTURES / "DJI_0977_rgb_640.jpg", d / "IMG_1.jpg")
    with pytest.raises(CompanionError, match="IMG_1_mask.png") as err:
        mask_photos([a / "IMG_1.jpg", b / "IMG_1.jpg"], tmp_path / "out", masker=_FarMasker())
    assert "separate --out" in err.value.fix and not (tmp_path / "out").exists()


def test_missing_photo_is_named(tmp_path):
    with pytest.raises(CompanionError, match="nope.jpg"):
        mask_photos([tmp_path / "nope.jpg"], tmp_path / "out", masker=_FarMasker())

"""`companion mask` one photo at a time: far patches not reaching the top are wall (companion/depth/single_photo.py).

The photos are frames of the validation pass val-b0169-40 (bench/depth_error_regions.py VALIDATION: TRAINING-split
CMP facade b0169 on the wall at 4 m, a training-split Boston street photo 40 m behind, exact truth), rendered at
640 px: the rule was chosen on these passes, so nothing here is a held-out figure (docs/DEPTH.md has those).
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from companion.cli import main
from companion.depth.single_photo import fill_enclosed
from companion.depth.training.realdata import facade_mask, list_real_photos, load_image
from evaluation.shared_data import shared_data_root
from sim.camera.photo_scene import CameraModel, PhotoPass, PhotoPassRenderer, PhotoTexture

# frame 3 of 50: a wall-only view whose top the "sim" network reads far around an enclosed patch (19 % error with
# the network's mask alone, 2 % with the rule); frame 4: the same wall farther along (19 % -> 15 %)
FRAMES = (3, 4)


@pytest.fixture(scope="module")
def photos(tmp_path_factory) -> tuple[Path, list[np.ndarray]]:
    index = {p.image.name: p for p in list_real_photos(shared_data_root(None))}
    wall_photo = index["cmp_b0169.jpg"]
    background_photo = index["static_boston_street_april__p1010115.jpg"]
    assert wall_photo.split == background_photo.split == "train"  # never a held-out photo
    wall = PhotoTexture(wall_photo.image.name, load_image(wall_photo), 14.0, facade_mask(wall_photo))
    spec = PhotoPass("val-b0169-40", wall, PhotoTexture(background_photo.image.name, load_image(background_photo), 1.0),
                     background_distance_m=40.0, frames=50, background_frames=10,
                     strips_up_m=(0.55 * wall.height_m, 0.88 * wall.height_m),
                     camera=CameraModel(width=640, height=360, hfov_deg=69.0))
    renderer = PhotoPassRenderer(spec)
    folder = tmp_path_factory.mktemp("photos")
    truths = []
    for i in FRAMES:
        frame = renderer.render(i)
        cv2.imwrite(str(folder / f"IMG_{i:04d}.png"), frame.image)
        truths.append(frame.roi_mask)
    return folder, truths


def _errors(out: Path, truths: list[np.ndarray]) -> list[float]:
    masks = [cv2.imread(str(out / f"IMG_{i:04d}_mask.png"), cv2.IMREAD_UNCHANGED) for i in FRAMES]
    return [float(np.count_nonzero((m > 127) != (t > 127))) / m.size for m, t in zip(masks, truths, strict=True)]


def test_mask_keeps_the_wall_around_a_patch_the_network_reads_far(photos, tmp_path):
    folder, truths = photos
    assert main(["mask", str(folder), "--out", str(tmp_path / "default"), "--threads", "1"]) == 0
    assert main(["mask", str(folder), "--out", str(tmp_path / "network"), "--threads", "1",
                 "--single-rule", "network"]) == 0
    default, network = _errors(tmp_path / "default", truths), _errors(tmp_path / "network", truths)
    assert network[0] > 0.10  # the network alone cuts an enclosed part of the wall ...
    assert default[0] < 0.05, default  # ... which the default rule keeps
    assert all(d <= n for d, n in zip(default, network, strict=True)), (default, network)


def test_enclosed_patches_are_filled_but_not_those_open_to_a_closed_border():
    mask = np.full((60, 80), 255, np.uint8)
    mask[20:30, 30:40] = 0  # enclosed: a window reflecting the sky
    mask[45:60, 10:20] = 0  # open to the bottom only: a portal
    mask[0:10, 50:60] = 0  # open to the top: sky above a roof line
    mask[25:35, 70:80] = 0  # open to the right: the street beside the wall's end
    out = fill_enclosed(mask)
    assert out[20:30, 30:40].min() == 255 and out[45:60, 10:20].min() == 255
    assert out[0:10, 50:60].max() == 0 and out[25:35, 70:80].max() == 0
    assert fill_enclosed(mask, open_borders=())[45:60, 10:20].max() == 0
    below_wall = fill_enclosed(mask, open_borders=("bottom", "left", "right"))  # the default rule's borders
    assert below_wall[25:35, 70:80].min() == 255 and below_wall[0:10, 50:60].max() == 0  # only the top is open sky
    assert fill_enclosed(np.zeros((8, 8), np.uint8)).max() == 0  # an all-background mask stays all background
    # a photo bigger than the 640 px working copy gets the same answer, pixel for pixel
    big = cv2.resize(mask, (80 * 16, 60 * 16), interpolation=cv2.INTER_NEAREST)
    expected = cv2.resize(out, (80 * 16, 60 * 16), interpolation=cv2.INTER_NEAREST)
    assert np.array_equal(fill_enclosed(big), expected)

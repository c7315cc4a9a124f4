"""The wall bound (issue 27 item 2): a photo's pose tags + the mission's wall cut what cannot be wall, and a GNSS
bias of 1.5 m never cuts true wall."""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pytest

from companion.depth.photo_pose import MissionWall, photo_bound, read_photo_pose
from companion.depth.photomask import mask_photos
from companion.depth.roi import RoiResult
from companion.depth.wall_bound import PoseUncertainty, WallExtent, frontal_view, wall_bound
from companion.mission.spec import load_mission
from companion.records import Pose
from companion.spool.camera import CameraTags, Intrinsics
from companion.spool.exif import encode_tagged_jpeg

ROOT = Path(__file__).resolve().parents[1]
W, H, HFOV = 640, 360, 69.0
ALONG, OUT, UP = 22.0, 20.0, 10.0  # 4.5 m before the 26.5 m wall's right end, 2 m below its 12 m roof line


@pytest.fixture(scope="module")
def wall() -> MissionWall:
    return MissionWall.from_mission(load_mission(ROOT / "missions" / "demo-facade.yaml"))


def _tagged_photo(tmp_path: Path, wall: MissionWall, make: str, along=ALONG, out=OUT, up=UP) -> Path:
    lat, lon, _ = wall.frame.facade_to_geodetic(along, out, up)
    pose = Pose(0.0, float(lat), float(lon), wall.ground_alt_amsl_m + up, up, 0.0, 0.0,
                wall.frame.yaw_facing_wall_deg, gimbal_pitch_deg=0.0, gimbal_yaw_deg=0.0)
    camera = CameraTags(make=make, intrinsics=Intrinsics.from_hfov(W, H, HFOV))
    image = np.full((H, W, 3), 128, np.uint8)
    path = tmp_path / f"{make}_{along:.1f}.jpg"
    path.write_bytes(encode_tagged_jpeg(image, pose, None, camera))
    return path


def _true_wall(wall: MissionWall, along=ALONG, out=OUT, up=UP) -> np.ndarray:
    """Where the wall really is in the image: its projection from the true pose, no margin."""
    focal = (W / 2) / np.tan(np.radians(HFOV / 2))
    exact = PoseUncertainty(horizontal_m=0.0, vertical_m=0.0, attitude_deg=0.0)
    bound = wall_bound(frontal_view(focal, W, H, along, out, up), wall.extent, exact)
    assert bound is not None
    return bound > 0


@pytest.mark.parametrize("make", ["DJI", "companion"])  # drone-dji gimbal tags / Pix4D Camera tags
def test_bound_from_tags_cuts_sky_above_roof_and_building_beyond_the_end(tmp_path, wall, make):
    path = _tagged_photo(tmp_path, wall, make)
    pose = read_photo_pose(path)
    assert pose is not None and pose.focal_px == pytest.approx((W / 2) / np.tan(np.radians(HFOV / 2)), rel=1e-3)
    bound = photo_bound(path, (H, W, 3), wall)
    assert bound is not None
    truth = _true_wall(wall)
    rows, cols = np.where(truth)
    assert not np.any(truth & (bound == 0))  # no true wall cut
    assert not bound[: rows.min() - 60].any()  # the sky well above the roof line is cut
    assert not bound[:, cols.max() + 130:].any()  # the building beyond the wall's end is cut
    assert (bound > 0).mean() < 0.75


def test_a_gnss_bias_of_1_5_m_never_cuts_true_wall(wall):
    focal = (W / 2) / np.tan(np.radians(HFOV / 2))
    for along, out, up in [(ALONG, OUT, UP), (2.0, 13.0, 11.0), (25.0, 6.0, 1.0)]:
        truth = _true_wall(wall, along, out, up)
        for da, do, du in itertools.product((-1.5, 1.5), (-1.5, 1.5), (-0.5, 0.5)):
            bound = wall_bound(frontal_view(focal, W, H, along + da, out + do, up + du), wall.extent)
            assert bound is None or not np.any(truth & (bound == 0)), (along, out, up, da, do, du)


def test_wall_extent_refuses_a_flat_wall():
    with pytest.raises(Exception, match="positive wall length"):
        WallExtent(10.0, 0.0)


class _KeepAll:
    """A masker that keeps every pixel (the network calling the whole photo wall)."""

    def mask(self, tagged):
        h, w = tagged.frame.image.shape[:2]
        full = np.full((h, w), 255, np.uint8)
        return None, RoiResult(mask=full, empty=False, no_boundary=True, roi_fraction=1.0, n_regions=1, n_kept=1,
                               roi_mean_disparity=1.0, background_mean_disparity=float("nan"),
                               gradient_threshold=0.0)


def test_mask_photos_cuts_outside_the_bound_and_leaves_photos_without_a_pose(tmp_path, wall):
    import cv2

    tagged = _tagged_photo(tmp_path, wall, "companion")
    plain = tmp_path / "plain.png"
    cv2.imwrite(str(plain), np.full((H, W, 3), 128, np.uint8))
    past_end = _tagged_photo(tmp_path, wall, "companion", along=50.0)  # sees only what lies beyond the wall's end
    results = {r.image.name: r for r in mask_photos(
        [tagged, plain, past_end], tmp_path / "out", _KeepAll(),
        bound=lambda path, shape: photo_bound(path, shape, wall))}
    cut = cv2.imread(str(results[tagged.name].mask_path), cv2.IMREAD_UNCHANGED)
    assert results[tagged.name].bounded and 0.2 < (cut > 0).mean() < 0.75 and cut[0].max() == 0
    assert not results[plain.name].bounded and results[plain.name].roi_fraction == 1.0
    assert results[past_end.name].no_near_surface


def test_companion_mask_with_a_mission_bounds_tagged_photos(tmp_path, wall, capsys):
    from companion.cli import main

    photo = _tagged_photo(tmp_path, wall, "DJI")
    mission = str(ROOT / "missions" / "demo-facade.yaml")
    assert main(["mask", str(photo), "--out", str(tmp_path / "m"), "--mission", mission, "--standoff", "20"]) == 0
    assert "(wall bound)" in capsys.readouterr().out
    import cv2

    mask = cv2.imread(str(tmp_path / "m" / f"{photo.stem}_mask.png"), cv2.IMREAD_UNCHANGED)
    assert not mask[:20].any() and not mask[:, -60:].any()  # above the roof, beyond the wall's end

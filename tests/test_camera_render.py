"""Renderer behaviour: truth agrees with geometry, seeds vary the scene, camera effects act as specified."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from companion.errors import CompanionError
from companion.geo import FacadeFrame, GeoPoint
from sim.camera.model import CameraModel, TruePose, project
from sim.camera.overlap import clip_to_rect, footprint_on_wall, polygon_area
from sim.camera.render import GROUND, SKY, TARGET, Renderer
from sim.camera.scene import Scene

FRAME = FacadeFrame.from_wall(GeoPoint(37.56650, 126.97800, 30.0), GeoPoint(37.56650, 126.97830, 30.0))
L, H = FRAME.length_m, 12.0
CAM = CameraModel().scaled(320)


@pytest.fixture(scope="module")
def scene():
    return Scene.build(L, H, seed=1)


def pose_at(along, out, up, dyaw=0.0, pitch=0.0, **kw) -> TruePose:
    e, n, u = FRAME.facade_to_enu(along, out, up)
    return TruePose.from_angles([float(e), float(n), float(u)], FRAME.yaw_facing_wall_deg + dyaw, pitch, 0.0, **kw)


def test_depth_and_mask_match_the_geometry(scene):
    r = Renderer(scene, FRAME, CAM, noise=False, blur=False)
    pose = pose_at(L, 4.0, 6.0)  # centred on the right end of the wall
    f = r.render(pose)
    roi = f.roi_mask > 0
    # ROI fraction = the part of the footprint on the wall rectangle
    poly = footprint_on_wall(CAM.K, CAM.width, CAM.height, pose, FRAME)
    expect = polygon_area(clip_to_rect(poly, 0, 0, L, H)) / polygon_area(poly)
    assert roi.mean() == pytest.approx(expect, abs=2.0 / CAM.width)
    assert np.allclose(f.depth[roi], 4.0, atol=1e-3)
    # a known wall point: its pixel sees the target facade at the predicted depth
    uv, z = project(CAM.K, pose, np.array([float(v) for v in FRAME.facade_to_enu(L - 1.0, 0.0, 5.2)]))
    col, row = int(uv[0, 0]), int(uv[0, 1])
    assert f.surface[row, col] == TARGET and f.depth[row, col] == pytest.approx(z[0], abs=1e-3)
    # past the wall's end: background only, far away or sky
    assert not roi[:, -5:].any()
    assert (f.depth[:, -5:] > 8).all()


def test_roof_line_and_ground_are_visible(scene):
    r = Renderer(scene, FRAME, CAM, noise=False, blur=False)
    top = r.render(pose_at(L / 2, 4.0, H + 0.5))
    assert (top.surface[0] == SKY).any() or (top.surface[0] != TARGET).all()
    assert (top.roi_mask[-1] > 0).all()
    low = r.render(pose_at(L / 2, 4.0, 1.0, pitch=-20.0))
    assert (low.surface[-1] == GROUND).all()


def test_same_seed_same_image_other_seed_other_wall(scene):
    r = Renderer(scene, FRAME, CAM)
    p = pose_at(8.0, 4.0, 5.0)
    a, b = r.render(p, index=4), r.render(p, index=4)
    assert np.array_equal(a.image, b.image)
    c = r.render(p, index=5)
    assert not np.array_equal(a.image, c.image)  # fresh sensor noise per frame
    other = Renderer(Scene.build(L, H, seed=2), FRAME, CAM).render(p, index=4)
    assert np.abs(other.image.astype(int) - a.image.astype(int)).mean() > 5


def test_seeds_vary_material_and_layout():
    styles = [Scene.build(L, H, seed=s).style for s in range(12)]
    assert len({s.material for s in styles}) == 3
    assert len({round(s.grid.floor_h, 3) for s in styles}) > 6


def sharpness(img):
    return float(cv2.Laplacian(cv2.cvtColor(img, cv2.COLOR_BGR2GRAY), cv2.CV_64F).var())


def test_motion_blur_grows_with_speed_and_exposure(scene):
    still = pose_at(8.0, 4.0, 5.0)
    fast = pose_at(8.0, 4.0, 5.0, velocity_enu_m_s=np.array([3.0, 0.0, 0.0]))
    sharp = Renderer(scene, FRAME, CAM, exposure_s=1 / 50, noise=False).render(still)
    blurred = Renderer(scene, FRAME, CAM, exposure_s=1 / 50, noise=False).render(fast)
    near, _ = Renderer(scene, FRAME, CAM, exposure_s=1 / 50).blur_vectors(blurred.depth, fast)
    # 3 m/s for 20 ms at 4 m: f * 0.06 / 4 pixels, horizontal
    assert abs(near[0]) == pytest.approx(CAM.K[0, 0] * 0.06 / 4.0, rel=0.01) and abs(near[1]) < 1e-6
    assert sharpness(blurred.image) < 0.7 * sharpness(sharp.image)


def test_crack_is_rendered_where_the_truth_says(scene):
    crack = scene.style.cracks[0]
    pts = np.asarray(crack.points)
    a, u = pts[len(pts) // 2]
    cam = CameraModel().scaled(640)
    r = Renderer(scene, FRAME, cam, noise=False, blur=False)
    pose = pose_at(a, 1.0, u)  # close look: 1 m away, ~1.4 mm per pixel
    f = r.render(pose)
    uv, _ = project(cam.K, pose, np.array([float(v) for v in FRAME.facade_to_enu(a, 0.0, u)]))
    c, rw = int(uv[0, 0]), int(uv[0, 1])
    grey = cv2.cvtColor(f.image, cv2.COLOR_BGR2GRAY).astype(float)
    on = grey[rw - 1 : rw + 2, c - 1 : c + 2].min()
    around = np.median(grey[rw - 25 : rw + 26, c - 25 : c + 26])
    assert crack.width_m > 0 and crack.length_m > 0.3
    assert on < around - 15


def test_exposure_is_validated(scene):
    with pytest.raises(CompanionError):
        Renderer(scene, FRAME, CAM, exposure_s=-1)
    assert math.isfinite(Renderer(scene, FRAME, CAM).render(pose_at(5, 4, 5)).gain)


@pytest.mark.parametrize("seed", [0, 2, 3])  # concrete, panels, brick
def test_every_material_gives_a_feature_matcher_texture(seed):
    sc = Scene.build(L, H, seed=seed)
    cam = CameraModel().scaled(640)
    r = Renderer(sc, FRAME, cam)
    a = r.render(pose_at(8.0, 4.0, 5.0), index=0)
    b = r.render(pose_at(9.0, 4.0, 5.0), index=1)  # 1 m along: 82 % overlap
    sift = cv2.SIFT_create()
    ka, da = sift.detectAndCompute(cv2.cvtColor(a.image, cv2.COLOR_BGR2GRAY), None)
    kb, db = sift.detectAndCompute(cv2.cvtColor(b.image, cv2.COLOR_BGR2GRAY), None)
    assert len(ka) > 100, sc.style.material
    good = [m for m, n in cv2.BFMatcher().knnMatch(da, db, k=2) if m.distance < 0.75 * n.distance]
    shift = np.median([kb[m.trainIdx].pt[0] - ka[m.queryIdx].pt[0] for m in good])
    assert len(good) > 30
    assert shift == pytest.approx(-cam.K[0, 0] * 1.0 / 4.0, abs=2.0)  # image moves left by f * 1 m / 4 m

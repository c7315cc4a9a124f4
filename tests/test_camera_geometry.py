"""Camera geometry truth: pinhole projection of known wall points, and true overlap from footprint polygons
checked against an independent per-pixel reprojection."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from companion.attitude import angles_from_rotation
from companion.errors import CompanionError
from companion.geo import FacadeFrame, GeoPoint
from sim.camera.model import CameraModel, TruePose, project, unproject
from sim.camera.overlap import clip_to_rect, footprint_on_wall, overlap_ratio, polygon_area

FRAME = FacadeFrame.from_wall(GeoPoint(37.56650, 126.97800, 30.0), GeoPoint(37.56650, 126.97830, 30.0))
CAM = CameraModel().scaled(640)


def pose_at(along, out, up, dyaw=0.0, pitch=0.0, roll=0.0) -> TruePose:
    e, n, u = FRAME.facade_to_enu(along, out, up)
    return TruePose.from_angles([float(e), float(n), float(u)], FRAME.yaw_facing_wall_deg + dyaw, pitch, roll)


def wall_point(along, up) -> np.ndarray:
    return np.array([float(v) for v in FRAME.facade_to_enu(along, 0.0, up)])


def test_known_wall_point_projects_where_pinhole_predicts():
    pose = pose_at(10.0, 4.0, 6.0)
    K = CAM.K
    uv, z = project(K, pose, wall_point(11.0, 5.5))
    # facing the wall squarely: 1 m to the right and 0.5 m down at 4 m depth
    assert z[0] == pytest.approx(4.0, abs=1e-6)
    assert uv[0, 0] == pytest.approx(K[0, 2] + K[0, 0] * 1.0 / 4.0, abs=1e-6)
    assert uv[0, 1] == pytest.approx(K[1, 2] + K[1, 1] * 0.5 / 4.0, abs=1e-6)
    back = unproject(K, pose, uv, z)
    assert np.allclose(back[0], wall_point(11.0, 5.5), atol=1e-9)


def test_default_camera_matches_the_paper():
    cam = CameraModel()
    assert (cam.width, cam.height) == (3840, 2160)
    assert cam.K[0, 0] == pytest.approx(1920 / math.tan(math.radians(34.5)))
    small = cam.scaled(640)
    assert small.height == 360 and small.K[0, 0] == pytest.approx(cam.K[0, 0] / 6)


@pytest.mark.parametrize("kw", [{"width": 8, "height": 8}, {"hfov_deg": 0.5}, {"hfov_deg": 200.0}])
def test_bad_camera_is_rejected(kw):
    with pytest.raises(CompanionError):
        CameraModel(**kw)


def test_attitude_round_trip():
    for yaw, pitch, roll in [(0, 0, 0), (359.9, -30, 5), (123.4, 12.5, -7.0), (270, -89, 0)]:
        R = TruePose.from_angles([0, 0, 0], yaw, pitch, roll).R_world_from_cam
        assert np.allclose(R @ R.T, np.eye(3), atol=1e-12)
        y, p, r = angles_from_rotation(R)
        assert (y - yaw + 180) % 360 - 180 == pytest.approx(0, abs=1e-9)
        assert p == pytest.approx(pitch, abs=1e-9) and r == pytest.approx(roll, abs=1e-9)


def test_camera_facing_wall_looks_into_it():
    pose = pose_at(5, 4, 3)
    fwd_enu = pose.R_world_from_cam[:, 2]
    a, o, u = FRAME.enu_to_facade(*fwd_enu)
    assert float(o) == pytest.approx(-1.0, abs=1e-6)


def test_fronto_parallel_footprint_size():
    pose = pose_at(10, 4, 6)
    poly = footprint_on_wall(CAM.K, CAM.width, CAM.height, pose, FRAME)
    w = 2 * 4 * math.tan(math.radians(34.5))
    h = w * CAM.height / CAM.width
    assert polygon_area(poly) == pytest.approx(w * h, rel=1e-6)
    assert poly[:, 0].min() == pytest.approx(10 - w / 2, abs=1e-6)


def reprojection_overlap(pi: TruePose, pj: TruePose, n: int = 160) -> float:
    """Independent estimate: sample pixels of frame i, intersect with the wall plane, project into frame j."""
    K = CAM.K
    us, vs = np.meshgrid((np.arange(n) + 0.5) / n * CAM.width, (np.arange(n) + 0.5) / n * CAM.height)
    uv = np.column_stack([us.ravel(), vs.ravel()])
    rays = np.column_stack([(uv[:, 0] - K[0, 2]) / K[0, 0], (uv[:, 1] - K[1, 2]) / K[1, 1], np.ones(len(uv))])
    d = rays @ pi.R_world_from_cam.T
    oe, on = FRAME.out_enu
    normal = np.array([oe, on, 0.0])
    s = -(pi.position_enu @ normal) / (d @ normal)  # wall plane passes through the ENU origin
    valid = s > 0
    X = pi.position_enu + d * s[:, None]
    # each pixel covers wall area r^2 dOmega / cos(theta) = s^2 / |d . n| (z = 1 rays, up to a constant)
    wgt = np.where(valid, s**2 / np.maximum(np.abs(d @ normal), 1e-12), 0.0)
    uvj, zj = project(K, pj, X)
    inside = valid & (zj > 0) & (uvj[:, 0] >= 0) & (uvj[:, 0] <= CAM.width) & (uvj[:, 1] >= 0) & (
        uvj[:, 1] <= CAM.height)
    return float(wgt[inside].sum() / wgt[valid].sum())


def test_overlap_of_a_frame_with_itself_is_one_and_far_frames_zero():
    p = pose_at(10, 4, 6)
    poly = footprint_on_wall(CAM.K, CAM.width, CAM.height, p, FRAME)
    assert overlap_ratio(poly, poly) == pytest.approx(1.0, abs=1e-6)
    far = footprint_on_wall(CAM.K, CAM.width, CAM.height, pose_at(20, 4, 6), FRAME)
    assert overlap_ratio(poly, far) == 0.0


def test_translation_overlap_matches_closed_form():
    # pure sideways translation by dx at standoff 4: overlap = 1 - dx / footprint width
    w = 2 * 4 * math.tan(math.radians(34.5))
    a = footprint_on_wall(CAM.K, CAM.width, CAM.height, pose_at(10, 4, 6), FRAME)
    b = footprint_on_wall(CAM.K, CAM.width, CAM.height, pose_at(11, 4, 6), FRAME)
    assert overlap_ratio(a, b) == pytest.approx(1 - 1 / w, abs=1e-5)


@settings(max_examples=25, deadline=None)
@given(
    da=st.floats(-3, 3), du=st.floats(-2, 2), dout=st.floats(-1.5, 1.5),
    yaw1=st.floats(-20, 20), yaw2=st.floats(-20, 20), pitch1=st.floats(-15, 15), pitch2=st.floats(-15, 15),
    roll=st.floats(-5, 5),
)
def test_polygon_overlap_agrees_with_pixel_reprojection(da, du, dout, yaw1, yaw2, pitch1, pitch2, roll):
    pi = pose_at(10, 4, 6, yaw1, pitch1, roll)
    pj = pose_at(10 + da, 4 + dout, 6 + du, yaw2, pitch2)
    geo = overlap_ratio(footprint_on_wall(CAM.K, CAM.width, CAM.height, pi, FRAME),
                        footprint_on_wall(CAM.K, CAM.width, CAM.height, pj, FRAME))
    assert geo == pytest.approx(reprojection_overlap(pi, pj), abs=0.015)


def test_clip_to_wall_rectangle():
    poly = footprint_on_wall(CAM.K, CAM.width, CAM.height, pose_at(0.0, 4, 6), FRAME)
    half = clip_to_rect(poly, 0, 0, FRAME.length_m, 12.0)
    assert polygon_area(half) == pytest.approx(polygon_area(poly) / 2, rel=1e-6)

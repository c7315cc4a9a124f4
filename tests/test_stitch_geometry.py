"""Unit tests of the stitcher's geometry: weighted DLT (Eq. 3/4), APAP mesh, homography sanity, pose prior."""

from __future__ import annotations

import numpy as np
import pytest

from companion.attitude import camera_rotation_enu
from companion.geo import FacadeFrame, GeoPoint
from companion.records import GimbalSource, Pose
from companion.spool.reader import CameraModel, CameraPose, FacadeGeometry, camera_attitude
from companion.stitch.geometry import apply_h, is_sane_homography, prior_plane_from_image
from companion.stitch.mesh import mesh_for_keyframe, weighted_dlt

H_TRUE = np.array([[1.1, 0.05, 3.0], [-0.02, 0.95, -2.0], [1e-4, -2e-4, 1.0]])


def test_uniform_weighted_dlt_recovers_homography():
    rng = np.random.default_rng(0)
    src = rng.uniform(0, 500, (60, 2))
    dst = apply_h(H_TRUE, src)
    H = weighted_dlt(src, dst, np.ones((1, 60)))[0]
    assert np.allclose(H, H_TRUE / H_TRUE[2, 2], atol=1e-6)


def test_weighted_dlt_follows_the_heavily_weighted_points():
    rng = np.random.default_rng(1)
    a = rng.uniform(0, 100, (30, 2))
    b = rng.uniform(400, 500, (30, 2))
    Hb = np.array([[1.0, 0.0, 7.0], [0.0, 1.0, -4.0], [0.0, 0.0, 1.0]])
    src = np.vstack((a, b))
    dst = np.vstack((apply_h(H_TRUE, a), apply_h(Hb, b)))
    w = np.concatenate((np.full(30, 1.0), np.full(30, 1e-6)))[None]
    H = weighted_dlt(src, dst, w)[0]
    assert np.abs(apply_h(H, a) - apply_h(H_TRUE, a)).max() < 0.05  # px; the light points pull ~1e-6


def test_apap_mesh_is_local_near_features_and_global_far_away():
    """Left half of the image must move by +1 cm to meet its partner; far right has no features."""
    G = np.diag([4.0, -4.0, 1.0])  # normalised image -> plane
    K = np.array([[500.0, 0, 320], [0, 500, 180], [0, 0, 1]])
    to_norm = np.linalg.inv(K)
    rng = np.random.default_rng(2)
    pts = np.column_stack((rng.uniform(0, 200, 80), rng.uniform(0, 360, 80)))
    base = apply_h(G @ to_norm, pts)
    targets = base + np.array([0.01, 0.0])
    mesh = mesh_for_keyframe(G, to_norm, 640, 360, pts, targets, cells=(8, 4), rho_px=60.0, gamma=1e-4)
    assert mesh.local
    glob = apply_h(G @ to_norm, mesh.src_px.reshape(-1, 2)).reshape(mesh.src_px.shape)
    shift = mesh.dst_plane - glob
    assert np.allclose(shift[:, 1, 0], 0.01, atol=1e-3)  # vertex column at x=80 px: among the features
    assert np.abs(shift[:, -1, 0]).max() < 0.01  # far right: towards the single best fit, not beyond it


def test_mesh_without_enough_matches_is_the_global_homography():
    G = np.diag([4.0, -4.0, 1.0])
    to_norm = np.linalg.inv(np.array([[500.0, 0, 320], [0, 500, 180], [0, 0, 1]]))
    mesh = mesh_for_keyframe(G, to_norm, 640, 360, np.zeros((3, 2)), np.zeros((3, 2)))
    assert not mesh.local
    assert np.allclose(mesh.dst_plane.reshape(-1, 2), apply_h(G @ to_norm, mesh.src_px.reshape(-1, 2)))


@pytest.mark.parametrize(
    "H, ok",
    [
        (np.eye(3), True),
        (H_TRUE, True),
        (np.diag([-1.0, 1.0, 1.0]), False),  # mirrored
        (np.diag([10.0, 10.0, 1.0]), False),  # implausible zoom
        (np.array([[1.0, 0, 0], [0, 1.0, 0], [-0.01, 0, 1.0]]), False),  # horizon crosses the image
        (np.full((3, 3), np.nan), False),
    ],
)
def test_homography_sanity(H, ok):
    corners = np.array([[0, 0], [640, 0], [640, 360], [0, 360]], float)
    assert is_sane_homography(H, corners) is ok


def test_camera_axes_level_and_facing_north():
    R = camera_rotation_enu(yaw_deg=0.0, pitch_deg=0.0, roll_deg=0.0)
    assert np.allclose(R[:, 2], [0, 1, 0])  # forward = north
    assert np.allclose(R[:, 0], [1, 0, 0])  # right = east
    assert np.allclose(R[:, 1], [0, 0, -1])  # image down = down


def test_camera_attitude_is_the_gimbal_s_in_every_form_the_writer_has_written():
    """Today's pose form (``Pose.to_json``) and the writer's form before it (``time_s``, a gimbal yaw of 0.0) give
    the camera on its stabilised gimbal; the vehicle's roll and pitch never tilt it."""
    today = Pose(81.2, 37.5, 127.0, 36.0, 6.0, 2.0, 5.0, 50.0, gimbal_pitch_deg=-10.0, gimbal_yaw_deg=15.0,
                 gimbal_source=GimbalSource.TELEMETRY).to_json()
    assert camera_attitude(today) == (0.0, -10.0, 65.0)
    before = {"time_s": 81.2, "lat": 37.5, "lon": 127.0, "alt_amsl_m": 36.0, "relative_alt_m": 6.0, "roll_deg": 2.0,
              "pitch_deg": 5.0, "yaw_deg": 50.0, "velocity_ned_m_s": [0.0, 0.0, 0.0], "gimbal_pitch_deg": -10.0,
              "gimbal_yaw_deg": 0.0, "mission_item": 3}
    assert camera_attitude(before) == (0.0, -10.0, 50.0)
    unknown = Pose(81.2, 37.5, 127.0, 36.0, 6.0, 2.0, 5.0, 50.0).to_json()  # no gimbal report nor plan
    assert camera_attitude(unknown) == (0.0, 0.0, 50.0)


def test_prior_puts_the_image_centre_in_front_of_the_camera():
    start = GeoPoint(37.5665, 126.978, 30.0)
    frame = FacadeFrame.from_wall(start, GeoPoint(37.5665, 126.9783, 30.0))
    facade = FacadeGeometry(frame, 12.0)
    lat, lon, alt = frame.facade_to_geodetic(10.0, 4.0, 6.0)
    R = camera_rotation_enu(yaw_deg=frame.yaw_facing_wall_deg, pitch_deg=0.0)
    P = prior_plane_from_image(CameraPose(float(lat), float(lon), float(alt), R), facade)
    assert np.allclose(apply_h(P, np.array([[0.0, 0.0]])), [[10.0, 6.0]], atol=1e-4)
    # one normalised unit to the right is standoff metres along the wall; image down is wall down
    assert np.allclose(apply_h(P, np.array([[1.0, 0.0], [0.0, 1.0]])), [[14.0, 6.0], [10.0, 2.0]], atol=1e-4)
    cam = CameraModel.from_hfov(640, 360, 90.0)
    assert cam.focal_px == pytest.approx(320.0)

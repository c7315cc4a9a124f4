"""The standoff measured from the wall's image motion (issue 26): true camera positions make the points, biased
poses go into the fit, as a non-RTK receiver gives them (the poses say 4.0 m while the camera is at 2.5 m)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from companion.keyframes.standoff import StandoffEstimator, StandoffFitConfig, StandoffMeasurement, measure_standoff
from companion.records import Pose
from evaluation.keyframes.synthetic import SITE, WallCamera

W, H, HFOV = 640, 360, 69.0


def _pose(cam: WallCamera, t_s: float, offset_m=(0.0, 0.0, 0.0), yaw_error_deg: float = 0.0,
          pitch_error_deg: float = 0.0) -> Pose:
    along, out, up = cam.centre + np.asarray(offset_m, dtype=float)
    lat, lon, alt = (float(v) for v in SITE.facade_to_geodetic(along, out, up))
    yaw = (SITE.yaw_facing_wall_deg + cam.yaw_deg + yaw_error_deg) % 360.0
    return Pose(t_s, lat, lon, alt, float(up), 0.0, 0.0, yaw, gimbal_pitch_deg=cam.pitch_deg + pitch_error_deg)


def _project(cam: WallCamera, points: np.ndarray) -> np.ndarray:
    """Facade points (N x 3) -> pixels of ``cam``."""
    f = (W / 2.0) / math.tan(math.radians(HFOV) / 2.0)
    K = np.array([[f, 0.0, W / 2.0], [0.0, f, H / 2.0], [0.0, 0.0, 1.0]])
    x = (K @ cam.rotation().T @ (points - cam.centre).T).T
    return x[:, :2] / x[:, 2:3]


def _pairs(a: WallCamera, b: WallCamera, n: int = 150, noise_px: float = 0.5, outliers: float = 0.0,
           seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Wall points both cameras see, projected with the TRUE cameras, pixel noise and a share of wrong matches."""
    rng = np.random.default_rng(seed)
    half = 0.5 * min(a.out_m, b.out_m)
    pts = np.stack([rng.uniform(a.along_m - half, a.along_m + half, n), np.zeros(n),
                    rng.uniform(a.up_m - 0.5 * half, a.up_m + 0.5 * half, n)], axis=1)
    pa, pb = _project(a, pts), _project(b, pts)
    pa += rng.normal(0.0, noise_px, pa.shape)
    pb += rng.normal(0.0, noise_px, pb.shape)
    wrong = rng.random(n) < outliers
    pb[wrong] = rng.uniform([0, 0], [W, H], (int(wrong.sum()), 2))
    return pa, pb


def _measure(a, b, pa, pb, offset_m=(0.0, 1.5, 0.0), **errors) -> StandoffMeasurement | None:
    return measure_standoff(pa, pb, _pose(a, 10.0, offset_m), _pose(b, 11.0, offset_m, **errors), SITE, HFOV, W, H)


def test_a_gnss_bias_towards_the_wall_does_not_move_the_measured_standoff():
    """The camera is at 2.5 m, the poses say 4.0 (1.5 m bias): the wall's image motion over a 0.6 m baseline
    says 2.5, within 2 %, and its sigma covers the error."""
    a, b = WallCamera(6.0, 2.5, 3.0), WallCamera(6.6, 2.5, 3.0)
    m = _measure(a, b, *_pairs(a, b))
    assert m is not None
    assert m.distance_m == pytest.approx(2.5, rel=0.02)
    assert abs(m.distance_m - 2.5) <= 2.0 * m.sigma_m and m.sigma_m < 0.1
    assert m.baseline_m == pytest.approx(0.6, abs=1e-3) and m.n_points >= 140 and m.time_s == pytest.approx(10.5)


def test_without_bias_it_measures_the_planned_standoff_and_a_bias_away_from_the_wall_too():
    a, b = WallCamera(6.0, 4.0, 3.0), WallCamera(6.0, 4.0, 3.8)  # a vertical strip: the camera climbs 0.8 m
    m = _measure(a, b, *_pairs(a, b), offset_m=(0.0, 0.0, 0.0))
    assert m is not None and m.distance_m == pytest.approx(4.0, rel=0.01)
    a, b = WallCamera(6.0, 5.5, 3.0), WallCamera(6.8, 5.5, 3.0)  # 1.5 m further than the poses say
    m = _measure(a, b, *_pairs(a, b), offset_m=(0.0, -1.5, 0.0))
    assert m is not None and m.distance_m == pytest.approx(5.5, rel=0.02)


def test_the_attitude_is_part_of_the_motion():
    """The camera also turns 2 degrees between the frames (the poses say so): the rotation's image motion is not
    taken for translation."""
    a, b = WallCamera(6.0, 2.5, 3.0), WallCamera(6.6, 2.5, 3.0, yaw_deg=2.0, pitch_deg=-1.0)
    m = _measure(a, b, *_pairs(a, b))
    assert m is not None and m.distance_m == pytest.approx(2.5, rel=0.02)


def test_a_hover_or_a_move_towards_the_wall_gives_no_measurement():
    a = WallCamera(6.0, 2.5, 3.0)
    hover = WallCamera(6.01, 2.5, 3.0, yaw_deg=1.5)  # 1 cm and a yaw: all image motion is the rotation's
    assert _measure(a, hover, *_pairs(a, hover)) is None
    closer = WallCamera(6.0, 2.45, 3.0)  # 5 cm along the optical axis: the centre does not move
    assert _measure(a, closer, *_pairs(a, closer)) is None
    assert _measure(a, a, *_pairs(a, a)) is None


def test_thirty_percent_wrong_matches_do_not_move_it():
    a, b = WallCamera(6.0, 2.5, 3.0), WallCamera(6.6, 2.5, 3.0)
    m = _measure(a, b, *_pairs(a, b, outliers=0.3, seed=3))
    assert m is not None and m.distance_m == pytest.approx(2.5, rel=0.02)
    assert 90 <= m.n_points <= 115  # the wrong matches were left out


def test_a_static_far_background_is_not_the_wall():
    """40 % of the matches on a background 120 m away (no mask): still the wall's 2.5 m."""
    a, b = WallCamera(6.0, 2.5, 3.0), WallCamera(6.6, 2.5, 3.0)
    pa, pb = _pairs(a, b, n=90)
    rng = np.random.default_rng(4)
    far = np.stack([rng.uniform(-60, 70, 60), np.full(60, -120.0), rng.uniform(-20, 40, 60)], axis=1)
    fa, fb = _project(a, far), _project(b, far)
    inside = (fa[:, 0] > 0) & (fa[:, 0] < W) & (fa[:, 1] > 0) & (fa[:, 1] < H)
    m = _measure(a, b, np.vstack([pa, fa[inside]]), np.vstack([pb, fb[inside]]))
    assert inside.sum() > 20 and m is not None and m.distance_m == pytest.approx(2.5, rel=0.02)


def test_sigma_is_honest_against_pose_noise():
    """Relative pose noise of the size the fit assumes (0.1 degree attitude, 1 cm position per axis) and 0.5 px
    point noise, 60 pairs: about 95 % of the errors within 2 sigma, and the sigma not a blanket (median error
    above a third of it)."""
    cfg = StandoffFitConfig()
    rng = np.random.default_rng(11)
    ratios = []
    for trial in range(60):
        a = WallCamera(6.0, 2.5, 3.0)
        b = WallCamera(6.0 + rng.uniform(0.3, 0.8), 2.5, 3.0 + rng.normal(0.0, 0.1))
        pa, pb = _pairs(a, b, n=80, seed=trial)
        offset_b = np.array([0.0, 1.5, 0.0]) + rng.normal(0.0, cfg.position_sigma_m, 3)
        pose_b = _pose(b, 1.0, offset_b, yaw_error_deg=rng.normal(0.0, cfg.attitude_sigma_deg),
                       pitch_error_deg=rng.normal(0.0, cfg.attitude_sigma_deg))
        m = measure_standoff(pa, pb, _pose(a, 0.0, (0.0, 1.5, 0.0)), pose_b, SITE, HFOV, W, H)
        assert m is not None
        ratios.append(abs(m.distance_m - 2.5) / m.sigma_m)
    ratios = np.array(ratios)
    assert np.mean(ratios < 2.0) >= 0.88, np.sort(ratios)
    assert np.median(ratios) > 0.33, np.sort(ratios)


def _m(d: float, t: float, sigma: float = 0.05) -> StandoffMeasurement:
    return StandoffMeasurement(d, sigma, 0.6, 80, t)


def test_estimator_combines_a_window_and_says_when_it_has_nothing():
    est = StandoffEstimator(window_s=5.0)
    assert est.estimate(0.0) is None
    for i, d in enumerate([2.48, 2.52, 2.50, 2.51, 9.0, 2.49]):  # one wild pair (a pose glitch)
        est.add(_m(d, 0.5 + 0.8 * i))
    now = est.estimate(5.0)
    assert now is not None and now.distance_m == pytest.approx(2.50, abs=0.01) and now.measurements == 5
    assert 0.015 < now.sigma_m < 0.03  # five pairs of 5 cm each: about 2.2 cm
    assert est.estimate(11.0) is None  # a hover after it: nothing in the last 5 s, not the last value held
    assert est.count == 6


def test_estimator_sigma_grows_when_measurements_disagree_more_than_their_sigmas():
    est = StandoffEstimator(window_s=5.0)
    for i, d in enumerate([2.3, 2.7, 2.35, 2.65]):
        est.add(_m(d, float(i), sigma=0.02))
    now = est.estimate(4.0)
    assert now is not None and now.distance_m == pytest.approx(2.5, abs=0.01)
    assert now.sigma_m > 0.08  # the scatter (0.2 m) says more than the sigmas (0.01 m for four)

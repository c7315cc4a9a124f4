"""The warp renderer against the ray caster: same surfaces, ROI mask and depth on poses that see the wall, its
ends, the roof line, the ground and the background; camera effects as the ray caster models them."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from companion.errors import CompanionError
from companion.geo import FacadeFrame, GeoPoint
from sim.camera.model import CameraModel, TruePose
from sim.camera.render import FAR, GROUND, ROOF, SIDE, SKY, TARGET, TREE, Renderer
from sim.camera.scene import Scene
from sim.camera.warp_render import WarpRenderer, make_renderer

FRAME = FacadeFrame.from_wall(GeoPoint(37.56650, 126.97800, 30.0), GeoPoint(37.56650, 126.97830, 30.0))
L, H = FRAME.length_m, 12.0
CAM = CameraModel().scaled(320)


def pose_at(along, out, up, dyaw=0.0, pitch=0.0, **kw) -> TruePose:
    e, n, u = FRAME.facade_to_enu(along, out, up)
    return TruePose.from_angles([float(e), float(n), float(u)], FRAME.yaw_facing_wall_deg + dyaw, pitch, 0.0, **kw)


POSES = {
    "facing the wall": pose_at(L / 2, 4.0, 6.0),
    "off the left end": pose_at(-1.0, 4.0, 6.0),
    "past the right end": pose_at(L + 3.0, 4.0, 3.0),
    "above the roof line": pose_at(5.0, 4.0, 13.0),
    "low, looking down": pose_at(8.0, 4.0, 1.5, pitch=-25.0),
    "yawed at the corner": pose_at(L, 6.0, 8.0, dyaw=35.0, pitch=10.0),
    "far back": pose_at(L / 2, 30.0, 10.0, pitch=5.0),
    "over the roof": pose_at(L / 2, 2.0, 20.0, pitch=-50.0),
}


@pytest.fixture(scope="module")
def renderers():
    scene = Scene.build(L, H, seed=0)
    kw = dict(noise=False, blur=False)
    return Renderer(scene, FRAME, CAM, **kw), WarpRenderer(scene, FRAME, CAM, **kw)


def _boundaries(surface: np.ndarray) -> np.ndarray:
    """Pixels with a different surface within one pixel (the only place rasterisation may disagree)."""
    k = np.ones((3, 3), np.uint8)
    out = np.zeros(surface.shape, bool)
    for s in np.unique(surface):
        m = (surface == s).astype(np.uint8)
        out |= cv2.dilate(m, k) != cv2.erode(m, k)
    return out


@pytest.mark.parametrize("name", list(POSES))
def test_truth_matches_the_ray_caster(renderers, name):
    ref_r, warp_r = renderers
    ref, got = ref_r.render(POSES[name]), warp_r.render(POSES[name])
    edge = _boundaries(ref.surface)
    differ = ref.surface != got.surface
    assert not (differ & ~edge).any(), f"{name}: surfaces differ off the boundaries"
    assert differ.mean() < 0.003
    roi_differ = ref.roi_mask != got.roi_mask
    assert not (roi_differ & ~edge).any() and roi_differ.mean() < 0.003
    same = ~differ & np.isfinite(ref.depth)
    assert (np.isinf(got.depth) == np.isinf(ref.depth))[~differ].all()
    rel = np.abs(got.depth[same] - ref.depth[same]) / ref.depth[same]
    assert rel.max() < 1e-4
    # colours: the same textures and shading, sampled from cached tiles instead of per pixel
    diff = np.abs(ref.image.astype(np.int16) - got.image.astype(np.int16)).mean()
    assert diff < 4.0, f"{name}: mean colour difference {diff:.1f} DN"
    assert got.gain == pytest.approx(ref.gain, rel=0.03)


def test_the_poses_cover_every_plane_kind(renderers):
    """The comparison above means something only if the poses see every kind of surface."""
    seen = set()
    for pose in POSES.values():
        seen |= set(np.unique(renderers[0].render(pose).surface).tolist())
    assert {SKY, TARGET, SIDE, ROOF, GROUND, FAR, TREE} <= seen


def test_noise_and_exposure_follow_the_camera_model():
    scene = Scene.build(L, H, seed=1)
    clean = WarpRenderer(scene, FRAME, CAM, noise=False, blur=False)
    noisy = WarpRenderer(scene, FRAME, CAM, blur=False, seed=3)
    p = POSES["facing the wall"]
    a, b, c = noisy.render(p, index=4), noisy.render(p, index=4), noisy.render(p, index=5)
    assert np.array_equal(a.image, b.image)  # deterministic per frame index
    assert not np.array_equal(a.image, c.image)  # fresh noise per frame
    d = a.image.astype(np.float32) - clean.render(p).image.astype(np.float32)
    # read noise 1.5 DN and shot noise 0.06 DN per DN of signal: 2.5-4 DN at mid grey, unbiased
    assert 1.5 < float(d.std()) < 4.5
    assert abs(float(d.mean())) < 0.3
    # frame-to-frame noise is independent: no correlation between two frames' noise
    e = c.image.astype(np.float32) - clean.render(p).image.astype(np.float32)
    assert abs(float(np.corrcoef(d.ravel(), e.ravel())[0, 1])) < 0.05


def test_noise_power_is_the_shot_noise_models():
    """One noise level per frame (one cheap pass), the root mean square of the per-pixel model: the frame's noise
    variance is 1.5^2 + 0.06 x its mean signal (plus 1/6 DN^2 of rounding), on a dark and a bright frame."""
    scene = Scene.build(L, H, seed=1)
    for pose in (POSES["facing the wall"], POSES["above the roof line"]):
        for gain in (0.7, 1.5):
            clean = WarpRenderer(scene, FRAME, CAM, noise=False, blur=False)._expose
            noisy = WarpRenderer(scene, FRAME, CAM, blur=False, seed=5)
            img, _, _ = noisy.radiance_u8(pose)
            mean = float(img.mean()) / 255.0
            ref = clean(img, gain, 0, mean).astype(np.float32)
            d = noisy._expose(img, gain, 0, mean).astype(np.float32) - ref
            ok = (ref > 20) & (ref < 235)  # away from saturation
            want = 1.5**2 + 0.06 * mean * gain * 255.0 + 1.0 / 6.0
            assert float(d[ok].var()) == pytest.approx(want, rel=0.08)
            assert abs(float(d[ok].mean())) < 0.1


def test_radiance_depth_is_the_frames(renderers):
    """``radiance_u8``'s z-depth and surfaces are the rendered frame's, also when the wall fills the view (its
    inverse depth is written only when read: it was returned unwritten, all sky)."""
    _, warp_r = renderers
    for name in ("facing the wall", "off the left end"):
        _, depth, surface = warp_r.radiance_u8(POSES[name])
        frame = warp_r.render(POSES[name])
        assert np.array_equal(depth, frame.depth) and np.array_equal(surface, frame.surface), name
        assert np.isfinite(depth).any(), name


def test_motion_blur_as_the_ray_caster():
    scene = Scene.build(L, H, seed=1)
    fast = pose_at(L / 2, 4.0, 6.0, velocity_enu_m_s=np.array([6.0, 0.0, 0.0]))
    ref = Renderer(scene, FRAME, CAM, exposure_s=1 / 50, noise=False).render(fast)
    got = WarpRenderer(scene, FRAME, CAM, exposure_s=1 / 50, noise=False).render(fast)
    sharp = WarpRenderer(scene, FRAME, CAM, exposure_s=1 / 50, noise=False, blur=False).render(fast)

    def sharpness(img):
        return float(cv2.Laplacian(cv2.cvtColor(img, cv2.COLOR_BGR2GRAY), cv2.CV_32F).var())

    assert sharpness(got.image) < 0.5 * sharpness(sharp.image)
    assert sharpness(got.image) == pytest.approx(sharpness(ref.image), rel=0.35)


def test_unknown_renderer_is_a_clear_error():
    scene = Scene.build(L, H, seed=1)
    with pytest.raises(CompanionError, match="raycast"):
        make_renderer("opengl", scene, FRAME, CAM)
    assert isinstance(make_renderer("raycast", scene, FRAME, CAM), Renderer)
    assert isinstance(make_renderer("warp", scene, FRAME, CAM), WarpRenderer)


def test_random_poses_around_the_building_agree_with_the_ray_caster():
    """Seeded random poses (in front, beside, above the building, looking anywhere but straight down) at a small
    size: the same truth as the ray caster, and no pose the warp renderer cannot draw."""
    scene = Scene.build(L, H, seed=4)
    cam = CameraModel().scaled(160)
    ref_r = Renderer(scene, FRAME, cam, noise=False, blur=False)
    warp_r = WarpRenderer(scene, FRAME, cam, noise=False, blur=False)
    rng = np.random.default_rng(11)
    for _ in range(16):
        along, out, up = rng.uniform(-15, L + 15), rng.uniform(1.0, 40.0), rng.uniform(0.5, 30.0)
        pose = pose_at(along, out, up, dyaw=rng.uniform(-180, 180), pitch=rng.uniform(-60, 40))
        ref, got = ref_r.render(pose), warp_r.render(pose)
        differ = ref.surface != got.surface
        assert not (differ & ~_boundaries(ref.surface)).any()
        same = ~differ & np.isfinite(ref.depth)
        assert (np.abs(got.depth[same] - ref.depth[same]) <= 1e-4 * ref.depth[same]).all()


@pytest.mark.parametrize("width", [320, 1280])
def test_wall_tiles_built_ahead_are_the_ones_the_frame_uses(width):
    """The live camera builds the wall's texture tiles while it waits for poses (prefetch_wall at wall_level of
    the standoff): a face-on frame at that standoff must then find every wall tile it needs already built, and
    look the same as without the prefetch."""
    scene = Scene.build(L, H, seed=2)
    cam = CameraModel().scaled(width)
    ahead = WarpRenderer(scene, FRAME, cam, noise=False, blur=False)
    along, up = L / 2, 6.0
    level = ahead.wall_level(4.0)
    assert ahead.prefetch_wall(level, along, up, max_tiles=80) > 0  # nearest first: the view's ~50 and more
    tiles = scene.texture._tiles
    before = set(tiles)
    frame = ahead.render(pose_at(along, 4.0, up))
    assert set(tiles) == before  # no wall tile built during the frame
    if width == 320:  # the whole wall in tiles of 4 m fits the prefetch: then nothing is left to build
        span = scene.texture.TILE * 2**level / 1000.0
        ahead.prefetch_wall(level, along, up, max_tiles=1000)
        assert len(tiles) == (int(L // span) + 1) * (int(H // span) + 1)
        assert ahead.prefetch_wall(level, along, up) == 0
    cold = WarpRenderer(Scene.build(L, H, seed=2), FRAME, cam, noise=False, blur=False).render(pose_at(along, 4.0, up))
    assert np.array_equal(frame.image, cold.image) and np.array_equal(frame.depth, cold.depth)

"""Motion parallax with a telemetry baseline: near wall and far background told apart by how far they move."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from companion.depth.parallax import camera_translation, fuse_with_network, parallax_depth, pick_reference
from companion.errors import CompanionError
from sim.camera.model import CameraModel
from sim.camera.photo_scene import PhotoPass, PhotoPassRenderer, PhotoTexture

CAM = CameraModel(width=640, height=360, hfov_deg=69.0)
R = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, -1.0, 0.0]])  # camera axes in (along, out, up)


def _texture(h: int, w: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    small = rng.integers(0, 255, (h // 8, w // 8, 3), dtype=np.uint8)
    import cv2

    return cv2.GaussianBlur(cv2.resize(small, (w, h), interpolation=cv2.INTER_NEAREST), (5, 5), 0)


@pytest.fixture(scope="module")
def renderer() -> PhotoPassRenderer:
    wall = PhotoTexture("wall", _texture(600, 1200, 1), 12.0)
    bg = PhotoTexture("bg", _texture(600, 800, 2), 1.0)
    return PhotoPassRenderer(PhotoPass("t", wall, bg, camera=CAM, frames=120, background_frames=10))


def _pair(renderer, i, back=2):
    a, b = renderer.render(i - back), renderer.render(i)
    t = camera_translation(R, np.array([a.along_m, 4.0, a.up_m]), R, np.array([b.along_m, 4.0, b.up_m]))
    return a, b, parallax_depth(a.image, b.image, t, CAM.fx)


def test_wall_is_near_and_background_far(renderer):
    _, b, par = _pair(renderer, 95)  # the wall's right end in view, background beside it
    assert 0.2 < b.wall_fraction < 0.8
    import cv2

    truth = cv2.resize(b.roi_mask, par.near.shape[::-1], interpolation=cv2.INTER_NEAREST) > 0
    assert par.trusted.mean() > 0.5
    assert par.near[truth].mean() > 0.7 and par.far[~truth].mean() > 0.7
    wrong = (par.near & ~truth) | (par.far & truth)
    assert wrong.sum() / par.trusted.sum() < 0.05
    assert np.median(par.depth_m[par.near & truth]) == pytest.approx(4.0, rel=0.15)
    fused, dropped = fuse_with_network(np.zeros_like(b.roi_mask), par)  # a network that lost the whole wall
    assert not dropped and ((fused > 0) == (b.roi_mask > 0)).mean() > 0.9


def test_frame_of_only_background_is_dropped_even_if_the_network_keeps_it(renderer):
    _, b, par = _pair(renderer, len(renderer) - 1)
    assert b.wall_fraction == 0.0 and par.all_background
    network_says_near = np.zeros_like(b.roi_mask)
    network_says_near[: 360 // 10] = 255  # the network keeps a strip: parallax sees it move like the background
    fused, dropped = fuse_with_network(network_says_near, par)
    assert dropped and not fused.any()


def test_no_motion_is_refused_and_reference_needs_a_baseline(renderer):
    a = renderer.render(0)
    with pytest.raises(CompanionError, match="no sideways camera motion"):
        parallax_depth(a.image, a.image, np.zeros(3), CAM.fx)
    positions = [np.array([x, 4.0, 2.0]) for x in (0.0, 0.05, 0.1, 0.12)]
    assert pick_reference(positions, np.array([0.15, 4.0, 2.0])) == 1  # the latest at least 8 cm back: 0.05
    assert pick_reference(positions[2:], np.array([0.15, 4.0, 2.0])) is None  # 5 cm or less: network alone
    assert pick_reference([np.zeros(3)], np.array([5.0, 0.0, 0.0])) is None  # too far to track


def test_masker_with_telemetry_parallax_drops_the_real_background_the_network_keeps():
    """Held-out real photos (ornate-entry pass), poses as telemetry: past the wall's end the shipped network keeps
    part of the 120 m background as facade; with parallax the frame is dropped, and a frame with wall is kept."""
    import pymap3d

    from companion.depth.masker import Masker
    from companion.depth.parallax import SequenceParallax
    from companion.records import Frame, Pose, TaggedFrame
    from sim.camera.photo_passes import RECIPES, build_pass

    r = PhotoPassRenderer(build_pass(RECIPES["ornate-entry"], frames=60, background_frames=6))
    masker = Masker(parallax=SequenceParallax(hfov_deg=69.0))
    results = {}
    for i in range(40, 60):
        f = r.render(i)
        # wall along east, drone on its south side 4 m out, camera looking north (yaw 0)
        lat, lon, alt = pymap3d.enu2geodetic(f.along_m, -4.0, f.up_m, 47.0, 8.0, 400.0)
        pose = Pose(time_s=i * 0.1, lat=lat, lon=lon, alt_amsl_m=alt, relative_alt_m=f.up_m, roll_deg=0.0,
                    pitch_deg=0.0, yaw_deg=0.0)
        masked, roi = masker.mask(TaggedFrame(Frame(i, i * 0.1, f.image), pose))
        results[i] = (f, masked, roi)
    assert masker.stats.parallax_frames >= 10
    f, masked, roi = results[59]
    assert f.wall_fraction == 0.0 and masked is None and roi.empty
    f, masked, roi = results[46]
    assert f.wall_fraction > 0.2 and masked is not None
    wall = f.roi_mask > 0
    # the network alone keeps 50 % of this wall and 15 % of the last frame: parallax corrects both
    assert (masked.mask[wall] > 0).mean() > 0.75 and (masked.mask[~wall] > 0).mean() < 0.2


def _geo_pose(i, f):
    import pymap3d

    from companion.records import Pose

    lat, lon, alt = pymap3d.enu2geodetic(f.along_m, -4.0, f.up_m, 47.0, 8.0, 400.0)
    return Pose(time_s=i * 0.1, lat=lat, lon=lon, alt_amsl_m=alt, relative_alt_m=f.up_m, roll_deg=0.0,
                pitch_deg=0.0, yaw_deg=0.0)


def test_sparse_masking_gets_its_reference_from_the_frames_only_tracked():
    """The onboard chain masks only the frames around a keyframe decision, about a metre apart: without the tracked
    frames in between there is never a reference within 60 cm and parallax never judges; remembering them
    (a resize each) gives every masked frame one, and the background-only frame is dropped."""
    from companion.depth.masker import Masker
    from companion.depth.parallax import SequenceParallax
    from companion.records import Frame, TaggedFrame
    from sim.camera.photo_passes import RECIPES, build_pass

    r = PhotoPassRenderer(build_pass(RECIPES["ornate-entry"], frames=60, background_frames=6))
    masked_frames = (36, 46, 59)
    assert r.render(46).along_m - r.render(36).along_m > 0.6  # the masked frames are too far apart on their own

    def run(remember: bool) -> tuple[Masker, dict]:
        masker = Masker(parallax=SequenceParallax(hfov_deg=69.0))
        out = {}
        for i in range(33, 60):
            f = r.render(i)
            tagged = TaggedFrame(Frame(i, i * 0.1, f.image), _geo_pose(i, f))
            if i in masked_frames:
                out[i] = masker.mask(tagged)
            elif remember:
                masker.remember(tagged)
        return masker, out

    sparse, _ = run(remember=False)
    assert sparse.stats.parallax_frames == 0
    masker, out = run(remember=True)
    assert masker.stats.parallax_frames == len(masked_frames)
    assert r.render(59).wall_fraction == 0.0 and out[59][0] is None
    assert r.render(46).wall_fraction > 0.2 and out[46][0] is not None


class _FlatDepthSession:
    """The shipped model's metadata, and a network that reads every pixel at one depth (what it says of a frame
    filled with plain wall, or of a background it misreads as nearly near)."""

    def __init__(self, depth_m: float):
        from companion.depth.session import DepthSession

        self.info = DepthSession().info
        self.depth_m = depth_m

    def disparity(self, image):
        return np.full((self.info.height, self.info.width), self.info.disparity_for_depth(self.depth_m), np.float32)


def test_the_flow_is_spent_only_where_the_network_is_in_doubt(renderer):
    """A frame the network reads as facade everywhere at the 4 m standoff costs no flow (it stays a reference);
    the same frames read at 10 m (a background misread as near: under the 15 m limit, so the network keeps it)
    are judged by parallax, which drops the background-only ones. Without a standoff every frame is judged."""
    from companion.depth.masker import Masker
    from companion.depth.parallax import SequenceParallax
    from companion.records import Frame, TaggedFrame

    def run(depth_m: float, standoff_m: float | None) -> tuple[Masker, dict]:
        masker = Masker(session=_FlatDepthSession(depth_m), parallax=SequenceParallax(69.0, standoff_m=standoff_m))
        out = {}
        for i in range(100, 120):
            f = renderer.render(i)
            out[i] = (f, masker.mask(TaggedFrame(Frame(i, i * 0.1, f.image), _geo_pose(i, f)))[0])
        return masker, out

    sure, out = run(4.0, 4.0)
    assert sure.stats.parallax_frames == 0 and sure.stats.parallax_skipped_sure == 20
    assert all(m is not None and (m.mask > 0).all() for _, m in out.values())  # the network's answer stands
    doubt, out = run(10.0, 4.0)
    assert doubt.stats.parallax_skipped_sure == 0 and doubt.stats.parallax_frames >= 15
    background_only = [i for i, (f, _) in out.items() if f.wall_fraction == 0.0]
    assert len(background_only) >= 5 and all(out[i][1] is None for i in background_only)
    no_standoff, _ = run(4.0, None)
    assert no_standoff.stats.parallax_skipped_sure == 0 and no_standoff.stats.parallax_frames >= 15


def test_network_is_sure_needs_a_whole_frame_of_facade_near_the_standoff():
    from companion.depth.parallax import network_is_sure
    from companion.depth.roi import extract_roi
    from companion.depth.session import DepthSession

    info = DepthSession().info
    flat = np.full((info.height, info.width), info.disparity_for_depth(4.5), np.float32)
    roi = extract_roi(flat, out_size=(640, 360))
    assert roi.no_boundary and network_is_sure(roi, info, standoff_m=4.0)
    assert not network_is_sure(roi, info, standoff_m=2.0)  # 4.5 m is over 1.5 standoffs of 2 m: in doubt
    assert not network_is_sure(roi, info, standoff_m=None)
    split = flat.copy()
    split[: info.height // 2] = info.disparity_for_depth(120.0)  # a far half: a boundary, so in doubt
    assert not network_is_sure(extract_roi(split, out_size=(640, 360)), info, standoff_m=4.0)


def _plain_patch_texture(h: int, w: int, seed: int, patch: tuple[slice, slice]) -> np.ndarray:
    tex = _texture(h, w, seed)
    tex[patch] = (150, 150, 150)  # plain: nothing for the flow to track
    return tex


def test_a_background_nearer_than_the_metric_limit_is_far_against_the_walls_own_flow():
    """A background 9 m behind a wall at 4 m (13 m from the camera) is under the fixed 15 m limit, so the old rule
    kept it as near wherever it was trusted; judged against the wall's own measured flow (2.5x its depth) it is
    far. The wall stays near under both rules."""
    import cv2

    from companion.depth.parallax import NearRule, ParallaxParams

    wall = PhotoTexture("wall", _texture(600, 1200, 1), 12.0)
    bg = PhotoTexture("bg", _texture(600, 800, 2), 1.0)
    r = PhotoPassRenderer(PhotoPass("t", wall, bg, background_distance_m=9.0, camera=CAM, frames=120,
                                    background_frames=10))
    a, b = r.render(93), r.render(95)
    assert 0.2 < b.wall_fraction < 0.8
    t = camera_translation(R, np.array([a.along_m, 4.0, a.up_m]), R, np.array([b.along_m, 4.0, b.up_m]))
    fixed = parallax_depth(a.image, b.image, t, CAM.fx, ParallaxParams(near_rule=NearRule.FIXED))
    ratio = parallax_depth(a.image, b.image, t, CAM.fx)
    truth = cv2.resize(b.roi_mask, ratio.near.shape[::-1], interpolation=cv2.INTER_NEAREST) > 0
    assert fixed.near[~truth & fixed.trusted].mean() > 0.7  # the old rule: the background is "near"
    assert ratio.far[~truth & ratio.trusted].mean() > 0.9
    assert ratio.near[truth & ratio.trusted].mean() > 0.9


def test_plain_patches_take_the_side_of_the_trusted_pixels_around_them():
    """A plain patch inside the wall (no texture: parallax cannot see it) that the network cut is wall: background
    cannot show through a wall. A plain patch of background the network kept, with only far pixels around it,
    is background. With the plain rule off both keep the network's mistake."""
    import cv2

    from companion.depth.parallax import ParallaxParams, PlainRule

    wall_tex = _plain_patch_texture(600, 1200, 1, (slice(200, 400), slice(900, 1100)))
    bg_tex = _plain_patch_texture(600, 800, 2, (slice(200, 330), slice(665, 740)))  # lands right of the wall
    wall = PhotoTexture("wall", wall_tex, 12.0)
    bg = PhotoTexture("bg", bg_tex, 1.0)
    r = PhotoPassRenderer(PhotoPass("t", wall, bg, camera=CAM, frames=120, background_frames=10))
    a, b = r.render(73), r.render(75)
    t = camera_translation(R, np.array([a.along_m, 4.0, a.up_m]), R, np.array([b.along_m, 4.0, b.up_m]))
    wall_px = b.roi_mask > 0
    plain_wall = wall_px & (np.abs(b.image.astype(int) - 150).max(axis=2) <= 3)
    plain_bg = ~wall_px & (np.abs(b.image.astype(int) - 150).max(axis=2) <= 3)
    plain_bg &= cv2.erode(plain_bg.astype(np.uint8), np.ones((9, 9), np.uint8)) > 0  # its inside
    assert plain_wall.mean() > 0.03 and plain_bg.mean() > 0.01
    network = np.where(wall_px & ~plain_wall, 255, 0).astype(np.uint8)  # cuts the plain wall patch ...
    network[plain_bg] = 255  # ... and keeps a plain patch of background
    for rule, expect in ((PlainRule.CONTINUITY, True), (PlainRule.NETWORK, False)):
        par = parallax_depth(a.image, b.image, t, CAM.fx, ParallaxParams(plain_rule=rule))
        fused, dropped = fuse_with_network(network, par)
        assert not dropped
        assert bool((fused[plain_wall] > 0).mean() > 0.9) is expect
        assert bool((fused[plain_bg] == 0).mean() > 0.9) is expect


def test_a_plain_wall_strip_leaving_the_view_is_carried_from_the_last_kept_frame_not_dropped():
    """At the wall's end a plain wall (nothing to track) leaves the view beside a textured background: parallax
    sees only far pixels and drops the frame, though it shows a strip of wall. The last kept frame's mask moved by
    the wall's motion is that strip: the frame is kept with it. Once the wall has left the view the carried strip
    is empty and a background-only frame is still dropped."""

    from companion.depth.parallax import ParallaxParams, carried_wall, keep_wall_in_view, kept_wall

    plain = np.full((600, 1200, 3), 140, np.uint8)
    r = PhotoPassRenderer(PhotoPass("t", PhotoTexture("wall", plain, 12.0), PhotoTexture("bg", _texture(600, 800, 2),
                                                                                         1.0),
                                    camera=CAM, frames=120, background_frames=10))
    pp = ParallaxParams(wall_in_view_rule=True)
    last = r.render(104)
    kept = kept_wall(last.roi_mask, np.array([last.along_m, 4.0, last.up_m]), 4.0, pp)
    for i, leaving in ((107, True), (112, False)):
        f, before = r.render(i), r.render(i - 2)
        assert (f.wall_fraction > 0.02) is leaving
        pos = np.array([f.along_m, 4.0, f.up_m])
        t = camera_translation(R, np.array([before.along_m, 4.0, before.up_m]), R, pos)
        par = parallax_depth(before.image, f.image, t, CAM.fx, pp)
        mask, dropped = fuse_with_network(np.zeros_like(f.roi_mask), par)
        assert dropped  # the rule before: only far pixels are trusted, so the frame goes
        in_view = carried_wall(kept, pos, R, CAM.fx, CAM.width, pp)
        mask, dropped = keep_wall_in_view(mask, dropped, in_view, par, pp)
        assert dropped is not leaving
        if leaving:
            truth = f.roi_mask > 0
            assert ((mask > 0) == truth).mean() > 0.97 and (mask[truth] > 0).mean() > 0.9
    far_back = np.array([last.along_m - 2.0, 4.0, last.up_m])
    assert carried_wall(kept, far_back, R, CAM.fx, CAM.width, pp) is None  # too far to carry a mask
    off = ParallaxParams(wall_in_view_rule=False)
    assert carried_wall(kept, np.array([last.along_m + 0.1, 4.0, last.up_m]), R, CAM.fx, CAM.width, off) is None


def test_the_masker_carries_the_wall_only_with_the_rule_on():
    """SequenceParallax remembers the last kept frame's wall only when the in-view rule is on (the default), and
    then gives it back moved by the camera's motion (the chain's path of the rule the test above checks on its
    own)."""
    import cv2

    from companion.depth.parallax import ParallaxParams, SequenceParallax

    r = PhotoPassRenderer(PhotoPass("t", PhotoTexture("wall", _texture(600, 1200, 1), 12.0),
                                    PhotoTexture("bg", _texture(600, 800, 2), 1.0), camera=CAM, frames=120,
                                    background_frames=10))
    f, g = r.render(104), r.render(107)  # 33 cm apart, the wall's end leaving the view
    off = SequenceParallax(69.0, ParallaxParams(wall_in_view_rule=False))
    off.note_kept(f.roi_mask, _geo_pose(0, f), 4.0)
    assert off.wall_in_view(_geo_pose(1, g), g.roi_mask.shape) is None
    on = SequenceParallax(69.0, ParallaxParams(wall_in_view_rule=True))
    on.note_kept(f.roi_mask, _geo_pose(0, f), 4.0)
    carried = on.wall_in_view(_geo_pose(1, g), g.roi_mask.shape)
    truth = cv2.resize(g.roi_mask, carried.shape[::-1], interpolation=cv2.INTER_NEAREST) > 0
    assert 0.02 < truth.mean() < (f.roi_mask > 0).mean()
    assert (carried & truth).sum() / (carried | truth).sum() > 0.9  # where the wall's end is now


def _biased_geo_pose(i, f, bias_m):
    """The telemetry pose of a photo pass's camera with a constant GNSS bias ``bias_m`` (along, out, up): what a
    non-RTK receiver reports for minutes."""
    import pymap3d

    from companion.records import Pose

    along, out, up = f.along_m + bias_m[0], 4.0 + bias_m[1], f.up_m + bias_m[2]
    lat, lon, alt = pymap3d.enu2geodetic(along, -out, up, 47.0, 8.0, 400.0)
    return Pose(time_s=i * 0.1, lat=lat, lon=lon, alt_amsl_m=alt, relative_alt_m=up, roll_deg=0.0, pitch_deg=0.0,
                yaw_deg=0.0)


@pytest.mark.parametrize("bias_m", [(1.5, 1.5, 0.5), (-1.5, -1.5, -0.5)])
def test_the_chain_keeps_a_sliver_of_wall_at_the_walls_end_under_a_gnss_bias(bias_m):
    """Issue 27: never drop a frame that shows wall. At the wall's end the last frame with wall shows it as a few
    pixel columns at the frame's edge: too little for the flow to measure, so parallax saw only far pixels and
    the chain dropped it (the rule before, ``no-wall-in-view``). The last kept frame's wall moved by the
    telemetry's baseline is still in view there: the frame is kept with that strip. The baseline is a difference of
    two poses, so a GNSS bias of 1.5 m (constant over the seconds between them) changes nothing; the background-only
    frames past the wall's end are still dropped, all but the first, 5 cm past it (the last kept mask reaches a
    few pixels beyond the wall)."""
    from companion.depth.masker import Masker
    from companion.depth.parallax import SequenceParallax
    from companion.records import Frame, TaggedFrame

    r = PhotoPassRenderer(PhotoPass("t", PhotoTexture("wall", _texture(600, 1200, 1), 12.0),
                                    PhotoTexture("bg", _texture(600, 800, 2), 1.0), camera=CAM, frames=250,
                                    background_frames=16))
    masker = Masker("sim", threads=1, parallax=SequenceParallax(CAM.hfov_deg, standoff_m=4.0))
    kept = {}
    for i in range(224, len(r)):
        f = r.render(i)
        masked, _ = masker.mask(TaggedFrame(Frame(i, i * 0.1, f.image), _biased_geo_pose(i, f, bias_m)))
        kept[i] = (f, None if masked is None else masked.mask)
    with_wall = [i for i, (f, _) in kept.items() if f.wall_fraction > 0.0]
    background = [i for i, (f, _) in kept.items() if f.wall_fraction == 0.0]
    sliver, mask = with_wall[-1], kept[with_wall[-1]][1]
    truth = kept[sliver][0].roi_mask > 0
    assert 0.0 < truth.mean() < 0.01 and not truth[:, 16:].any()  # a few columns at the left edge
    assert mask is not None  # the rule before dropped it
    assert (mask[truth] > 0).mean() > 0.9 and not mask[:, 32:].any()  # kept where the wall's end is, no more
    assert all(kept[i][1] is not None for i in with_wall)
    assert len(background) >= 16 and all(kept[i][1] is None for i in background[1:])


def _training_photo_pass(camera: CameraModel):
    """Validation pass ``val-b0169-40`` of bench/depth_error_regions.py (training-split photos: a CMP facade whose
    upper strip ends in a plain white balustrade, a Boston street 40 m behind) at a smaller camera."""
    from companion.depth.training.realdata import facade_mask, list_real_photos, load_image
    from evaluation.shared_data import shared_data_root

    photos = {p.image.name: p for p in list_real_photos(shared_data_root())}
    wall_p, bg_p = photos["cmp_b0169.jpg"], photos["static_boston_street_april__p1010115.jpg"]
    assert wall_p.split == "train" and bg_p.split == "train"  # never a held-out photo in a test of a rule
    wall = PhotoTexture(wall_p.image.name, load_image(wall_p), 14.0, facade_mask(wall_p))
    bg = PhotoTexture(bg_p.image.name, load_image(bg_p), 1.0)
    spec = PhotoPass("val-b0169-40", wall, bg, background_distance_m=40.0, camera=camera, frames=100,
                     background_frames=12, strips_up_m=(0.55 * wall.height_m, 0.88 * wall.height_m))
    return PhotoPassRenderer(spec)


@pytest.mark.skipif(not (Path(__file__).resolve().parents[1].parent / "shared" / "data" / "real-facades").is_dir(),
                    reason="needs ../shared/data/real-facades beside the clone")
def test_a_strip_of_wall_the_flow_calls_far_is_kept_by_the_wall_plane_check():
    """At the end of a strip a balustrade (thin balusters, plain white) fills the bottom of the frame beside a
    street 40 m behind. DIS smooths the street's small motion into it and calls it far with a consistent
    forward-backward flow, so the frame, 10-17 % wall, was dropped as all background (the old rule, kept as
    ``no-plane-check``). Under the wall plane's own motion (f x baseline / standoff) its patches fit and under a
    far motion they do not: it is near and the frame is kept. The background-only frames after it are still
    dropped."""
    import cv2

    from companion.depth.parallax import dense_flow, depth_from_flow
    from evaluation.depth.parallax_rules import PARALLAX_RULES

    cam = CameraModel(width=1920, height=1080, hfov_deg=69.0)  # the pass as the bench renders it
    r = _training_photo_pass(cam)
    for i, has_wall in ((82, True), (97, False)):
        a, b = r.render(i - 1), r.render(i)
        assert (b.wall_fraction > 0.09) is has_wall and (b.wall_fraction == 0.0) is not has_wall
        t = camera_translation(R, np.array([a.along_m, 4.0, a.up_m]), R, np.array([b.along_m, 4.0, b.up_m]))
        no_network = np.zeros_like(b.roi_mask)  # the network reads the balustrade as far too (both models)
        results = {}
        for rule in ("no-plane-check", "default"):
            pp = PARALLAX_RULES[rule]
            par = depth_from_flow(dense_flow(a.image, b.image, pp), t, cam.fx, pp, wall_depth_m=4.0)
            results[rule] = (par, *fuse_with_network(no_network, par))
        old_dropped, (par, mask, dropped) = results["no-plane-check"][2], results["default"]
        if has_wall:
            assert old_dropped  # the rule before: the frame with wall was dropped
            assert not dropped
            truth = cv2.resize(b.roi_mask, par.near.shape[::-1], interpolation=cv2.INTER_NEAREST) > 0
            assert par.near[truth].mean() > 0.5  # the balustrade moves like the wall
            assert (mask[b.roi_mask > 0] > 0).mean() > 0.5
        else:
            assert old_dropped and dropped


def test_plain_sky_above_the_roof_line_joins_the_far_background_it_touches():
    """Plain sky above a wall's top edge has nothing to track. It touches the wall below (near) and a textured
    hillside beside it (far), so the continuity rule leaves it to the network, which keeps it. Grown from the
    trusted pixels over the frame's colours, the far side reaches it across a faint edge (hills in haze) and the
    wall's side stops at the roof line, a strong one: it is cut. A plain patch inside the wall stays wall."""
    from companion.depth.parallax import ParallaxParams, ParallaxResult

    rng = np.random.default_rng(3)
    h, w = 90, 160
    image = np.zeros((h, w, 3), np.uint8)
    image[40:] = np.clip(rng.normal(90, 25, (h - 40, w, 3)), 0, 255).astype(np.uint8)  # textured wall
    image[60:75, 20:50] = (90, 90, 90)  # a plain patch of the wall
    image[:40, :100] = (235, 200, 160)  # plain sky (BGR light blue)
    # distant hills in haze: textured, but their colour runs on into the sky's
    image[:40, 100:] = np.clip(rng.normal((205, 185, 150), 12, (40, w - 100, 3)), 0, 255).astype(np.uint8)
    plain = np.zeros((h, w), bool)
    plain[:40, :100] = True
    plain[60:75, 20:50] = True
    wall = np.zeros((h, w), bool)
    wall[40:] = True
    near, far = wall & ~plain, ~wall & ~plain
    for rule, sky_cut in ((ParallaxParams(), True), (ParallaxParams(plain_watershed_cut=False), False)):
        par = ParallaxResult(np.where(near, 4.0, 100.0).astype(np.float32), near | far, near, far, rule)
        network = np.full((h, w), 255, np.uint8)  # the network keeps everything but the hills
        network[:40, 100:] = 0
        fused, dropped = fuse_with_network(network, par, image=image)
        assert not dropped
        assert bool((fused[:35, :95] == 0).mean() > 0.95) is sky_cut
        assert (fused[62:73, 22:48] > 0).all() and (fused[45:, :] > 0).mean() > 0.97

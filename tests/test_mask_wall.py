"""The shipped mask keeps wall that parallax cannot see, and still drops the background (issues 13/15).

Measured on the real-texture passes (docs/DEPTH.md "Where the sim mask loses wall"): the wall the shipped ``sim``
mask cut in every keyframe was (1) the top 40 % of the first frame of each strip, which no earlier frame lets
parallax judge and the network reads at 20-60 m, and (2) plain bands at the frame's bottom or sides (balcony bases,
plain stone) and plain pilasters hanging from its top, that the network reads as far, parallax cannot track, and
the plain-patch rule left to the network because they touch the frame's border. The bottom and the sides of (2)
are fixed by default; (1) and the top of (2) are named rule sets (``unjudged-paper``, ``borders-top-alone``), off by
default because each kept background on a measured pass (docs/DEPTH.md).
"""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from companion.depth.masker import Masker
from companion.depth.parallax import ParallaxParams, ParallaxResult, PlainRule, SequenceParallax, plain_vote
from companion.records import Frame, Pose, TaggedFrame
from evaluation.depth.parallax_rules import PARALLAX_RULES
from sim.camera.model import CameraModel
from sim.camera.photo_passes import RECIPES, build_pass
from sim.camera.photo_scene import PhotoPassRenderer


def _scene(h: int = 60, w: int = 100):
    """A frame of wall (trusted near everywhere but its plain patches) with three plain patches the network cut:
    a band along the bottom edge, a pilaster hanging from the top edge, and a patch spanning the top-left corner
    (as plain sky above a roof line spans the frame)."""
    near = np.ones((h, w), bool)
    bottom_band = np.zeros((h, w), bool)
    bottom_band[h - 8:, 20:80] = True
    pilaster = np.zeros((h, w), bool)
    pilaster[:25, 45:55] = True
    corner_sky = np.zeros((h, w), bool)
    corner_sky[:12, :30] = True
    plain = bottom_band | pilaster | corner_sky
    near &= ~plain
    far = np.zeros((h, w), bool)
    network = np.where(plain, 0.0, 1.0).astype(np.float32)
    return near, far, network, bottom_band, pilaster, corner_sky


def _vote(params: ParallaxParams, near, far, network) -> np.ndarray:
    par = ParallaxResult(np.full(near.shape, 4.0, np.float32), near | far, near, far, params)
    mask = (network * 255).astype(np.uint8)
    return plain_vote(mask, par)


def _with_background_in_view(near, far):
    """The same frame with a textured background (trusted far) in its right fifth, clear of the plain patches."""
    near, far = near.copy(), far.copy()
    far[:, 84:] = True
    near[:, 84:] = False
    return near, far


def test_plain_bands_at_the_bottom_are_wall_but_patches_at_the_top_stay_the_networks_with_background_in_view():
    near, far, network, bottom_band, pilaster, corner_sky = _scene()
    near, far = _with_background_in_view(near, far)
    vote = _vote(ParallaxParams(plain_rule=PlainRule.CONTINUITY), near, far, network)
    assert (vote[bottom_band] >= 0.5).all(), "a plain band along the bottom edge with only wall around it is wall"
    assert (vote[pilaster] < 0.5).all(), "with background in view a patch touching the top edge is the network's"
    assert (vote[corner_sky] < 0.5).all(), "a plain patch spanning the top and a side (sky) stays the network's"
    before = replace(PARALLAX_RULES["before-borders"], plain_rule=PlainRule.CONTINUITY)
    vote = _vote(before, near, far, network)
    assert (vote[bottom_band | pilaster] < 0.5).all(), "the rule before left every border patch to the network"


def test_with_no_background_in_view_plain_patches_touching_the_top_are_wall():
    """A frame whose trusted pixels are all near shows no background anywhere: a plain patch at the top with only
    wall around it is wall (the mask-top change; the rule before left every patch touching the top to the network,
    and on the real-texture passes that was most of the wall lost: docs/DEPTH.md). A few far pixels (mistracked
    railings, flow noise: under 1 % of the frame) do not count as a background in view."""
    near, far, network, bottom_band, pilaster, corner_sky = _scene()
    vote = _vote(ParallaxParams(plain_rule=PlainRule.CONTINUITY), near, far, network)
    assert (vote[bottom_band | pilaster | corner_sky] >= 0.5).all()
    speck = np.zeros_like(near)
    speck[30:33, 60:63] = True  # 0.15 % of the frame trusted far, away from the patches
    vote = _vote(ParallaxParams(plain_rule=PlainRule.CONTINUITY), near & ~speck, far | speck, network)
    assert (vote[pilaster | corner_sky] >= 0.5).all()
    before = replace(PARALLAX_RULES["before-top"], plain_rule=PlainRule.CONTINUITY)
    vote = _vote(before, near, far, network)
    assert (vote[pilaster | corner_sky] < 0.5).all(), "the rule before left the top to the network"
    assert (vote[bottom_band] >= 0.5).all()


def test_a_speck_of_far_pixels_beside_a_plain_patch_does_not_veto_it_in_a_frame_with_no_background():
    """A window pane reflects the scene behind the camera, which moves like something far: on held-out CMP b0283
    (tests/test_mask_top.py, frame 10) 33 work pixels of one pane (0.1 % of the frame) were trusted far, right
    beside the plain render running out of the frame's top. Their 28 far votes against 190 near ones vetoed that
    patch (more than 5 % dissent), so the network's cut stood and 6 % of an all-wall frame was lost. Which pixels of
    the pane track as far is chance: OpenCV 5.1's warpAffine, one grey level off 5.0's on 3 % of the rendered pixels,
    was enough to make them. A frame that shows no background (at most 1 % trusted far) has none beside its plain
    patches either: far specks the wall encloses do not veto one; far pixels coming in from the frame's border
    (the edge of a background or sky) still do."""
    near, far, network, _, pilaster, _ = _scene()
    speck = np.zeros_like(near)
    speck[25:28, 47:53] = True  # 0.3 % of the frame trusted far, just under the pilaster's lower end
    vote = _vote(ParallaxParams(plain_rule=PlainRule.CONTINUITY), near & ~speck, far | speck, network)
    assert (vote[pilaster] >= 0.5).all(), "a far speck in a frame with no background vetoed a plain wall patch"
    before = replace(PARALLAX_RULES["before-speck"], plain_rule=PlainRule.CONTINUITY)
    vote = _vote(before, near & ~speck, far | speck, network)
    assert (vote[pilaster] < 0.5).all(), "the rule before let the speck veto it"
    edge = np.zeros_like(near)
    edge[:6, 55:58] = True  # as few far pixels, but reaching the frame's top beside the pilaster: the sky's edge
    vote = _vote(ParallaxParams(plain_rule=PlainRule.CONTINUITY), near & ~edge, far | edge, network)
    assert (vote[pilaster] < 0.5).all(), "far pixels coming in from a border still veto"
    near_bg, far_bg = _with_background_in_view(near & ~speck, far | speck)
    vote = _vote(ParallaxParams(plain_rule=PlainRule.CONTINUITY), near_bg, far_bg, network)
    assert (vote[pilaster] < 0.5).all(), "with a background in view the top stays the network's, as before"


def test_the_top_alone_rule_takes_a_pilaster_hanging_from_the_top_but_not_sky_spanning_it():
    near, far, network, bottom_band, pilaster, corner_sky = _scene()
    near, far = _with_background_in_view(near, far)
    vote = _vote(replace(PARALLAX_RULES["borders-top-alone"], plain_rule=PlainRule.CONTINUITY), near, far, network)
    assert (vote[bottom_band | pilaster] >= 0.5).all()
    assert (vote[corner_sky] < 0.5).all()


def test_a_plain_border_patch_with_far_pixels_around_it_stays_cut():
    """Beside the wall's end a plain patch of background at the frame's side has the background's own textured
    (far) pixels around it: the wall rule does not take it."""
    near, far, network, bottom_band, _, _ = _scene()
    ring = np.zeros_like(near)
    ring[near.shape[0] - 12:, 16:84] = True
    ring &= ~bottom_band
    far |= ring
    near &= ~ring
    vote = _vote(ParallaxParams(plain_rule=PlainRule.CONTINUITY), near, far, network)
    assert (vote[bottom_band] < 0.5).all()


CAM = CameraModel(width=640, height=360, hfov_deg=69.0)


@pytest.fixture(scope="module")
def ornate_entry() -> PhotoPassRenderer:
    """The held-out ornate-entry pass (Strecha entry-P10 before Palma at 120 m) at 640 px, 80 frames."""
    spec = build_pass(RECIPES["ornate-entry"], frames=80, background_frames=7)
    return PhotoPassRenderer(replace(spec, camera=CAM))


def _pose(frame, standoff_m: float) -> Pose:
    """The frame's camera as telemetry reports it (exact; the parallax baselines are relative motion)."""
    from evaluation.stitch.synthetic import SyntheticWall, TelemetryErrors, reported_pose, wall_frame

    wall = wall_frame(SyntheticWall(length_m=12.0, height_m=3.0))
    return reported_pose(np.random.default_rng(0), wall, (frame.along_m, standoff_m, frame.up_m, 0.0, 0.0),
                         TelemetryErrors(), frame.index, time_s=frame.index / 10.0)


def _masked(masker: Masker, frame, standoff_m: float):
    return masker.mask(TaggedFrame(Frame(frame.index, frame.index / 10.0, frame.image), _pose(frame, standoff_m)))


@pytest.mark.parametrize("rules, expect_kept", [("unjudged-paper", True), ("default", False)])
def test_first_frame_of_a_real_pass_keeps_the_top_of_its_wall_with_the_unjudged_rule(ornate_entry, rules, expect_kept):
    """The first frame of a strip has no earlier frame to judge it by parallax. The shipped network reads the top
    of this real wall (held out) at 20-60 m and its far cut takes the top 40 % of the frame; this frame is the only
    keyframe that sees the wall's start, so that is a hole in the map. The ``unjudged-paper`` rules keep what no
    depth boundary separates (off by default: the same frame of another pass then keeps the background beside the
    wall's start, docs/DEPTH.md)."""
    frame = ornate_entry.render(0)
    assert frame.wall_fraction == 1.0
    masker = Masker("sim", parallax=SequenceParallax(CAM.hfov_deg, PARALLAX_RULES[rules]))
    masked, roi = _masked(masker, frame, ornate_entry.spec.standoff_m)
    assert masked is not None
    kept = float((roi.mask > 0).mean())
    assert (kept >= 0.95) is expect_kept, f"{rules}: {100 * kept:.1f} % of an all-wall first frame kept"


@pytest.mark.parametrize("rules", ["default", "unjudged-paper"])
def test_background_only_frames_of_the_pass_are_still_dropped(ornate_entry, rules):
    """With the rules that keep more wall, every frame past the wall's end (held-out Palma photo at 120 m) is still
    dropped by the shipped mask, frames masked in capture order with telemetry as onboard."""
    masker = Masker("sim", parallax=SequenceParallax(CAM.hfov_deg, PARALLAX_RULES[rules]))
    dropped, background_only = [], []
    for i in range(62, len(ornate_entry)):
        frame = ornate_entry.render(i)
        masked, _ = _masked(masker, frame, ornate_entry.spec.standoff_m)
        if frame.wall_fraction == 0.0:
            background_only.append(i)
            if masked is None:
                dropped.append(i)
    assert background_only and dropped == background_only


@pytest.mark.parametrize("rules, least, most", [("default", 0.85, 1.0), ("before-borders", 0.0, 0.75)])
def test_balcony_bases_along_the_frames_bottom_are_kept(rules, least, most):
    """CMP b0283 (held out: six floors, iron balconies) on the lower strip: the plain stone of the balcony bases
    along the frame's bottom edge is untrackable, read as far by the network and touches the frame's border; with
    only wall around it, it is now kept (the rule before kept about 60-67 % of the wall in the bottom fifth)."""
    spec = build_pass(RECIPES["cmp-balconies"], frames=80, background_frames=11)
    r = PhotoPassRenderer(replace(spec, camera=CAM))
    masker = Masker("sim", parallax=SequenceParallax(CAM.hfov_deg, PARALLAX_RULES[rules]))
    for i in (9, 10):
        frame = r.render(i)
        masked, roi = _masked(masker, frame, spec.standoff_m)
    wall = frame.roi_mask > 0
    bottom = np.zeros_like(wall)
    bottom[int(0.8 * wall.shape[0]):] = True
    kept = float((roi.mask > 0)[wall & bottom].mean())
    assert least <= kept <= most, f"{rules}: {100 * kept:.1f} % of the bottom fifth's wall kept"


@pytest.mark.parametrize("field, value", [("continuity_speck_veto", "bordr"), ("plain_rule", "continuty"),
                                          ("near_rule", "ratio"), ("plane_drop_rule", "fits"),
                                          ("continuity_wall_borders", "bottom,tops")])
def test_a_misspelt_parallax_rule_is_refused_with_the_names_it_takes(field, value):
    """Each rule is chosen by comparing with one name, so a misspelt one used to act silently as another."""
    from companion.errors import CompanionError

    with pytest.raises(CompanionError, match=field):
        ParallaxParams(**{field: value})
    assert all(isinstance(rules, ParallaxParams) for rules in PARALLAX_RULES.values())


def test_a_parallax_rule_given_by_name_becomes_its_member_and_prints_as_the_name():
    from companion.depth.parallax import Border, SpeckVeto

    named = ParallaxParams(plain_rule="continuity", continuity_speck_veto="every",
                           continuity_wall_borders="bottom, top")
    assert named.plain_rule is PlainRule.CONTINUITY and named.continuity_speck_veto is SpeckVeto.EVERY
    assert named.continuity_wall_borders == {Border.BOTTOM, Border.TOP}
    assert ParallaxParams(continuity_wall_borders="").continuity_wall_borders == frozenset()
    assert ParallaxParams() == ParallaxParams(continuity_wall_borders="bottom,left,right", plain_rule="calibrated")
    assert f"{ParallaxParams().plain_rule}" == "calibrated" and json.dumps(SpeckVeto.BORDER) == '"border"'

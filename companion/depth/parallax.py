"""Geometry where the network is unsure: motion parallax between two frames with a known (telemetry) baseline.

During a scan the camera translates along the wall. A static point at depth Z moves f * |t| / Z pixels between
two frames whose camera centres are t apart (translation across the optical axis): a wall at 4 m moves about 30
times more than a background at 120 m. Dense optical flow (OpenCV's DIS) between the frames, projected on the
direction the baseline predicts, gives Z wherever the image has texture to track. That answer does not depend on
what the network learnt, so it confirms or corrects the network's mask where it is sure, and it is the better
judge of a frame with no near surface at all (every textured pixel moves like the far background).

Limits: it needs a translation (no answer while hovering or at the first frame: the network alone decides);
rotation between the frames is not compensated (the camera is gimballed and the frames are close in time);
plain surfaces have no trackable texture and are left to the network.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass, replace
from enum import StrEnum

import cv2
import numpy as np

from companion.attitude import camera_rotation_enu
from companion.errors import CompanionError


class NearRule(StrEnum):
    """Which trusted pixels are near (``ParallaxParams.near_rule``)."""

    WALL_RATIO = "wall_ratio"
    FIXED = "fixed"


class PlainRule(StrEnum):
    """How plain (untracked) pixels are decided (``ParallaxParams.plain_rule``)."""

    CALIBRATED = "calibrated"
    CONTINUITY = "continuity"
    NETWORK = "network"


class PlaneDropRule(StrEnum):
    """The wall-plane check's evidence that a frame is all background (``ParallaxParams.plane_drop_rule``)."""

    FIT = "fit"
    NEAR = "near"


class SpeckVeto(StrEnum):
    """Which far pixels of a frame with no background in view veto a wall patch
    (``ParallaxParams.continuity_speck_veto``)."""

    BORDER = "border"
    EVERY = "every"
    NONE = "none"


class Border(StrEnum):
    """A frame border a plain patch judged wall may touch (``ParallaxParams.continuity_wall_borders``)."""

    BOTTOM = "bottom"
    LEFT = "left"
    RIGHT = "right"
    TOP = "top"
    TOP_ALONE = "top-alone"  # the top edge alone, not the top and a side


# The rule fields and their choices. Enums, not strings, because every rule is chosen by comparing with one name:
# a misspelt string would silently act as another rule. StrEnum keeps each printed or written value the same text.
_RULE_KINDS: dict[str, type[StrEnum]] = {"near_rule": NearRule, "plain_rule": PlainRule,
                                         "plane_drop_rule": PlaneDropRule, "continuity_speck_veto": SpeckVeto}


@dataclass(frozen=True)
class ParallaxParams:
    # flow is computed at this width (frames are resized, aspect kept). 240 px: on three validation passes built
    # from training-split photos the mask error fell from 480 to 320 to 240 px and flattened below (docs/DEPTH.md);
    # small copies track the wall's motion over the whole 8-60 cm baseline, and the flow costs a quarter
    work_width: int = 240
    max_near_depth_m: float = 15.0  # nearer than this is near surface (the masker's all-background limit)
    # ... or, with the wall's depth known (the standoff), nearer than this many times it where that is farther:
    # 15 m is the 4 m standoff's limit, and a wall 30 m away was all "far" by the flow (only the wall-plane check
    # gave it back, less 9-12 % of a frame under 0.1 m of pose noise). At 4 m 2.5 x 4 = 10 m: unchanged. None:
    # ``max_near_depth_m`` whatever the standoff (the rule before).
    max_near_standoffs: float | None = 2.5
    # Which trusted pixels are near. "wall_ratio": within ``wall_ratio`` x the depth of the wall this frame's own
    # flow measured (the median depth of the nearest trusted pixels that cover ``min_wall_share`` of the frame,
    # when there are that many nearer than ``max_near_depth_m``), and never beyond ``max_near_depth_m``. A
    # background's flow is judged against the wall's, not against a fixed metric limit that hills 40 m behind
    # come within by flow noise.
    # 2.5 as the ROI's near ratio 0.4: windows and recesses a metre or two off the wall are at most ~1.5x farther
    # at a 4 m standoff, a background at 20 m or more 5x. "fixed": nearer than ``max_near_depth_m`` only.
    near_rule: NearRule = NearRule.WALL_RATIO
    wall_ratio: float = 2.5
    min_wall_share: float = 0.05
    # Plain (untracked) pixels: "continuity" labels each connected plain patch by the trusted pixels around it
    # when they agree (at most ``continuity_max_dissent`` of its trusted neighbours disagree): a plain patch
    # enclosed by the wall (no frame border) that the network cut is wall (background cannot show through a
    # wall), and a plain patch the network kept whose trusted neighbours are all far is background. Every other
    # plain pixel keeps the network's answer. "network": every plain pixel keeps the network's answer.
    # "calibrated" (needs the network's depth): first, in a frame where trusted pixels show both the wall and the
    # background (each at least ``calibrate_min_share`` of the frame), the network's depth that best separates
    # them (equal weight to both sides) becomes this frame's near/far split for the plain pixels: the network
    # orders near and far well on real photos but puts the split in the wrong place (a street 40 m behind read
    # at 14 m, inside its 15 m limit). Only where its ordering holds (at most ``calibrate_max_error`` of the
    # trusted pixels on the wrong side). Otherwise, or without the network's depth, "continuity".
    plain_rule: PlainRule = PlainRule.CALIBRATED
    continuity_max_dissent: float = 0.05
    # Which frame borders a plain patch the network cut may touch and still be judged wall by its trusted
    # neighbours (all near). The top is left to the network: plain sky above a roof line touches it with the roof's
    # near pixels below and nothing far. A plain band along the bottom or a side of the frame with only wall around
    # it (balcony bases, a plinth, plain stone at the frame's edge, which the network reads as far) is wall: a
    # background beside the wall shows its own far texture there. No border: the rule before. ``TOP_ALONE``
    # also takes a patch hanging from the top edge alone (a plain pilaster between windows; measured, docs/DEPTH.md:
    # more wall on the held-out passes, but on a validation pass it kept background seen through a hole in the
    # facade hanging from the frame's top, where the flow had called the background near).
    continuity_wall_borders: frozenset[Border] = frozenset({Border.BOTTOM, Border.LEFT, Border.RIGHT})
    # A frame whose trusted pixels show (almost) no far texture (at most this share of the frame is trusted far)
    # gives no sign of a background anywhere: there a plain patch touching the top whose trusted neighbours are all
    # near (plain render between windows running up out of the frame, a plain band beside the balconies, the plain
    # part of the wall photo the network reads at 20-90 m) is judged wall like the other borders. It was the
    # largest error left on the real-texture passes (docs/DEPTH.md "Plain wall running out of the frame's top"):
    # on wall-only frames of the two-strip passes the `sim` network cut 2-17 % of the frame there. The price: plain
    # sky above a roof line in a frame that shows no textured background at all is kept (nothing in the two
    # frames tells it from plain wall). 1 % of the frame: the few far pixels flow noise and mistracked railings
    # give a wall-only frame stay under it, a background beside the wall's end shows far more. None: the top is
    # always left to the network (the rule before).
    continuity_top_max_far_share: float | None = 0.01
    # In such a frame, which of its few far pixels veto a wall patch (more than ``continuity_max_dissent`` of its
    # trusted neighbours far): "every" (the rule before); "border": those of a far region that reaches the frame's
    # border (a background beside the wall's end or above the roof comes in from a border; a window pane reflecting
    # the scene behind the camera, tracked as far, is enclosed by the wall: 0.1 % of a held-out all-wall frame,
    # it vetoed the plain render beside it and 6 % of the frame was lost); "none" (docs/DEPTH.md "A far speck").
    continuity_speck_veto: SpeckVeto = SpeckVeto.BORDER
    calibrate_min_share: float = 0.03
    calibrate_max_error: float = 0.15
    min_texture: float = 6.0  # local gradient magnitude (grey levels per pixel) below which flow is not trusted
    max_fb_error_px: float = 0.6  # forward-backward flow disagreement above which a pixel is not trusted
    min_confident_share: float = 0.15  # a frame judged by parallax needs this share of trusted pixels
    drop_max_near_share: float = 0.01  # ... and at most this share of trusted near pixels to be all background
    # ... and the network keeps at most this share of the frame where parallax cannot see (plain wall, sky)
    drop_max_untrusted_kept: float = 0.10
    min_baseline_m: float = 0.08  # the reference frame is the latest one at least this far from the current
    max_baseline_m: float = 0.6  # beyond this the flow is too large to track reliably: network alone
    # The 8-60 cm window above is for a wall this far away. What DIS must track is the wall's image motion,
    # f x baseline / standoff, so with the standoff known (the mission's) the window scales with standoff / this:
    # sparse stills 13-31 m from the wall, 2-5 m apart, move the wall about as much as 0.3-1.5 m at 4 m (issue 27).
    # At the paper's 4 m nothing changes. None: the fixed window whatever the standoff (the rule before).
    baseline_standoff_m: float | None = 4.0
    # ... and beyond it, with the standoff and the camera's field of view known (the onboard chain, ``companion
    # cull``), a reference up to where the wall's predicted image motion (f x baseline / standoff) is this share of
    # the working width, the flow measured around that motion (``dense_flow(..., prior=...)``, as ``--sequence``
    # does around the dominant motion): stills 3 m apart 13 m out move the wall 40 of 240 px, beyond the scaled
    # window's 1.95 m, and were left to the network alone (issue 27 item 4). 0.3 as ``sequence_max_share``. Only
    # for standoffs beyond ``baseline_standoff_m``: at the paper's 4 m nothing changes. None: the window alone (the
    # rule before).
    telemetry_max_share: float | None = 0.3
    # ``companion mask --sequence`` (no telemetry): where two neighbouring photos' dominant motion (phase
    # correlation of the working copies) exceeds this share of the working width, the flow is measured around it
    # (``dense_flow(..., prior=...)``): DIS's fast preset lost the wall of stills 3 m apart 13 m out (39 of 240 px:
    # 0-5 % of the frame trusted, walls dropped as background). 0.1: about the 60 cm at 4 m the window above
    # allows (26 px), so the passes it was tuned on are unchanged. None: never (the rule before).
    sequence_align_share: float | None = 0.1
    sequence_align_min_response: float = 0.2  # phase correlation peak below this: no dominant motion to trust
    # ... and where the pass's wall moves more than this share of the working width between neighbours (stills 3 m
    # apart 4 m out move it half the frame: aligned or not, parallax made the masks worse than the network alone
    # on the validation passes, 25-29 % -> 57-76 % error), parallax is not used: the network alone decides
    sequence_max_share: float = 0.3
    # ``--sequence``: a photo its own flow would drop as all background is judged again with the wall-plane check
    # at the pass's wall depth (``sequence.PassMotion.wall_depth``): a sliver of wall at the frame's edge is too
    # little for the flow to measure the wall's depth, so the check never ran there. Only in a pass whose wall moves
    # less than ``sequence_align_share`` of the width between neighbours: on the validation passes at 0.5 m it
    # dropped 1 and 0 photos with wall (3 and 8 before) at no cost, but at 3 m spacing 13 m out one
    # background-only photo of six was kept (5 of 6, under the 90 % bar), and on the held-out passes there 16 of 32
    # dropped instead of 31 (seen before this restriction was made: docs/DEPTH.md). False: the rule before.
    sequence_wall_depth: bool = True
    # ``--sequence`` on a pass whose wall needed aligning: each photo's flow is also measured around no motion, for
    # the pixels neither its dominant motion nor the wall's could track (a far background moves a few pixels while
    # the wall fills most of the pair). Off: on the validation passes at 3 m spacing 13 m out it raised the error
    # (val-b0169-40 12.8 -> 13.6 %, val-coruna-120 7.8 -> 8.4 %; docs/DEPTH.md). False: the two motions only.
    sequence_zero_prior: bool = False
    # ``--sequence``: a photo whose pair with the previous photo moves more than this many degrees off the pass's
    # direction (a strip's first photo: its predecessor is the last of the strip before, at another height and
    # the camera flown back), while its pair with the next photo moves along it, is compared with the next photo
    # (as the pass's first photo is). None: always the previous photo (the rule before).
    sequence_break_deg: float | None = 30.0
    # ``--sequence``: the pixels a photo's flow against the previous photo could not trust (the strip that entered
    # the view since, which has nothing to compare with there) are judged against the next photo. False: the
    # previous photo only (the rule before).
    sequence_both_sides: bool = True
    # The chain (``companion cull``, onboard) at a standoff beyond ``baseline_standoff_m``: a frame judged against
    # one reference has no flow in the strip the reference does not show (the strip that entered the view since an
    # earlier frame: a quarter of the frame for stills 5 m apart 13 m out), which the network decided, and on real
    # walls it cut 20-25 % of such keyframes there. Those pixels are judged against a reference on the other side
    # (:func:`fill_untrusted`, as ``sequence_both_sides``): one already kept (the chain may mask a frame after it has
    # seen the next one), else, for a keyframe, the next frame far enough along the baseline, which it waits for
    # (``parallax_first.LaterReference``, the hold of a strip's first keyframe). At the paper's 4 m nothing
    # changes. False: one reference (the rule before).
    telemetry_both_sides: bool = True
    # ... and the second reference decides the mask only in the pixels it newly trusts (the strip), the rest of the
    # frame keeps the mask of the first reference alone (:func:`second_look_in_strip`). Its trusted pixels also
    # feed the frame's plain-pixel rules (the calibrated split, the continuity and the watershed), which then moved
    # the mask far from the strip: on the validation passes at 13 m (stills 2 and 5 m apart) 6 of 218 keyframes with
    # wall lost more than 5 points of it against one reference alone (up to 16), none with this rule
    # (docs/DEPTH.md). False: the filled answer decides the whole frame.
    telemetry_both_sides_strip_only: bool = True
    # ``--sequence``: the pass's scale (f x baseline) is the median of the pairs whose motion is at least this share
    # of the pass's wall motion (the 90th percentile of the pairs' median flow). A pair of background-only photos
    # (past the wall's end) moves a few pixels and, where the network reads the far background as near, measures a
    # scale many times too small; with more such pairs than wall pairs (16 photos past the wall's end, stills 3 m
    # apart 13 m out) their median set the scale and every background was kept as near. None: every pair (the rule
    # before).
    sequence_scale_min_motion: float | None = 0.5
    # No frame is dropped while the wall the last kept frame showed is still in view (issue 27: "never drop a
    # frame that shows wall"): that mask, moved by the wall's image motion between the two camera positions
    # (f x baseline / wall depth; the wall's end is a fixed point on the wall plane), is a strip of wall this frame
    # still shows. Where it covers at least ``wall_in_view_min_share`` of the frame, the frame is kept with that
    # strip (less what trusted parallax calls far) instead of dropped, by parallax or by the network. Only from a
    # kept frame at most ``wall_in_view_max_m`` back. A sliver of wall at the wall's end (under 1 % of the frame,
    # a few pixel columns) gives the flow nothing to measure, so nothing in the frame itself can keep it; the
    # baseline can. It uses only the telemetry's relative motion, never its absolute position: a GNSS bias of
    # 1-2 m, constant over the seconds between the two frames, cancels (the mission's wall projected with the pose
    # cannot decide this: at 4 m its 2-sigma bound covers every background-only frame of the validation passes,
    # all within 0.6 m of the wall's end). Measured on the validation passes (docs/DEPTH.md "A sliver of wall at
    # the wall's end"): frames with wall dropped 1 -> 0 for both models, background-only frames dropped 68 -> 65
    # of 70 (the frame just past the wall's end keeps the few pixels the last kept mask reached beyond the wall).
    # Off before (docs/DEPTH.md, the same section): measured before the wall-plane check, it carried plain sky into
    # every background-only frame of val-montana-40; with today's rules it does not (16 of 18 dropped either way).
    # False: the rule before.
    wall_in_view_rule: bool = True
    wall_in_view_min_share: float = 0.002
    wall_in_view_max_m: float = 1.5
    # the network needs no second opinion on a frame it reads as facade everywhere (no depth boundary) no farther
    # than this many standoffs: the flow is skipped there (the bulk of a scan's frames). None: judge every frame.
    sure_wall_standoffs: float | None = 1.5
    # The wall-plane check (issue 13, frames with wall dropped). DIS's coarse-to-fine flow smooths the large
    # background's small motion into a narrow strip of wall (a balustrade at the end of a strip, a plain wall edge)
    # and calls it far with a consistent forward-backward flow, and the frame is dropped. The wall is a plane at
    # the standoff, so its motion is known: f x baseline / standoff. Each textured pixel's patch (``plane_box``
    # work pixels) is compared under that motion and under a far motion (``plane_far_fractions`` of it: 0 is
    # infinitely far, 0.2 five standoffs); the hypothesis that fits ``plane_margin`` grey levels (mean absolute
    # difference) better wins: a pixel that moves like the wall is near, one that moves like the far background
    # stays far only when the wall's motion does not fit it, and a pixel neither fits clearly is left untrusted.
    # A frame is all background only when at most ``plane_drop_max_near_share`` of it is near (the wall plane's
    # evidence spreads over the patch size at a wall's outline, so a sliver of wall shows as 2-8 % of the frame).
    # Chosen on the validation passes of training-split photos (docs/DEPTH.md). False: DIS alone.
    plane_check: bool = True
    plane_margin: float = 2.0
    plane_box: int = 7
    plane_far_fractions: tuple[float, ...] = (0.0, 0.2)
    # Where the wall moves far (at least ``sequence_align_share`` of the working width: stills metres apart, the
    # flow measured around a prior), two far motions leave a background between them several pixels off both (a
    # background 120 m behind a wall 13 m away moves 5 of the wall's 54 px; 0.2 of it is 11 px), so neither fits
    # and it stays near or untrusted. There the far motions run from 0 to 1 / ``wall_ratio`` of the wall's every
    # ``plane_far_step_px`` pixels. None: the fractions above whatever the motion (the rule before). The demo's
    # frames a few centimetres apart move the wall a few pixels: unchanged.
    plane_far_step_px: float | None = 2.0
    # The wall's motion the check tests is the telemetry's prediction unless the flow's near pixels move more than
    # this many work pixels off it (a pose's noise on sparse stills far from the wall): then their median motion
    # (``wall_motion_for_check``). Off: written for the 0.1 m pose noise on stills 30 m out, whose loss turned out
    # to be the 15 m near limit (``max_near_standoffs``); with 1.0 the demo's keyframe masks at 4 m changed.
    plane_wall_from_flow_px: float | None = None
    plane_drop_max_near_share: float = 0.015
    # "fit": the drop evidence is the share of the frame that moves like the wall AND fits the wall's motion
    # within ``plane_fit_max`` grey levels (a real wall matches up to JPEG noise; a background patch the wall's
    # motion happens to fit better than the far ones rarely fits it closely); "near": the near share above
    plane_drop_rule: PlaneDropRule = PlaneDropRule.FIT
    plane_fit_max: float = 4.0
    plane_drop_max_fit_share: float = 0.0007
    # True: a pixel DIS calls far stays far only where the far motion fits clearly better; False: unless the wall's
    # motion fits clearly better
    plane_far_verified: bool = True
    # True: a textured pixel DIS could not track (forward-backward inconsistent: DIS's coarse-to-fine flow smears the
    # wall's large motion over a background beside it) whose patch fits a far motion clearly better than the
    # wall's, and closely (within ``plane_fit_max``), is far too, not only the pixels DIS itself called far. On the
    # 40 m pass the textured street beside the wall's end was 90 % untracked (DIS gave it 5-13 px of the wall's
    # 14 px against its true 1.4 px) and the network kept it; it is also what shows a frame has background in view
    # (``continuity_top_max_far_share``). False: DIS's far pixels only (the rule before)
    plane_far_untracked: bool = True
    plane_open: int = 3  # morphological opening (work pixels) of the pixels that move like the wall; 1: none
    # Plain pixels the network keeps, cut where a watershed of the frame's colours grown from the trusted near and
    # far pixels gives them to the far side: plain sky or a plain hillside joins the textured background it
    # touches across no edge, while the wall's outline (the roof line) is an edge that stops the far side. Only
    # cuts (a plain strip of wall with only background beside it would be flooded from the far side). Needs the
    # frame (``fuse_with_network(..., image=...)``).
    plain_watershed_cut: bool = True
    # A frame parallax cannot judge (no reference yet: the first frame of a pass, the first after a gap) keeps the
    # network's mask with the ROI's far cut at this ratio instead of ``RoiParams.far_cut_ratio`` (None: unchanged).
    # 0: only what a depth boundary separates is cut (the paper's rule). The far cut is the network's least reliable
    # answer on real walls (the shipped ``sim`` model reads the top 40 % of a real wall at 20-60 m, farther than the
    # real background) and the first keyframe of a strip is the only one that sees the wall's start, so what it cuts
    # is a hole in the map. Off by default (measured, docs/DEPTH.md "Where the sim mask loses wall"): with 0 the maps
    # of the real-texture passes covered 97.6-99.6 % of the seen wall instead of 91.7-94.6 %, but the first frame of
    # a strip also kept all of the background beside the wall's start (18-55 % of it before), and the map of the
    # 40 m pass showed more of it (27 background inliers against 16): nothing on that frame tells the two apart.
    unjudged_far_cut_ratio: float | None = None

    def __post_init__(self) -> None:
        """Each rule becomes its enum member: one given by name (``plain_rule="continuity"``, borders as a comma
        list ``"bottom,left"``) is converted, so the checks compare members, and a misspelt name is refused
        rather than silently acting as another rule."""
        for field, kind in _RULE_KINDS.items():
            value = getattr(self, field)
            if value not in set(kind):
                allowed = tuple(str(m) for m in kind)
                raise CompanionError(f"parallax rule {field}={value!r} is not one of {allowed}",
                                     f"set {field} to one of {', '.join(allowed)}")
            object.__setattr__(self, field, kind(value))
        object.__setattr__(self, "continuity_wall_borders", _borders(self.continuity_wall_borders))


def _borders(borders: str | Iterable[str]) -> frozenset[Border]:
    """``ParallaxParams.continuity_wall_borders`` as a set of :class:`Border` (also from a comma list of names)."""
    names = borders.split(",") if isinstance(borders, str) else borders
    names = {str(b).strip() for b in names if str(b).strip()}
    unknown = names - set(Border)
    if unknown:
        raise CompanionError(f"continuity_wall_borders names unknown borders {sorted(unknown)}",
                             f"use a set of {', '.join(Border)} (or a comma list of them)")
    return frozenset(Border(b) for b in names)


@dataclass(frozen=True)
class ParallaxResult:
    """Per pixel at work resolution: depth from parallax (inf: no motion), trusted, near and far (both trusted)."""

    depth_m: np.ndarray
    trusted: np.ndarray
    near: np.ndarray
    far: np.ndarray
    params: ParallaxParams
    plane_checked: bool = False  # near and far were decided with the wall-plane check
    before_plane: ParallaxResult | None = None  # the same flow without the wall-plane check (for the drop rule)
    wall_fit_share: float = float("nan")  # share of the frame that moves like the wall and fits it closely
    # the answer against the first reference alone, when the pixels it could not trust were judged against a second
    # (the chain beyond 4 m, ``telemetry_both_sides``): the second look then decides only those
    first_reference: ParallaxResult | None = None

    @property
    def trusted_share(self) -> float:
        return float(self.trusted.mean())

    @property
    def all_background(self) -> bool:
        """Enough trusted pixels and (almost) none of them near: the frame shows no near surface."""
        p = self.params
        limit = p.plane_drop_max_near_share if self.plane_checked else p.drop_max_near_share
        return self.trusted_share >= p.min_confident_share and float(self.near.mean()) <= limit


def fill_untrusted(par: ParallaxResult, second: ParallaxResult) -> ParallaxResult:
    """``par`` with the pixels it could not trust decided by ``second`` where that can (near, far, depth); the drop
    evidence stays ``par``'s. Both answers are for the same frame, against two references (an earlier and a
    later frame: the strip that entered the view since the earlier one has no flow there)."""
    use = ~par.trusted & second.trusted
    before = par.before_plane
    if before is not None and second.before_plane is not None:
        b2 = second.before_plane
        before = replace(before, trusted=before.trusted | (use & b2.trusted), near=before.near | (use & b2.near),
                         far=before.far | (use & b2.far), depth_m=np.where(use, b2.depth_m, before.depth_m))
    return replace(par, depth_m=np.where(use, second.depth_m, par.depth_m), trusted=par.trusted | use,
                   near=par.near | (use & second.near), far=par.far | (use & second.far), before_plane=before)


def with_second_reference(par: ParallaxResult, second: ParallaxResult) -> ParallaxResult:
    """The chain's answer for a frame judged against two references (``ParallaxParams.telemetry_both_sides``):
    :func:`fill_untrusted`, remembering ``par`` when the second decides only the strip (``..._strip_only``)."""
    filled = fill_untrusted(par, second)
    return replace(filled, first_reference=par) if par.params.telemetry_both_sides_strip_only else filled


def camera_translation(R_world_from_cam_ref: np.ndarray, pos_ref: np.ndarray, R_world_from_cam_cur: np.ndarray,
                       pos_cur: np.ndarray) -> np.ndarray:
    """Translation of the camera from the reference to the current frame, in the current camera's axes (metres)."""
    del R_world_from_cam_ref  # rotation between the frames is not compensated (see the module notes)
    return np.asarray(R_world_from_cam_cur, float).T @ (np.asarray(pos_cur, float) - np.asarray(pos_ref, float))


def _grey(image: np.ndarray, width: int) -> np.ndarray:
    h, w = image.shape[:2]
    size = (width, max(8, round(h * width / w)))
    g = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) if image.ndim == 3 else image
    return cv2.resize(g, size, interpolation=cv2.INTER_AREA)


@dataclass(frozen=True)
class DenseFlow:
    """Dense flow of the current frame against the reference at work resolution: ``cur(x) ~ ref(x + flow(x))``,
    and where it can be trusted (textured, forward-backward consistent, tracked to a point inside the reference).
    """

    flow: np.ndarray  # H x W x 2, pixels at work resolution
    trusted: np.ndarray  # H x W bool
    work_width: int  # pixels
    frame_width: int  # pixels of the frames the flow was computed from
    ref: np.ndarray | None = None  # the grey working copies the flow was computed from (for the wall-plane check)
    cur: np.ndarray | None = None


def dense_flow(ref_image: np.ndarray, cur_image: np.ndarray, params: ParallaxParams | None = None,
               prior: tuple[int, int] | None = None) -> DenseFlow:
    """DIS optical flow both ways between two frames of the same camera, at ``params.work_width``; ``prior``: a
    shift (work pixels) the flow is measured around (:func:`dense_flow_grey`)."""
    p = params or ParallaxParams()
    if ref_image.shape != cur_image.shape:
        raise CompanionError(f"frames differ in size: {ref_image.shape} vs {cur_image.shape}",
                             "compare frames of the same camera")
    return dense_flow_grey(_grey(ref_image, p.work_width), _grey(cur_image, p.work_width), cur_image.shape[1], p,
                           prior)


def dense_flow_grey(ref: np.ndarray, cur: np.ndarray, frame_width: int,
                    params: ParallaxParams | None = None, prior: tuple[int, int] | None = None) -> DenseFlow:
    """:func:`dense_flow` of two grey working copies (``work_width`` wide) of frames ``frame_width`` wide.

    ``prior`` (whole work pixels, None: none): the reference is first moved by it and DIS measures the rest. DIS's
    fast preset loses a wall moving much more than a tenth of the frame (stills metres apart); moved by the
    pass's dominant motion, what is left for it is small (companion/depth/sequence.py)."""
    p = params or ParallaxParams()
    dx, dy = prior or (0, 0)
    moved = ref if not (dx or dy) else cv2.warpAffine(
        ref, np.float32([[1, 0, dx], [0, 1, dy]]), (ref.shape[1], ref.shape[0]),
        flags=cv2.INTER_NEAREST | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_REPLICATE)  # moved(x) = ref(x + d)
    dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_FAST)
    fwd = dis.calc(cur, moved, None)  # cur(x) ~ ref(x + fwd(x)): a point at depth Z moves by f t / Z
    bwd = dis.calc(moved, cur, None)
    h, w = cur.shape
    xx, yy = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    back = cv2.remap(bwd, xx + fwd[..., 0], yy + fwd[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    fb_err = np.hypot(fwd[..., 0] + back[..., 0], fwd[..., 1] + back[..., 1])
    gx = cv2.Sobel(cur, cv2.CV_32F, 1, 0, ksize=3) / 4.0
    gy = cv2.Sobel(cur, cv2.CV_32F, 0, 1, ksize=3) / 4.0
    texture = cv2.boxFilter(np.hypot(gx, gy), -1, (7, 7))
    fwd[..., 0] += dx
    fwd[..., 1] += dy
    tx, ty = xx + fwd[..., 0], yy + fwd[..., 1]
    inside = (tx >= 0) & (tx <= w - 1) & (ty >= 0) & (ty <= h - 1)  # tracked to a point inside the reference
    trusted = (texture >= p.min_texture) & (fb_err <= p.max_fb_error_px) & inside
    return DenseFlow(fwd, trusted, p.work_width, frame_width, ref, cur)


def _patch_residual(ref: np.ndarray, cur: np.ndarray, dx: float, dy: float, box: int) -> tuple[np.ndarray, np.ndarray]:
    """Mean absolute grey difference over ``box`` x ``box`` patches between ``cur`` and ``ref`` moved by (dx, dy)
    (``cur(x) ~ ref(x + d)``), and where the moved point lies inside ``ref``."""
    moved = cv2.warpAffine(ref, np.float32([[1, 0, dx], [0, 1, dy]]), (cur.shape[1], cur.shape[0]),
                           flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_REPLICATE)
    diff = cv2.absdiff(cur, moved).astype(np.float32)
    h, w = cur.shape
    inside = np.zeros((h, w), bool)
    # a shift within a thousandth of a pixel of whole is whole (telemetry never gives an exact 0: a 1e-6 px
    # vertical shift must not put the whole top row outside the reference)
    tol = 1e-3
    x0, x1 = max(0, int(np.ceil(-dx - tol))), min(w, int(np.floor(w - 1 - dx + tol)) + 1)
    y0, y1 = max(0, int(np.ceil(-dy - tol))), min(h, int(np.floor(h - 1 - dy + tol)) + 1)
    inside[y0:y1, x0:x1] = True
    return cv2.boxFilter(diff, -1, (box, box)), inside


def wall_motion_for_check(flow: DenseFlow, near: np.ndarray, direction: np.ndarray, predicted_px: float,
                          params: ParallaxParams) -> tuple[np.ndarray, float]:
    """(direction, pixels) of the wall's image motion the wall-plane check tests: the telemetry's prediction, or
    where the flow's own near pixels (``min_wall_share`` of the frame at least) move more than
    ``plane_wall_from_flow_px`` off it, their median motion. A pose's noise moves the prediction: 0.1 m on stills
    2 m apart 30 m out puts it a pixel or more off the wall's 12 px, and the check then called 9-12 % of a
    wall-only frame far (untracked plain patches that fit the no-motion hypothesis better than a wrong wall motion)."""
    p = params
    if p.plane_wall_from_flow_px is None or float(near.mean()) < p.min_wall_share:
        return direction, predicted_px
    measured = np.median(flow.flow[near], axis=0)
    size = float(np.hypot(*measured))
    if size <= 1e-3 or float(np.hypot(*(measured - predicted_px * direction))) <= p.plane_wall_from_flow_px:
        return direction, predicted_px
    return measured / size, size


def far_fractions(params: ParallaxParams, wall_flow_px: float) -> tuple[float, ...]:
    """The far motions the wall-plane check tries, as fractions of the wall's (``plane_far_step_px``)."""
    p = params
    if p.plane_far_step_px is None or p.sequence_align_share is None \
            or wall_flow_px < p.sequence_align_share * p.work_width:
        return p.plane_far_fractions
    top = 1.0 / p.wall_ratio
    n = int(np.ceil(top * wall_flow_px / p.plane_far_step_px))
    return tuple(float(v) for v in np.linspace(0.0, top, n + 1)[:-1])  # the last is the near rule's own limit


def wall_plane_check(flow: DenseFlow, direction: np.ndarray, wall_flow_px: float,
                     params: ParallaxParams) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(moves like the wall, moves like the far background, moves like the wall and fits it closely, moves like
    the far background and fits it closely): textured pixels whose patch fits the wall plane's motion
    (``wall_flow_px`` along ``direction``) ``plane_margin`` better than every far motion, the reverse, and the first
    two within ``plane_fit_max``. See ``ParallaxParams.plane_check``."""
    p = params
    ref, cur = flow.ref, flow.cur
    e_wall, inside = _patch_residual(ref, cur, wall_flow_px * direction[0], wall_flow_px * direction[1], p.plane_box)
    e_far = np.min([_patch_residual(ref, cur, a * wall_flow_px * direction[0], a * wall_flow_px * direction[1],
                                    p.plane_box)[0] for a in far_fractions(p, wall_flow_px)], axis=0)
    gx = cv2.Sobel(cur, cv2.CV_32F, 1, 0, ksize=3) / 4.0
    gy = cv2.Sobel(cur, cv2.CV_32F, 0, 1, ksize=3) / 4.0
    textured = cv2.boxFilter(np.hypot(gx, gy), -1, (7, 7)) >= p.min_texture
    like_wall = textured & inside & (e_wall + p.plane_margin < e_far)
    if p.plane_open > 1:  # a wall is a coherent region: single patches a repeated background texture fits go
        like_wall = cv2.morphologyEx(like_wall.astype(np.uint8), cv2.MORPH_OPEN,
                                     np.ones((p.plane_open, p.plane_open), np.uint8)).astype(bool)
    like_far = textured & (e_far + p.plane_margin < e_wall)
    return like_wall, like_far, like_wall & (e_wall < p.plane_fit_max), like_far & (e_far < p.plane_fit_max)


def depth_from_flow(flow: DenseFlow, translation_cam_m: np.ndarray, fx_px: float,
                    params: ParallaxParams | None = None, wall_depth_m: float | None = None) -> ParallaxResult:
    """Depth = f x baseline / (flow along the baseline's image direction); near and far where the flow is trusted.
    ``fx_px`` is the focal length at full frame width. ``wall_depth_m`` (the standoff) enables the wall-plane
    check (``ParallaxParams.plane_check``); without it the wall depth this flow measured is used, if any."""
    p = params or ParallaxParams()
    t = np.asarray(translation_cam_m, float)
    base = float(np.hypot(t[0], t[1]))
    if base <= 1e-6:
        raise CompanionError("no sideways camera motion between the two frames",
                             "use the network alone for hovering frames, or a reference frame further back")
    f = fx_px * flow.work_width / flow.frame_width
    fwd = flow.flow
    direction = np.array([t[0], t[1]]) / base
    along = fwd[..., 0] * direction[0] + fwd[..., 1] * direction[1]
    with np.errstate(divide="ignore"):
        depth = np.where(along > 1e-3, f * base / np.maximum(along, 1e-3), np.inf).astype(np.float32)
    limit = p.max_near_depth_m
    if p.max_near_standoffs is not None and wall_depth_m is not None and np.isfinite(wall_depth_m):
        limit = max(limit, p.max_near_standoffs * float(wall_depth_m))
    near = flow.trusted & (depth < limit)
    k = int(p.min_wall_share * depth.size)
    if p.near_rule == NearRule.WALL_RATIO and k >= 2 and int(near.sum()) >= k:
        # the wall: the nearest trusted pixels covering min_wall_share of the frame (their median depth), so a
        # background that fills most of the frame does not set the scale, and a few mistracked pixels do not
        near_depths = depth[near]
        measured_wall_m = float(np.partition(near_depths, k // 2)[k // 2])
        near &= depth < p.wall_ratio * measured_wall_m
        wall_depth_m = wall_depth_m if wall_depth_m is not None else measured_wall_m
    far = flow.trusted & ~near
    if p.plane_check and flow.ref is not None and flow.cur is not None and wall_depth_m is not None \
            and np.isfinite(wall_depth_m) and wall_depth_m > 0:
        plane_direction, plane_px = wall_motion_for_check(flow, near, direction, f * base / wall_depth_m, p)
        like_wall, like_far, fits_wall, fits_far = wall_plane_check(flow, plane_direction, plane_px, p)
        near_flow, far_flow = near, far
        near = (near & ~like_far) | like_wall
        far = far & (like_far if p.plane_far_verified else ~like_wall)
        if p.plane_far_untracked:
            far |= fits_far & ~flow.trusted
        return ParallaxResult(depth, near | far, near, far, p, plane_checked=True,
                              before_plane=ParallaxResult(depth, flow.trusted, near_flow, far_flow, p),
                              wall_fit_share=float(fits_wall.mean()))
    return ParallaxResult(depth, flow.trusted, near, far, p)


def parallax_depth(ref_image: np.ndarray, cur_image: np.ndarray, translation_cam_m: np.ndarray, fx_px: float,
                   params: ParallaxParams | None = None) -> ParallaxResult:
    """Depth from the parallax of ``cur_image`` against ``ref_image`` (same camera; ``fx_px`` at full width)."""
    t = np.asarray(translation_cam_m, float)
    if float(np.hypot(t[0], t[1])) <= 1e-6:
        raise CompanionError("no sideways camera motion between the two frames",
                             "use the network alone for hovering frames, or a reference frame further back")
    return depth_from_flow(dense_flow(ref_image, cur_image, params), t, fx_px, params)


@dataclass(frozen=True)
class KeptWall:
    """The last kept frame's mask at work resolution, its camera position and its wall's depth."""

    mask: np.ndarray  # bool, work resolution
    position: np.ndarray  # metres, in the frame the translations are measured in
    wall_depth_m: float


def wall_depth_of(parallax: ParallaxResult | None, fallback_m: float) -> float:
    """The wall's depth a frame measured by parallax (median of its trusted near pixels, when they cover
    ``min_wall_share`` of the frame: a few near pixels are as likely mistracked background), else ``fallback_m``
    (the mission's standoff, or the network's)."""
    if parallax is not None and float(parallax.near.mean()) >= parallax.params.min_wall_share:
        return float(np.median(parallax.depth_m[parallax.near]))
    return fallback_m


def wall_still_in_view(kept: KeptWall, translation_cam_m: np.ndarray, fx_work_px: float) -> np.ndarray:
    """The kept frame's wall seen from the current camera: its mask shifted by the wall's image motion
    (a point at depth Z moves by -f t / Z when the camera moves by t); bool at work resolution."""
    t = np.asarray(translation_cam_m, float)
    dx, dy = (-fx_work_px * t[0] / kept.wall_depth_m, -fx_work_px * t[1] / kept.wall_depth_m)
    h, w = kept.mask.shape
    moved = cv2.warpAffine(kept.mask.astype(np.uint8), np.float32([[1, 0, dx], [0, 1, dy]]), (w, h),
                           flags=cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    return moved > 0


def kept_wall(mask: np.ndarray, position: np.ndarray, wall_depth_m: float, params: ParallaxParams) -> KeptWall:
    """A kept frame's final mask (frame size) as a :class:`KeptWall` at work resolution."""
    h, w = mask.shape[:2]
    size = (params.work_width, max(8, round(h * params.work_width / w)))
    small = cv2.resize(mask, size, interpolation=cv2.INTER_NEAREST) > 0
    return KeptWall(small, np.asarray(position, float), float(wall_depth_m))


def carried_wall(kept: KeptWall | None, position: np.ndarray, R_world_from_cam: np.ndarray, fx_px: float,
                 frame_width: int, params: ParallaxParams) -> np.ndarray | None:
    """The last kept frame's wall as the camera at ``position`` must still see it (work resolution), or None
    (rule off, nothing kept yet, or kept more than ``wall_in_view_max_m`` away). ``fx_px`` at full width."""
    if kept is None or not params.wall_in_view_rule:
        return None
    if np.linalg.norm(np.asarray(position, float) - kept.position) > params.wall_in_view_max_m:
        return None
    t = camera_translation(R_world_from_cam, kept.position, R_world_from_cam, position)
    return wall_still_in_view(kept, t, fx_px * params.work_width / frame_width)


def keep_wall_in_view(mask: np.ndarray, dropped: bool, in_view: np.ndarray | None,
                      parallax: ParallaxResult | None, params: ParallaxParams) -> tuple[np.ndarray, bool]:
    """A frame about to be dropped (or left with an empty mask) keeps the strip of wall ``in_view`` predicts,
    less the pixels trusted parallax calls far, when that strip covers ``wall_in_view_min_share``."""
    if not params.wall_in_view_rule or in_view is None or (not dropped and mask.any()):
        return mask, dropped
    strip = in_view & ~parallax.far if parallax is not None and parallax.far.shape == in_view.shape else in_view
    if strip.mean() < params.wall_in_view_min_share:
        return mask, dropped
    h, w = mask.shape[:2]
    full = cv2.resize(strip.astype(np.uint8), (w, h), interpolation=cv2.INTER_NEAREST)
    return np.where(full > 0, 255, 0).astype(np.uint8), False


def _all_background(network_mask: np.ndarray, parallax: ParallaxResult,
                    network_depth_m: np.ndarray | None) -> tuple[bool, np.ndarray]:
    """The drop rule of one parallax result, and the network's plain-pixel vote it used."""
    net = plain_vote(network_mask, parallax, network_depth_m)
    untrusted_kept = float((net[~parallax.trusted] >= 0.5).sum()) / net.size
    return parallax.all_background and untrusted_kept <= parallax.params.drop_max_untrusted_kept, net


def fuse_with_network(network_mask: np.ndarray, parallax: ParallaxResult,
                      network_depth_m: np.ndarray | None = None,
                      image: np.ndarray | None = None) -> tuple[np.ndarray, bool]:
    """The network's mask (uint8 0/255 at frame size) corrected by parallax where parallax is trusted.

    Returns (mask, dropped). A frame whose trusted pixels are (almost) all far is dropped unless the network
    keeps 10 % of the frame where parallax cannot see (with the wall-plane check: and unless the wall's motion
    fits more than a sliver of it); elsewhere trusted near pixels are kept and trusted far pixels cut, smoothed
    over 5 work pixels so single mistracked pixels do not punch holes; untrusted pixels (plain wall, sky) keep the
    network's answer as ``plain_rule`` corrects it, and with ``image`` (the frame) those the watershed gives to the
    far side are cut (``ParallaxParams.plain_watershed_cut``).
    """
    if parallax.first_reference is not None:
        return second_look_in_strip(network_mask, parallax, network_depth_m, image)
    h, w = network_mask.shape[:2]
    # all background: the trusted pixels say so, and what the network keeps is not hiding in untrusted (plain)
    # parts of the frame, such as a plain strip of wall parallax cannot track. With the wall-plane check: the flow
    # alone says so (as before the check) and the wall plane's motion fits at most a sliver of the frame (a strip
    # of wall the flow called far keeps the frame)
    dropped, net = _all_background(network_mask, parallax, network_depth_m)
    if parallax.before_plane is not None:
        pp = parallax.params
        if pp.plane_drop_rule == PlaneDropRule.NEAR:
            evidence = float(parallax.near.mean()) <= pp.plane_drop_max_near_share
        else:
            evidence = parallax.wall_fit_share <= pp.plane_drop_max_fit_share
        dropped = _all_background(network_mask, parallax.before_plane, network_depth_m)[0] and evidence
    if dropped:
        return np.zeros((h, w), np.uint8), True
    if image is not None and parallax.params.plain_watershed_cut:
        net = watershed_cut(net, parallax, image)
    vote = np.where(parallax.near, 1.0, np.where(parallax.far, 0.0, net)).astype(np.float32)
    vote = cv2.medianBlur(vote, 5)
    fused = cv2.resize(vote, (w, h), interpolation=cv2.INTER_LINEAR)
    return np.where(fused >= 0.5, 255, 0).astype(np.uint8), False


def second_look_in_strip(network_mask: np.ndarray, parallax: ParallaxResult,
                         network_depth_m: np.ndarray | None = None,
                         image: np.ndarray | None = None) -> tuple[np.ndarray, bool]:
    """:func:`fuse_with_network` of a frame judged against two references (``parallax.first_reference``: the
    first alone): the mask fused from both in the pixels only the second reference could trust (the strip the
    first does not show, grown by 2 work pixels for the median smoothing), the mask of the first alone elsewhere
    (``ParallaxParams.telemetry_both_sides_strip_only``). Dropped only when both answers drop it."""
    first, first_dropped = fuse_with_network(network_mask, parallax.first_reference, network_depth_m, image)
    both, both_dropped = fuse_with_network(network_mask, replace(parallax, first_reference=None), network_depth_m,
                                           image)
    if first_dropped and both_dropped:
        return first, True
    h, w = network_mask.shape[:2]
    strip = (parallax.trusted & ~parallax.first_reference.trusted).astype(np.uint8)
    strip = cv2.resize(cv2.dilate(strip, np.ones((5, 5), np.uint8)), (w, h), interpolation=cv2.INTER_NEAREST) > 0
    return np.where(strip, both, first).astype(np.uint8), False


def watershed_cut(net: np.ndarray, parallax: ParallaxResult, image: np.ndarray) -> np.ndarray:
    """The 0..1 plain-pixel vote (work resolution) with the untrusted pixels that a watershed of the frame grown
    from the trusted near and far pixels gives to the far side cut (``ParallaxParams.plain_watershed_cut``)."""
    if not parallax.near.any() or not parallax.far.any():
        return net
    ph, pw = parallax.near.shape
    colour = image if image.ndim == 3 else cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
    small = cv2.resize(colour, (pw, ph), interpolation=cv2.INTER_AREA)
    markers = np.zeros((ph, pw), np.int32)
    markers[parallax.near] = 1
    markers[parallax.far] = 2
    cv2.watershed(small, markers)  # every pixel joins the seed it reaches across the weakest edges (-1: ridges)
    return np.where(~parallax.trusted & (markers == 2), 0.0, net).astype(np.float32)


def plain_vote(network_mask: np.ndarray, parallax: ParallaxResult,
               network_depth_m: np.ndarray | None = None) -> np.ndarray:
    """The network's 0..1 vote at work resolution, with its plain (untracked) pixels decided by
    ``params.plain_rule`` (trusted pixels are overridden by parallax afterwards)."""
    ph, pw = parallax.near.shape
    net = cv2.resize(network_mask, (pw, ph), interpolation=cv2.INTER_AREA).astype(np.float32) / 255.0
    rule = parallax.params.plain_rule
    split = None
    if rule == PlainRule.CALIBRATED and network_depth_m is not None:
        depth = cv2.resize(np.asarray(network_depth_m, np.float32), (pw, ph), interpolation=cv2.INTER_LINEAR)
        split = calibrated_split_m(depth, parallax)
        if split is not None:
            net = np.where(parallax.trusted, net, (depth <= split).astype(np.float32))
    if rule in (PlainRule.CONTINUITY, PlainRule.CALIBRATED) and split is None:
        net = plain_by_continuity(net, parallax)
    return net


def calibrated_split_m(network_depth_m: np.ndarray, parallax: ParallaxResult) -> float | None:
    """The network depth (metres) that best separates the trusted near pixels from the trusted far ones (equal
    weight to both sides); None when either side covers less than ``calibrate_min_share`` of the frame or the
    network orders them wrongly on more than ``calibrate_max_error`` of them."""
    p = parallax.params
    near_d = np.sort(network_depth_m[parallax.near].ravel())
    far_d = np.sort(network_depth_m[parallax.far].ravel())
    need = p.calibrate_min_share * network_depth_m.size
    if len(near_d) < need or len(far_d) < need:
        return None
    candidates = np.unique(np.concatenate([near_d, far_d])[:: max(1, (len(near_d) + len(far_d)) // 512)])
    near_wrong = 1.0 - np.searchsorted(near_d, candidates, side="right") / len(near_d)  # near read beyond
    far_wrong = np.searchsorted(far_d, candidates, side="right") / len(far_d)  # far read within
    error = 0.5 * (near_wrong + far_wrong)
    best = int(np.argmin(error))
    if error[best] > p.calibrate_max_error:
        return None
    return float(candidates[best])


def plain_by_continuity(net: np.ndarray, parallax: ParallaxResult) -> np.ndarray:
    """The network's 0..1 vote (work resolution) with plain patches relabelled by the trusted pixels around them.

    Why: parallax sees only textured pixels, and on real facades the network's mistakes are mostly on plain ones
    (a plain stretch of wall read as far, a patch of sky kept). A plain patch the network cut that is enclosed by
    trusted near pixels and touches no frame border is a piece of the wall; a plain patch the network kept whose
    trusted neighbours are (almost) all far is background, unless it runs from the top of the frame to the bottom
    at one side (a plain strip of wall entering or leaving the view has only the background beside it). A cut
    patch with only near neighbours may touch the frame's bottom or sides, or hang from its top edge alone
    (``continuity_wall_borders``: balcony bases, a plinth, a pilaster under the frame's top); one spanning the top
    and a side (sky above a roof line, near pixels below it and nothing far) is left to the network: nothing in
    the two frames says which side of the roof line it belongs to. Except in a frame that shows no background at
    all (``continuity_top_max_far_share``): there every patch touching the top is judged by its neighbours too, and
    a few far pixels enclosed by the wall (a window pane's reflection) veto no wall patch
    (``continuity_speck_veto``): 28 such votes beside a plain patch cost a held-out all-wall frame 6 % of its wall.
    """
    p = parallax.params
    plain = ~parallax.trusted
    if not plain.any() or not parallax.trusted.any():
        return net
    n, labels = cv2.connectedComponents(plain.astype(np.uint8), connectivity=4)
    ring = np.ones((3, 3), np.uint8)
    touches_near = cv2.dilate(parallax.near.astype(np.uint8), ring).astype(bool) & plain
    touches_far = cv2.dilate(parallax.far.astype(np.uint8), ring).astype(bool) & plain
    near_votes = np.bincount(labels[touches_near], minlength=n)
    far_votes = np.bincount(labels[touches_far], minlength=n)
    top, bottom, left, right = (np.zeros(n, bool) for _ in range(4))
    for flag, edge in ((top, labels[0]), (bottom, labels[-1]), (left, labels[:, 0]), (right, labels[:, -1])):
        flag[np.unique(edge)] = True
    allowed = p.continuity_wall_borders
    closed_border = np.zeros(n, bool)  # borders a plain patch judged wall may not touch
    for name, flag in ((Border.BOTTOM, bottom), (Border.LEFT, left), (Border.RIGHT, right)):
        if name not in allowed:
            closed_border |= flag
    # no background in view (``continuity_top_max_far_share``): the top is judged like the other borders
    no_far_in_view = p.continuity_top_max_far_share is not None \
        and float(parallax.far.mean()) <= p.continuity_top_max_far_share
    if Border.TOP not in allowed and not no_far_in_view:
        # TOP_ALONE: a patch hanging from the top edge between near pixels (a plain pilaster under the frame's
        # top) is judged too; one that also reaches a side (sky spanning the frame above a roof line) is not
        closed_border |= top & (left | right) if Border.TOP_ALONE in allowed else top
    # a full-height plain strip at one side of the frame: the wall's end entering or leaving the view (sky touches
    # the top, not the bottom; a background street the bottom, not the top; a plain background filling the frame's
    # height spans from side to side)
    side_strip = top & bottom & (left ^ right)
    kept = np.bincount(labels.ravel(), weights=(net >= 0.5).ravel(), minlength=n)
    size = np.bincount(labels.ravel(), minlength=n)
    votes = np.maximum(near_votes + far_votes, 1)
    # in a frame with no background in view, far pixels the wall encloses (a window pane reflecting the scene behind
    # the camera) are no background either: they do not veto a wall patch (``continuity_speck_veto``)
    dissent = far_votes
    if no_far_in_view and p.continuity_speck_veto != SpeckVeto.EVERY:
        border_only = p.continuity_speck_veto == SpeckVeto.BORDER
        vetoing = _reaching_border(parallax.far) if border_only else np.zeros_like(plain)
        touches_vetoing = cv2.dilate(vetoing.astype(np.uint8), ring).astype(bool) & plain
        dissent = np.bincount(labels[touches_vetoing], minlength=n)
    wall = (near_votes > 0) & (dissent <= p.continuity_max_dissent * votes) & ~closed_border & (kept < size)
    background = (far_votes > 0) & (near_votes <= p.continuity_max_dissent * votes) & (kept > 0) & ~side_strip
    wall[0] = background[0] = False  # label 0: the trusted pixels
    out = net.copy()
    out[wall[labels]] = 1.0
    out[background[labels]] = 0.0
    return out


def _reaching_border(region: np.ndarray) -> np.ndarray:
    """The pixels of ``region`` whose 8-connected part of it reaches the frame's border."""
    n, labels = cv2.connectedComponents(region.astype(np.uint8), connectivity=8)
    reach = np.zeros(n, bool)
    reach[np.unique(np.concatenate([labels[0], labels[-1], labels[:, 0], labels[:, -1]]))] = True
    reach[0] = False
    return reach[labels]


def baseline_window(params: ParallaxParams, standoff_m: float | None,
                    hfov_deg: float | None = None) -> tuple[float, float]:
    """(min, max) baseline in metres for a wall ``standoff_m`` away (``ParallaxParams.baseline_standoff_m``): the
    fixed 8-60 cm without a standoff or with the scaling off. With ``hfov_deg`` too, the max reaches as far as the
    wall's image motion stays within ``telemetry_max_share`` of the working width (:func:`wall_motion_px`)."""
    if params.baseline_standoff_m is None or standoff_m is None or not standoff_m > 0:
        return params.min_baseline_m, params.max_baseline_m
    scale = standoff_m / params.baseline_standoff_m
    low, high = params.min_baseline_m * scale, params.max_baseline_m * scale
    if _aligns(params, standoff_m) and hfov_deg is not None:
        f_work = (params.work_width / 2.0) / np.tan(np.radians(hfov_deg) / 2.0)
        high = max(high, params.telemetry_max_share * params.work_width * standoff_m / f_work)
    return low, high


def judges_both_sides(params: ParallaxParams, standoff_m: float | None) -> bool:
    """Whether the pixels a frame's flow could not trust are judged against a second reference on the other side
    (``ParallaxParams.telemetry_both_sides``): only for a wall farther than the window was made for
    (``baseline_standoff_m``), where frames metres apart bring a strip of new wall into view; at the paper's 4 m
    nothing changes."""
    return params.telemetry_both_sides and params.baseline_standoff_m is not None \
        and standoff_m is not None and standoff_m > params.baseline_standoff_m


def _aligns(params: ParallaxParams, standoff_m: float | None) -> bool:
    """Whether the telemetry window reaches beyond the scaled one (``telemetry_max_share``): only for a wall farther
    than the window was made for (``baseline_standoff_m``), so at the paper's 4 m nothing changes (not measured
    there: a reference a metre back at 4 m stays beyond reach, as before)."""
    return params.telemetry_max_share is not None and params.baseline_standoff_m is not None \
        and standoff_m is not None and standoff_m > params.baseline_standoff_m


def wall_prior(params: ParallaxParams, translation_cam_m: np.ndarray, hfov_deg: float,
               standoff_m: float | None) -> tuple[int, int] | None:
    """The wall's predicted image motion (work pixels, ``cur(x) ~ ref(x + d)``: f x baseline / standoff) when it is
    large enough that DIS should measure around it (``sequence_align_share`` of the width, with
    ``telemetry_max_share`` on); None otherwise."""
    if not _aligns(params, standoff_m) or params.sequence_align_share is None:
        return None
    f_work = (params.work_width / 2.0) / np.tan(np.radians(hfov_deg) / 2.0)
    t = np.asarray(translation_cam_m, float)
    dx, dy = f_work * t[0] / standoff_m, f_work * t[1] / standoff_m
    if np.hypot(dx, dy) < params.sequence_align_share * params.work_width:
        return None
    return round(dx), round(dy)


def dominant_motion_grey(ref: np.ndarray, cur: np.ndarray) -> tuple[float, float, float]:
    """Two grey working copies' dominant image motion (``cur(x) ~ ref(x + d)``) by phase correlation, and the
    correlation peak (near 1: one motion fills the frame)."""
    size = (cur.shape[1], cur.shape[0])
    (dx, dy), response = cv2.phaseCorrelate(cur.astype(np.float32), ref.astype(np.float32),
                                            cv2.createHanningWindow(size, cv2.CV_32F))
    return float(dx), float(dy), float(response)


def motion_prior(motion: tuple[float, float, float], params: ParallaxParams) -> tuple[int, int] | None:
    """A pair's dominant motion (:func:`dominant_motion_grey`) rounded to work pixels when it is large and clear
    enough that DIS should measure around it (``sequence_align_share``, ``sequence_align_min_response``)."""
    if params.sequence_align_share is None:
        return None
    dx, dy, response = motion
    if response < params.sequence_align_min_response or \
            np.hypot(dx, dy) < params.sequence_align_share * params.work_width:
        return None
    return round(dx), round(dy)


def merged_flow(flow_around: Callable[[tuple[int, int]], DenseFlow], candidates: Iterable[tuple[int, int] | None],
                params: ParallaxParams) -> DenseFlow:
    """The flow measured around each candidate motion in turn (None skipped; one within half the align share of a
    kept one skipped too), each pixel taking the first flow that it can trust: a pair may show two motions (the
    wall's and a far background's), and DIS measured around one loses the other."""
    apart = params.sequence_align_share * params.work_width / 2 if params.sequence_align_share else 0.0
    priors: list[tuple[int, int]] = []
    for prior in candidates:
        if prior is not None and (not priors or all(np.hypot(*np.subtract(prior, q)) >= apart for q in priors)):
            priors.append(prior)
    flow = flow_around(priors[0])
    for prior in priors[1:]:
        other = flow_around(prior)
        use = ~flow.trusted & other.trusted
        flow = replace(flow, flow=np.where(use[..., None], other.flow, flow.flow), trusted=flow.trusted | other.trusted)
    return flow


def aligned_flow_grey(ref: np.ndarray, cur: np.ndarray, frame_width: int, params: ParallaxParams,
                      wall: tuple[int, int]) -> DenseFlow:
    """The flow of two grey working copies whose wall moves by ``wall`` (work pixels, predicted from the
    telemetry), measured around each motion the pair may show (:func:`merged_flow`): its dominant one (phase
    correlation, when large enough: the wall's, or the background's where that fills the frame), the wall's, and
    none (a far background moves a few pixels). Around the wall's motion alone the background is lost, and around
    none the wall."""
    own = motion_prior(dominant_motion_grey(ref, cur), params)
    return merged_flow(lambda prior: dense_flow_grey(ref, cur, frame_width, params, prior),
                       (own or (0, 0), wall, (0, 0)), params)


def pick_reference(positions: list[np.ndarray], current: np.ndarray,
                   params: ParallaxParams | None = None, standoff_m: float | None = None,
                   hfov_deg: float | None = None) -> int | None:
    """Index (into ``positions``, oldest first) of the latest earlier camera position at least the window's
    minimum (:func:`baseline_window`) from ``current`` and at most its maximum; None when there is none (hover,
    first frames, stills farther apart than the flow tracks)."""
    low, high = baseline_window(params or ParallaxParams(), standoff_m, hfov_deg)
    for k in range(len(positions) - 1, -1, -1):
        d = float(np.linalg.norm(np.asarray(current, float) - np.asarray(positions[k], float)))
        if d >= low:
            return k if d <= high else None
    return None


def network_is_sure(roi, info, standoff_m: float | None, params: ParallaxParams | None = None) -> bool:
    """True when the network reads the whole frame as facade (no depth boundary) at about the planned standoff.

    Why: two dense flows cost about as much as the network itself, and in the bulk of a scan (the camera filling
    its frame with wall) they only confirm what the network says. Parallax earns its cost where the network cuts
    something (windows read as far, a roof line, the wall's end) or reads the frame as nearly-near (a background
    read at 8-11 m, under the 15 m limit): those frames keep their second opinion. ``roi`` is the network's
    :class:`companion.depth.roi.RoiResult`, ``info`` its model's ``ModelInfo``; without a standoff or a metric
    model every frame is judged.
    """
    p = params or ParallaxParams()
    if p.sure_wall_standoffs is None or standoff_m is None or not info.metric:
        return False
    if roi.empty or not roi.no_boundary or not np.isfinite(roi.roi_mean_disparity):
        return False
    depth = float(info.depth_from_disparity(np.float32(roi.roi_mean_disparity)))
    return depth <= p.sure_wall_standoffs * standoff_m


class SequenceParallax:
    """Parallax for frames arriving in capture order with their telemetry poses (``companion.records.Pose``).

    Keeps grey working copies of the last few frames; each frame to be masked is compared with the latest one at
    least the baseline window's minimum away (``min_baseline_m``, scaled by the standoff: :func:`baseline_window`).
    Returns None (the network alone decides) without a pose, while hovering, or at
    the start of a pass. The onboard chain masks only the frames around a keyframe decision (about two per
    keyframe, a metre apart), so it also shows the masker every frame it tracks (:meth:`remember`, a resize and
    no flow): that is what gives the masked frame a reference a few centimetres back. ``standoff_m`` (the
    mission's) lets the masker skip the flow where the network is sure (:func:`network_is_sure`).
    """

    def __init__(self, hfov_deg: float, params: ParallaxParams | None = None, keep: int = 12,
                 standoff_m: float | None = None):
        if not 1.0 < hfov_deg < 179.0:
            raise CompanionError(f"camera hfov {hfov_deg} deg is out of range", "give the horizontal field of view")
        self.hfov_deg = hfov_deg
        self.params = params or ParallaxParams()
        self.keep = keep
        self.standoff_m = standoff_m
        self._origin: tuple[float, float, float] | None = None
        # (grey copy, ENU, frame shape, capture time s)
        self._history: list[tuple[np.ndarray, np.ndarray, tuple[int, ...], float]] = []
        self._kept: tuple[KeptWall, tuple[int, ...]] | None = None  # the last kept frame's wall, its frame shape
        self.last_answer: ParallaxResult | None = None  # what the last :meth:`update` returned
        # the last answer came from an earlier frame alone and left pixels untrusted that a later frame, on the
        # other side, may judge (``telemetry_both_sides``; the chain holds such a keyframe for one)
        self.last_wants_later = False

    def _enu(self, pose) -> np.ndarray:
        import pymap3d

        if self._origin is None:
            self._origin = (pose.lat, pose.lon, pose.alt_amsl_m)
        return np.array(pymap3d.geodetic2enu(pose.lat, pose.lon, pose.alt_amsl_m, *self._origin), float)

    def note_kept(self, mask: np.ndarray, pose, wall_depth_m: float) -> None:
        """Remember a kept frame's final mask (frame size), where it was taken and its wall's depth."""
        if not self.params.wall_in_view_rule or pose is None or not np.isfinite(wall_depth_m) or wall_depth_m <= 0:
            return
        self._kept = (kept_wall(mask, self._enu(pose), wall_depth_m, self.params), mask.shape[:2])

    def kept_wall_depth_m(self) -> float:
        """The wall depth of the last kept frame (a frame kept by carrying its strip measured none of its own)."""
        return self._kept[0].wall_depth_m if self._kept is not None else float("nan")

    def wall_in_view(self, pose, frame_shape: tuple[int, ...]) -> np.ndarray | None:
        """The last kept frame's wall as this frame must still see it (work resolution), or None."""
        if pose is None or self._kept is None or self._kept[1] != tuple(frame_shape[:2]):
            return None
        yaw, pitch, roll = pose.camera_angles()
        R = camera_rotation_enu(yaw_deg=yaw, pitch_deg=pitch, roll_deg=roll)
        fx = (frame_shape[1] / 2.0) / np.tan(np.radians(self.hfov_deg) / 2.0)
        return carried_wall(self._kept[0], self._enu(pose), R, fx, frame_shape[1], self.params)

    def baseline_window(self) -> tuple[float, float]:
        """The baseline window (metres) for this pass's standoff (:func:`baseline_window`)."""
        return baseline_window(self.params, self.standoff_m, self.hfov_deg)

    def remember(self, image: np.ndarray, pose) -> None:
        """Keep a frame as a possible reference without judging it (frames closer than a quarter of the minimum
        baseline to the last one kept add nothing and are skipped)."""
        if pose is None:
            return
        pos = self._enu(pose)
        if self._history and np.linalg.norm(pos - self._history[-1][1]) < self.baseline_window()[0] / 4:
            return
        self._push(_grey(image, self.params.work_width), pos, image.shape, pose.time_s)

    def _push(self, grey: np.ndarray, pos: np.ndarray, shape: tuple[int, ...], time_s: float) -> None:
        self._history = (self._history + [(grey, pos, shape, time_s)])[-self.keep:]

    def update(self, image: np.ndarray, pose) -> ParallaxResult | None:
        """Judge a frame against the latest reference far enough back, then keep it as a reference too. Beyond the
        4 m standoff (``telemetry_both_sides``), the pixels that flow could not trust are judged against a
        reference on the other side of the frame when one is kept (:meth:`_other_side`: the chain may mask a frame
        after it has seen the next one)."""
        self.last_wants_later = False
        if pose is None:
            return None
        pos = self._enu(pose)
        grey = _grey(image, self.params.work_width)
        k = pick_reference([h[1] for h in self._history], pos, self.params, self.standoff_m, self.hfov_deg)
        result = None
        if k is not None and self._history[k][2] == image.shape:
            result = self._against(k, grey, pos, pose, image.shape)
            if result is not None and judges_both_sides(self.params, self.standoff_m) \
                    and not bool(result.trusted.all()):
                other = self._other_side(k, pos, image.shape)
                second = None if other is None else self._against(other, grey, pos, pose, image.shape)
                if second is not None:
                    result = with_second_reference(result, second)
                else:
                    self.last_wants_later = self._history[k][3] < pose.time_s
        self._push(grey, pos, image.shape, pose.time_s)
        self.last_answer = result
        return result

    def _against(self, k: int, grey: np.ndarray, pos: np.ndarray, pose,
                 shape: tuple[int, ...]) -> ParallaxResult | None:
        """The parallax of a frame (its grey working copy, position and pose) against kept reference ``k``."""
        yaw, pitch, roll = pose.camera_angles()  # the gimbal holds the camera level
        R = camera_rotation_enu(yaw_deg=yaw, pitch_deg=pitch, roll_deg=roll)
        t = camera_translation(R, self._history[k][1], R, pos)
        if np.hypot(t[0], t[1]) <= 1e-6:
            return None
        fx = (shape[1] / 2.0) / np.tan(np.radians(self.hfov_deg) / 2.0)
        prior = wall_prior(self.params, t, self.hfov_deg, self.standoff_m)
        flow = dense_flow_grey(self._history[k][0], grey, shape[1], self.params) if prior is None \
            else aligned_flow_grey(self._history[k][0], grey, shape[1], self.params, prior)
        return depth_from_flow(flow, t, fx, self.params, self.standoff_m)

    def _other_side(self, k: int, pos: np.ndarray, shape: tuple[int, ...]) -> int | None:
        """The latest kept reference within the baseline window on the other side of ``pos`` from reference ``k``
        (the frame between them: what entered the view since one of them, the other shows); None when none is kept."""
        low, high = self.baseline_window()
        towards_k = self._history[k][1] - pos
        for j in range(len(self._history) - 1, -1, -1):
            grey, q, frame_shape, _ = self._history[j]
            d = float(np.linalg.norm(q - pos))
            if j != k and frame_shape == shape and low <= d <= high and float(np.dot(q - pos, towards_k)) < 0:
                return j
        return None

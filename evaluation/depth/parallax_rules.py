"""Named parallax rule sets, so an evaluation can compare them side by side on the same frames
(bench/depth_real_passes.py, bench/mask_wall_coverage.py, the mask tests): the product's default and the rule sets
each change to the parallax rules was measured against. The product only ever uses ``ParallaxParams()``.
"""

from __future__ import annotations

from companion.depth.parallax import Border, NearRule, ParallaxParams, PlainRule, PlaneDropRule, SpeckVeto

# the mask-top change's two rules switched off: the rule sets named before it compare as they were measured
# ... and the last kept frame's wall carried into a frame about to be dropped (``wall_in_view_rule``), off when
# every rule set below was measured
_BEFORE_TOP = {"continuity_top_max_far_share": None, "plane_far_untracked": False, "wall_in_view_rule": False}
# the default borders and a plain patch hanging from the frame's top edge alone
_TOP_ALONE = frozenset({Border.BOTTOM, Border.LEFT, Border.RIGHT, Border.TOP_ALONE})
PARALLAX_RULES: dict[str, ParallaxParams] = {
    "default": ParallaxParams(),
    # the rules before issue 13's diagnosis: trusted pixels nearer than 15 m are near, plain pixels keep the
    # network's answer
    "fixed-15m": ParallaxParams(near_rule=NearRule.FIXED, plain_rule=PlainRule.NETWORK, plane_check=False,
                                plain_watershed_cut=False, **_BEFORE_TOP),
    # the rules before the wall-plane check (DIS alone decides which textured pixels are near and far)
    "no-plane-check": ParallaxParams(plane_check=False, plain_watershed_cut=False, **_BEFORE_TOP),
    # the wall-plane check without the watershed cut of plain background
    "no-watershed": ParallaxParams(plain_watershed_cut=False, **_BEFORE_TOP),
    # the wall-plane check's first drop rule: at most 1.5 % of the frame near after the check
    "near-drop": ParallaxParams(plane_drop_rule=PlaneDropRule.NEAR, **_BEFORE_TOP),
    # the rules before the mask-wall change: a plain patch touching any frame border keeps the network's answer
    "before-borders": ParallaxParams(continuity_wall_borders=frozenset(), **_BEFORE_TOP),
    # the rules before the mask-top change: a plain patch touching the frame's top always keeps the network's
    # answer, and only pixels DIS itself calls far are far
    "before-top": ParallaxParams(**_BEFORE_TOP),
    # the rules before far specks enclosed by the wall stopped vetoing wall patches where no background is in view
    "before-speck": ParallaxParams(continuity_speck_veto=SpeckVeto.EVERY, wall_in_view_rule=False),
    # ... and no far pixel of such a frame vetoing one (measured, docs/DEPTH.md "A far speck": more background kept)
    "speck-none": ParallaxParams(continuity_speck_veto=SpeckVeto.NONE, wall_in_view_rule=False),
    # a frame parallax cannot judge (a strip's first) keeps what no depth boundary separates: more wall, and the
    # background beside the wall's start with it (docs/DEPTH.md; measured with the top-alone border rule)
    "unjudged-paper": ParallaxParams(unjudged_far_cut_ratio=0.0, continuity_wall_borders=_TOP_ALONE, **_BEFORE_TOP),
    # plain patches hanging from the frame's top edge alone judged by their neighbours too (docs/DEPTH.md)
    "borders-top-alone": ParallaxParams(continuity_wall_borders=_TOP_ALONE, **_BEFORE_TOP),
    # the rules before issue 27's "never drop a frame that shows wall": a frame parallax or the network drops is
    # dropped even while the last kept frame's wall must still be in view (a sliver at the wall's end)
    "no-wall-in-view": ParallaxParams(wall_in_view_rule=False),
}

"""Named ROI rule sets, so an evaluation can compare them side by side on the same disparity
(bench/depth_real_passes.py): the product's default and the rule sets it was chosen against. The product only
ever uses ``RoiParams()`` (or a mission's own settings).
"""

from __future__ import annotations

from companion.depth.roi import RoiParams

ROI_RULES: dict[str, RoiParams] = {
    "default": RoiParams(),  # near 0.4, far cut 0.4: keep what is within 2.5x the facade's distance
    "sim-0.6-0.5": RoiParams(near_ratio=0.6, far_cut_ratio=0.5),  # the rules chosen on the simulator alone
    "paper": RoiParams(far_cut_ratio=0.0),  # the paper's regions only, no far cut
    # the default plus a per-pixel metric cut at the masker's depth limit (metric models), frame dropped under 1 %
    "metric": RoiParams(pixel_depth_cut=True, min_roi_fraction=0.01),
    # depth alone (metric models): every region kept, only the per-pixel cut at the depth limit
    "metric-only": RoiParams(near_ratio=0.01, far_cut_ratio=0.0, pixel_depth_cut=True, min_roi_fraction=0.01),
}

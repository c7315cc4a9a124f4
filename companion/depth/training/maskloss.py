"""The near/far mask loss: a hinge on the predicted disparity that scores the ROI decision made at inference.

Why: the scale-invariant depth loss scores metres everywhere alike, but the masker only asks one question of the
network per pixel: is it within the keep range of the facade (``companion.depth.roi``'s far cut: disparity at
least ``far_cut_ratio`` x the facade's 95th percentile) or beyond it, and is the nearest surface nearer than the
masker's depth limit (15 m, else the frame is dropped as all background). Continuing the real-photo model with the
depth loss alone kept lowering that loss while it lost the plain wall and the windows of held-out photos
(docs/DEPTH.md). This loss scores exactly those decisions, on every sample with a facade mask:

- facade pixels are penalised when predicted beyond the keep threshold (``ratio * margin`` x the predicted
  facade reference) and, in frames with facade, when predicted beyond the depth limit / margin;
- background pixels are penalised when predicted inside the cut (above ``ratio / margin`` x the reference);
- in frames with no facade at all, background pixels are penalised when predicted nearer than the depth limit x
  margin (the masker must drop such a frame).

Only pixels whose *true* depth is clearly on their side (by the same margin) are scored, so the hinge never asks
for something the true depth contradicts (a window recess 1 m behind the wall, the ground beside the wall's foot).
The hinge is on log disparity, so a pixel read twice too far costs log 2 whatever the scale. The reference is the
prediction's own 95th percentile over the facade (as at inference), taken as a constant for the gradient: the loss
moves the pixels to the right side of the threshold, not the threshold.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from companion.depth.roi import RoiParams

# The masker's default depth limit (companion.depth.masker.Masker(max_roi_depth_m=15.0)): a frame whose kept part
# is farther on average is dropped as all background. A test checks that the two agree.
MASKER_DEPTH_LIMIT_M = 15.0
REFERENCE_QUANTILE = 0.95  # roi.py's far cut judges against the kept side's 95th percentile
MIN_FACADE_PIXELS = 50  # fewer facade pixels than this in a crop: no reliable reference, judged as no facade


@dataclass(frozen=True)
class MaskLossParams:
    """The ROI rule the hinge scores, and its margin (a factor on disparity, > 1)."""

    keep_ratio: float = RoiParams().far_cut_ratio
    margin: float = 1.25
    depth_limit_m: float = MASKER_DEPTH_LIMIT_M
    min_depth: float = 0.1
    max_depth: float = 100.0

    def sigmoid_disparity(self, depth: torch.Tensor | float) -> torch.Tensor | float:
        """The network's sigmoid output for a depth in metres (the inverse of Monodepth2's disp_to_depth): the
        quantity roi.py's ratios are taken on."""
        min_disp, max_disp = 1.0 / self.max_depth, 1.0 / self.min_depth
        return (1.0 / depth - min_disp) / (max_disp - min_disp)


def _hinge_mean(values: torch.Tensor) -> torch.Tensor:
    return values.clamp(min=0).mean() if values.numel() else values.new_zeros(())


def mask_hinge_loss(
    disp: torch.Tensor, depth_gt: torch.Tensor, facade: torch.Tensor, params: MaskLossParams = MaskLossParams()
) -> torch.Tensor:
    """Mean over the batch of the per-image hinge (see the module docstring).

    ``disp``: B x 1 x H x W sigmoid disparity (the network output, at the size of the truth); ``depth_gt``: true
    depth in metres, same shape; ``facade``: bool, same shape (True = facade in the truth mask)."""
    if disp.shape != depth_gt.shape or disp.shape != facade.shape:
        raise ValueError(f"shapes differ: disparity {tuple(disp.shape)}, depth {tuple(depth_gt.shape)}, "
                         f"facade {tuple(facade.shape)}")
    log_disp = torch.log(disp.clamp(min=1e-6))
    true_disp = params.sigmoid_disparity(depth_gt.clamp(params.min_depth, params.max_depth))
    limit = float(params.sigmoid_disparity(params.depth_limit_m))
    m = params.margin
    losses = []
    for b in range(disp.shape[0]):
        f, ld, td = facade[b], log_disp[b], true_disp[b]
        if int(f.sum()) >= MIN_FACADE_PIXELS:
            ref_pred = torch.quantile(disp[b][f].detach(), REFERENCE_QUANTILE)
            ref_true = torch.quantile(td[f], REFERENCE_QUANTILE)
            keep = f & (td >= params.keep_ratio * m * ref_true)
            far = ~f & (td <= params.keep_ratio / m * ref_true)
            keep_log = torch.log(params.keep_ratio * m * ref_pred.clamp(min=1e-6))
            cut_log = torch.log(params.keep_ratio / m * ref_pred.clamp(min=1e-6))
            near_limit = f & (td >= limit * m)
            loss = (_hinge_mean(keep_log - ld[keep]) + _hinge_mean(ld[far] - cut_log)
                    + _hinge_mean(math.log(limit * m) - ld[near_limit]))
        else:
            beyond = ~f & (td <= limit / m)
            loss = _hinge_mean(ld[beyond] - math.log(limit / m))
        losses.append(loss)
    return torch.stack(losses).mean()

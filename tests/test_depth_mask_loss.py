"""The near/far mask loss (companion.depth.training.maskloss): it scores the ROI decision of roi.py, with the right
sign on each side, only where the truth is clearly on one side, and its gradient moves pixels the right way."""

from __future__ import annotations

import inspect
import math

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from companion.depth.masker import Masker  # noqa: E402
from companion.depth.roi import RoiParams, extract_roi  # noqa: E402
from companion.depth.training.maskloss import (  # noqa: E402
    MASKER_DEPTH_LIMIT_M,
    MaskLossParams,
    mask_hinge_loss,
)

P = MaskLossParams()
H, W = 32, 64


def _scene(wall_depth: float = 4.0, background_depth: float = 120.0):
    """Left half wall at ``wall_depth``, right half background; returns (true depth, facade) as 1x1xHxW tensors."""
    facade = torch.zeros(1, 1, H, W, dtype=torch.bool)
    facade[..., : W // 2] = True
    depth = torch.where(facade, torch.tensor(wall_depth), torch.tensor(background_depth))
    return depth, facade


def _disp(depth: torch.Tensor) -> torch.Tensor:
    return P.sigmoid_disparity(depth).float()


def test_params_follow_the_inference_rules():
    assert P.keep_ratio == RoiParams().far_cut_ratio
    assert inspect.signature(Masker.__init__).parameters["max_roi_depth_m"].default == MASKER_DEPTH_LIMIT_M


def test_true_depth_costs_nothing():
    depth, facade = _scene()
    assert float(mask_hinge_loss(_disp(depth), depth, facade)) == 0.0


def test_facade_read_far_is_penalised_and_background_read_near_is_penalised():
    depth, facade = _scene()
    ok = _disp(depth)
    wall_far = ok.clone()
    wall_far[..., : W // 4] = float(P.sigmoid_disparity(40.0))  # half the wall read at 40 m: the ROI would cut it
    bg_near = ok.clone()
    bg_near[..., W // 2 :] = float(P.sigmoid_disparity(5.0))  # background read at 5 m: the ROI would keep it
    assert float(mask_hinge_loss(wall_far, depth, facade)) > 0.1
    assert float(mask_hinge_loss(bg_near, depth, facade)) > 0.1
    # and the ROI step indeed gets these wrong, while the truth-like disparity is masked right
    truth = facade[0, 0].numpy()
    assert (extract_roi(ok[0, 0].numpy()).mask > 0).tolist() == truth.tolist()
    assert (extract_roi(bg_near[0, 0].numpy()).mask > 0)[:, W // 2 :].mean() > 0.9


def test_gradient_moves_facade_nearer_and_background_farther():
    """Descending the loss must raise the disparity of far-read facade and lower that of near-read background;
    a sign error in either hinge fails here."""
    depth, facade = _scene()
    disp = _disp(depth)
    disp[..., :4] = float(P.sigmoid_disparity(40.0))  # a strip of wall read far
    disp[..., -4:] = float(P.sigmoid_disparity(5.0))  # a strip of background read near
    disp.requires_grad_(True)
    mask_hinge_loss(disp, depth, facade).backward()
    g = disp.grad[0, 0]
    assert (g[:, :4] < 0).all()  # gradient descent raises these disparities (nearer)
    assert (g[:, -4:] > 0).all()  # and lowers these (farther)
    assert (g[:, 8 : W // 2 - 4] == 0).all() and (g[:, W // 2 + 4 : -8] == 0).all()  # right pixels untouched


def test_margin_scores_pixels_just_inside_the_threshold():
    depth, facade = _scene()
    disp = _disp(depth)
    ref = float(disp[facade].max())
    disp[..., W // 2 :] = ref * P.keep_ratio * 0.95  # background just beyond the cut: ROI right, margin not met
    loss = float(mask_hinge_loss(disp, depth, facade))
    assert loss == pytest.approx(math.log(0.95 * P.margin), rel=0.05)
    wide = float(mask_hinge_loss(disp, depth, facade, MaskLossParams(margin=1.01)))
    assert wide == 0.0


def test_no_facade_frame_must_be_beyond_the_depth_limit():
    depth = torch.full((1, 1, H, W), 120.0)
    facade = torch.zeros_like(depth, dtype=torch.bool)
    assert float(mask_hinge_loss(_disp(depth), depth, facade)) == 0.0
    near = torch.full_like(depth, float(P.sigmoid_disparity(10.0)))  # all background read at 10 m: kept
    assert float(mask_hinge_loss(near, depth, facade)) == pytest.approx(
        math.log(float(P.sigmoid_disparity(10.0)) / (float(P.sigmoid_disparity(15.0)) / P.margin)), rel=1e-4)


def test_truth_that_is_not_clearly_far_is_not_scored():
    """Ground or a recess beside the wall (non-facade in the mask, but truly near) is left to the depth loss."""
    depth, facade = _scene(background_depth=6.0)  # 'background' only 1.5x the wall's distance
    disp = _disp(depth)
    disp[..., W // 2 :] = float(P.sigmoid_disparity(4.0))
    assert float(mask_hinge_loss(disp, depth, facade)) == 0.0


def test_batch_is_the_mean_of_images_and_shapes_are_checked():
    depth, facade = _scene()
    good = _disp(depth)
    bad = good.clone()
    bad[..., : W // 2] = float(P.sigmoid_disparity(60.0))
    one = float(mask_hinge_loss(bad, depth, facade))
    both = float(mask_hinge_loss(torch.cat([good, bad]), torch.cat([depth, depth]), torch.cat([facade, facade])))
    assert both == pytest.approx(one / 2)
    with pytest.raises(ValueError, match="shapes differ"):
        mask_hinge_loss(good[..., :10], depth, facade)


def test_training_loss_adds_the_hinge_only_with_a_weight(tmp_path):
    from companion.depth.training.config import TrainConfig
    from companion.depth.training.train import total_loss

    depth, facade = _scene()
    disp = _disp(depth)
    disp[..., : W // 2] = float(P.sigmoid_disparity(60.0))  # wall read far
    outputs = {("disp", s): torch.nn.functional.interpolate(disp, scale_factor=0.5**s) for s in range(4)}
    x = torch.rand(1, 3, H, W, generator=torch.Generator().manual_seed(0))
    off = TrainConfig(out=tmp_path, recordings=[])
    on = TrainConfig(out=tmp_path, recordings=[], mask_loss_weight=1.0)
    base = float(total_loss(outputs, x, depth, off, facade))
    assert float(total_loss(outputs, x, depth, on, None)) == pytest.approx(base)
    assert float(total_loss(outputs, x, depth, on, facade)) > base + 0.5
    assert np.isfinite(base)


@pytest.mark.parametrize("flags", [["--mask-loss-weight", "-1"], ["--mask-margin", "0.8"]])
def test_train_command_refuses_a_bad_mask_loss_setting(tmp_path, capsys, flags):
    from companion.cli import main

    rc = main(["depth", "train", "--out", str(tmp_path / "run"), "--view-seeds", "0", *flags])
    assert rc != 0
    err = capsys.readouterr().err
    assert "out of range" in err and "margin >= 1" in err
    assert not (tmp_path / "run").exists()  # refused before anything was written or rendered

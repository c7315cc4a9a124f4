"""Trainable torch weights from a shipped Monodepth2 ONNX file, so that a fine-tune can start from the shipped model.

The shipped model's training runs (their ``checkpoint.pt``) are not kept in the repository; its ONNX file is. The
exporter folds every encoder BatchNorm into the convolution before it (W' = W * g / sqrt(v + eps), b' = the rest),
and keeps only the full-resolution disparity head. To train again we undo that:

* decoder convolutions carry their module names in the ONNX file and load as they are;
* encoder convolutions are anonymous: they are matched to the torch encoder's convolutions in execution order
  (the exporter traces the forward pass, so its Conv nodes come in that order) and checked by shape;
* each folded BatchNorm is rebuilt so that the network in eval mode is exactly the ONNX network, and in train
  mode (batch statistics) nearly so: its running mean and variance are set to the statistics of the folded
  convolution's output on calibration images, with weight sqrt(v + eps) and bias mean + b', which gives
  BN(W'x) = W'x + b' in eval mode;
* the three coarse disparity heads (used only by the multi-scale training loss) are not in the file; they start
  fresh, and ``fit_missing_heads`` trains them alone for a few steps so that their first gradients do not
  disturb the decoder.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from companion.depth.training.networks import Monodepth2
from companion.errors import CompanionError

ONNX_HEAD_SCALE = 0  # the only disparity head in an exported file


def _bn_name(conv_name: str) -> str:
    if conv_name.endswith("downsample.0"):
        return conv_name[: -len("0")] + "1"
    head, _, tail = conv_name.rpartition("conv")
    return head + "bn" + tail


def _encoder_convs_in_order(model: Monodepth2, height: int, width: int) -> list[tuple[str, torch.nn.Conv2d]]:
    names = {m: n for n, m in model.encoder.named_modules() if isinstance(m, torch.nn.Conv2d)}
    order: list[tuple[str, torch.nn.Conv2d]] = []
    hooks = [m.register_forward_hook(lambda mod, i, o: order.append((names[mod], mod))) for m in names]
    with torch.no_grad():
        model.encoder(torch.zeros(1, 3, height, width))
    for h in hooks:
        h.remove()
    return order


def model_from_onnx(path: str | Path, calibration: torch.Tensor | None = None) -> Monodepth2:
    """A Monodepth2 torch model with the ONNX file's weights (eval-mode output identical to the file's).

    ``calibration``: N x 3 x H x W images in [0, 1] whose encoder statistics rebuild the BatchNorm layers for
    training; without it the BatchNorms are identities around the folded weights (exact in eval mode only).
    """
    import onnx
    from onnx import numpy_helper

    path = Path(path)
    try:
        proto = onnx.load(str(path))
    except Exception as exc:  # onnx raises several types for a missing or corrupt file
        raise CompanionError(f"cannot read ONNX model {path}: {exc}", "pass a Monodepth2 .onnx file") from exc
    meta = {p.key: p.value for p in proto.metadata_props}
    if meta.get("format") != "monodepth2" or "encoder_width" not in meta:
        raise CompanionError(f"{path} is not a companion Monodepth2 export (metadata format/encoder_width missing)",
                             "start from a model written by companion depth train / average / export")
    height, width = int(meta["input_height"]), int(meta["input_width"])
    model = Monodepth2(width=float(meta["encoder_width"]))
    inits = {t.name: torch.from_numpy(numpy_helper.to_array(t).copy()) for t in proto.graph.initializer}

    decoder_sd = model.depth.state_dict()
    for key in decoder_sd:
        name = f"depth.{key}"
        if name in inits:
            decoder_sd[key] = inits[name].reshape(decoder_sd[key].shape)
    model.depth.load_state_dict(decoder_sd)

    convs = [n for n in proto.graph.node if n.op_type == "Conv" and not n.input[1].startswith("depth.")]
    order = _encoder_convs_in_order(model, height, width)
    if len(convs) != len(order):
        raise CompanionError(f"{path} has {len(convs)} encoder convolutions, the model {len(order)}",
                             "start from a Monodepth2 ResNet-18 export of the same layout")
    folded_bias: dict[str, torch.Tensor] = {}
    modules = dict(model.encoder.named_modules())
    for node, (name, conv) in zip(convs, order, strict=True):
        weight = inits[node.input[1]]
        if weight.shape != conv.weight.shape:
            raise CompanionError(f"{path}: encoder convolution {name} has shape {tuple(weight.shape)}, "
                                 f"expected {tuple(conv.weight.shape)}", "start from an export of the same layout")
        conv.weight.data.copy_(weight)
        bias = inits[node.input[2]] if len(node.input) > 2 else torch.zeros(weight.shape[0])
        folded_bias[name] = bias
        bn = modules[_bn_name(name)]
        bn.running_mean.zero_()
        bn.running_var.fill_(1.0 - bn.eps)
        bn.weight.data.fill_(1.0)
        bn.bias.data.copy_(bias)
    if calibration is not None:
        _calibrate_batchnorm(model, order, folded_bias, calibration)
    model.eval()
    return model


@torch.no_grad()
def _calibrate_batchnorm(model, order, folded_bias, calibration: torch.Tensor) -> None:
    """Set each rebuilt BatchNorm's statistics to those of its convolution's output on ``calibration``."""
    modules = dict(model.encoder.named_modules())
    stats: dict[str, tuple[torch.Tensor, torch.Tensor]] = {}
    hooks = []
    for name, conv in order:
        def hook(mod, inputs, output, name=name):
            stats[name] = (output.mean((0, 2, 3)), output.var((0, 2, 3), unbiased=False))
        hooks.append(conv.register_forward_hook(hook))
    model.eval()  # eval: every layer sees exactly the ONNX network's activations
    model.encoder(calibration)
    for h in hooks:
        h.remove()
    for name, _ in order:
        mean, var = stats[name]
        bn = modules[_bn_name(name)]
        bn.running_mean.copy_(mean)
        bn.running_var.copy_(var)
        bn.weight.data.copy_(torch.sqrt(var + bn.eps))
        bn.bias.data.copy_(mean + folded_bias[name])


def missing_head_parameters(model: Monodepth2) -> list[torch.nn.Parameter]:
    """The coarse disparity heads that an ONNX file does not carry."""
    return [p for s in model.depth.scales if s != ONNX_HEAD_SCALE
            for p in model.depth._conv("dispconv", s).parameters()]


def fit_missing_heads(model: Monodepth2, batches, loss_fn, steps: int, lr: float = 1e-3) -> float:
    """Train only the coarse disparity heads for ``steps`` batches (everything else frozen); returns the last loss.

    ``batches`` yields (x, depth) tensors; ``loss_fn(outputs, x, depth)`` is the training loss."""
    params = missing_head_parameters(model)
    frozen = [p for p in model.parameters() if all(p is not q for q in params)]
    for p in frozen:
        p.requires_grad_(False)
    opt = torch.optim.Adam(params, lr=lr)
    model.eval()  # BatchNorm statistics stay those of the shipped model while the heads catch up
    last = float("nan")
    try:
        for _ in range(steps):
            x, d = next(batches)
            loss = loss_fn(model.forward_all(x), x, d)
            opt.zero_grad()
            loss.backward()
            opt.step()
            last = float(loss.item())
    finally:
        for p in frozen:
            p.requires_grad_(True)
        model.train()
    return last if np.isfinite(last) else float("nan")

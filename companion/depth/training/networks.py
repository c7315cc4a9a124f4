"""Monodepth2 in PyTorch: ResNet-18 encoder + DepthDecoder, module names identical to the original.

Written without torchvision so that the official checkpoints load unchanged: ``encoder.pth`` keys are
``encoder.conv1.weight``, ``encoder.layer1.0.conv1.weight``, ... (plus 'height', 'width', 'use_stereo');
``depth.pth`` keys are ``decoder.N.conv.conv.weight`` (the original's ModuleList of ConvBlock / Conv3x3).
``width`` < 1 shrinks every channel count (our shipped model uses 0.25 to train on a CPU); 1.0 is the original.
"""

from __future__ import annotations

from collections import OrderedDict

import torch
import torch.nn.functional as F
from torch import nn

ENCODER_EXTRA_KEYS = ("height", "width", "use_stereo")


def disp_to_depth(disp: torch.Tensor, min_depth: float, max_depth: float) -> tuple[torch.Tensor, torch.Tensor]:
    """Sigmoid output -> (scaled disparity, depth), exactly as in Monodepth2's layers.py."""
    min_disp = 1.0 / max_depth
    max_disp = 1.0 / min_depth
    scaled_disp = min_disp + (max_disp - min_disp) * disp
    return scaled_disp, 1.0 / scaled_disp


class BasicBlock(nn.Module):
    expansion = 1

    def __init__(self, inplanes: int, planes: int, stride: int = 1, downsample: nn.Module | None = None):
        super().__init__()
        self.conv1 = nn.Conv2d(inplanes, planes, 3, stride, 1, bias=False)
        self.bn1 = nn.BatchNorm2d(planes)
        self.relu = nn.ReLU(inplace=True)
        self.conv2 = nn.Conv2d(planes, planes, 3, 1, 1, bias=False)
        self.bn2 = nn.BatchNorm2d(planes)
        self.downsample = downsample

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        identity = x if self.downsample is None else self.downsample(x)
        out = self.relu(self.bn1(self.conv1(x)))
        out = self.bn2(self.conv2(out))
        return self.relu(out + identity)


class ResNet18(nn.Module):
    """torchvision's resnet18 layout (conv1, bn1, layer1..4, fc) with optionally scaled widths."""

    def __init__(self, channels: tuple[int, int, int, int]):
        super().__init__()
        c = channels
        self.inplanes = c[0]
        self.conv1 = nn.Conv2d(3, c[0], 7, 2, 3, bias=False)
        self.bn1 = nn.BatchNorm2d(c[0])
        self.relu = nn.ReLU(inplace=True)
        self.maxpool = nn.MaxPool2d(3, 2, 1)
        self.layer1 = self._make_layer(c[0], 1)
        self.layer2 = self._make_layer(c[1], 2)
        self.layer3 = self._make_layer(c[2], 2)
        self.layer4 = self._make_layer(c[3], 2)
        for m in self.modules():
            if isinstance(m, nn.Conv2d):
                nn.init.kaiming_normal_(m.weight, mode="fan_out", nonlinearity="relu")
            elif isinstance(m, nn.BatchNorm2d):
                nn.init.constant_(m.weight, 1)
                nn.init.constant_(m.bias, 0)

    def _make_layer(self, planes: int, stride: int) -> nn.Sequential:
        downsample = None
        if stride != 1 or self.inplanes != planes:
            downsample = nn.Sequential(
                nn.Conv2d(self.inplanes, planes, 1, stride, bias=False), nn.BatchNorm2d(planes)
            )
        layers = [BasicBlock(self.inplanes, planes, stride, downsample), BasicBlock(planes, planes)]
        self.inplanes = planes
        return nn.Sequential(*layers)


class ResnetEncoder(nn.Module):
    """Monodepth2's ResnetEncoder (18 layers, one input image). Returns the five feature maps."""

    def __init__(self, width: float = 1.0):
        super().__init__()
        base = (64, 128, 256, 512)
        chans = tuple(max(4, int(round(c * width))) for c in base)
        self.num_ch_enc = [chans[0], chans[0], chans[1], chans[2], chans[3]]
        self.encoder = ResNet18(chans)  # attribute name gives the official 'encoder.' key prefix

    def forward(self, input_image: torch.Tensor) -> list[torch.Tensor]:
        x = (input_image - 0.45) / 0.225
        e = self.encoder
        f0 = e.relu(e.bn1(e.conv1(x)))
        f1 = e.layer1(e.maxpool(f0))
        f2 = e.layer2(f1)
        f3 = e.layer3(f2)
        f4 = e.layer4(f3)
        return [f0, f1, f2, f3, f4]


class Conv3x3(nn.Module):
    def __init__(self, in_channels: int, out_channels: int):
        super().__init__()
        self.pad = nn.ReflectionPad2d(1)
        self.conv = nn.Conv2d(in_channels, out_channels, 3)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.conv(self.pad(x))


class ConvBlock(nn.Module):
    def __init__(self, in_channels: int, out_channels: int):
        super().__init__()
        self.conv = Conv3x3(in_channels, out_channels)
        self.nonlin = nn.ELU(inplace=True)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.nonlin(self.conv(x))


class DepthDecoder(nn.Module):
    """Monodepth2's DepthDecoder: skip connections, nearest upsampling, sigmoid disparity at 4 scales."""

    def __init__(self, num_ch_enc: list[int], scales=range(4), width: float = 1.0, use_skips: bool = True):
        super().__init__()
        self.scales = list(scales)
        self.use_skips = use_skips
        self.num_ch_enc = list(num_ch_enc)
        self.num_ch_dec = [max(2, int(round(c * width))) for c in (16, 32, 64, 128, 256)]
        convs: OrderedDict[tuple, nn.Module] = OrderedDict()
        for i in range(4, -1, -1):
            ch_in = self.num_ch_enc[-1] if i == 4 else self.num_ch_dec[i + 1]
            convs[("upconv", i, 0)] = ConvBlock(ch_in, self.num_ch_dec[i])
            ch_in = self.num_ch_dec[i] + (self.num_ch_enc[i - 1] if use_skips and i > 0 else 0)
            convs[("upconv", i, 1)] = ConvBlock(ch_in, self.num_ch_dec[i])
        for s in self.scales:
            convs[("dispconv", s)] = Conv3x3(self.num_ch_dec[s], 1)
        self._index = {key: n for n, key in enumerate(convs)}
        self.decoder = nn.ModuleList(list(convs.values()))
        self.sigmoid = nn.Sigmoid()

    def _conv(self, *key) -> nn.Module:
        return self.decoder[self._index[key]]

    def forward(self, input_features: list[torch.Tensor]) -> dict[tuple[str, int], torch.Tensor]:
        outputs = {}
        x = input_features[-1]
        for i in range(4, -1, -1):
            x = self._conv("upconv", i, 0)(x)
            parts = [F.interpolate(x, scale_factor=2.0, mode="nearest")]
            if self.use_skips and i > 0:
                parts.append(input_features[i - 1])
            x = self._conv("upconv", i, 1)(torch.cat(parts, 1))
            if i in self.scales:
                outputs[("disp", i)] = self.sigmoid(self._conv("dispconv", i)(x))
        return outputs


class Monodepth2(nn.Module):
    """Encoder + decoder. ``forward`` returns the full-resolution sigmoid disparity (N x 1 x H x W)."""

    def __init__(self, width: float = 1.0):
        super().__init__()
        self.width = width
        self.encoder = ResnetEncoder(width)
        self.depth = DepthDecoder(self.encoder.num_ch_enc, width=width)

    def forward_all(self, x: torch.Tensor) -> dict[tuple[str, int], torch.Tensor]:
        return self.depth(self.encoder(x))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.forward_all(x)[("disp", 0)]


def encoder_state_dict(model: Monodepth2, height: int, width: int) -> dict:
    """The encoder's weights in the official ``encoder.pth`` layout (with 'height', 'width', 'use_stereo')."""
    sd = dict(model.encoder.state_dict())
    sd.update({"height": height, "width": width, "use_stereo": False})
    return sd


def load_official(encoder_path, decoder_path, width: float = 1.0) -> tuple[Monodepth2, dict]:
    """Load Monodepth2 checkpoints saved in the official key layout. Returns (model in eval mode, extras)."""
    from companion.errors import CompanionError

    try:
        enc = torch.load(encoder_path, map_location="cpu", weights_only=True)
        dec = torch.load(decoder_path, map_location="cpu", weights_only=True)
    except FileNotFoundError as exc:
        raise CompanionError(
            f"checkpoint not found: {exc.filename}", "pass the paths of encoder.pth and depth.pth"
        ) from exc
    except Exception as exc:  # torch raises many types for a corrupt / non-checkpoint file
        raise CompanionError(f"cannot read checkpoint: {exc}", "pass Monodepth2 encoder.pth / depth.pth files") from exc
    if not isinstance(enc, dict) or "encoder.conv1.weight" not in enc:
        raise CompanionError(
            f"{encoder_path} is not a Monodepth2 encoder checkpoint (no 'encoder.conv1.weight')",
            "pass the encoder.pth of a Monodepth2 ResNet-18 model (--encoder) and its depth.pth (--decoder)",
        )
    if width == 1.0:  # infer the width from the checkpoint itself
        width = enc["encoder.conv1.weight"].shape[0] / 64.0
    extras = {k: enc[k] for k in ENCODER_EXTRA_KEYS if k in enc}
    model = Monodepth2(width=width)
    enc_sd = {k: v for k, v in enc.items() if k not in ENCODER_EXTRA_KEYS and not k.startswith("encoder.fc.")}
    try:
        model.encoder.load_state_dict(enc_sd, strict=True)
        model.depth.load_state_dict(dec, strict=True)
    except RuntimeError as exc:
        raise CompanionError(
            f"checkpoint does not match the Monodepth2 ResNet-18 layout: {str(exc).splitlines()[0]}",
            "use the mono 640x192 / 1024x320 ResNet-18 models (encoder.pth + depth.pth from the same model)",
        ) from exc
    model.eval()
    return model, extras

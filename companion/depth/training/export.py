"""Export a Monodepth2 model to ONNX (1x3xHxW RGB in [0,1] -> 1x1xHxW sigmoid disparity) and verify it.

The check runs the same random input through torch and onnxruntime and fails if they differ by >= 1e-4.
Metadata (input size, depth range, source, licence) is written into the ONNX ``metadata_props`` so the runtime
(companion.depth.session) needs nothing but the .onnx file.
"""

from __future__ import annotations

import io
import logging
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from companion.errors import CompanionError

log = logging.getLogger(__name__)

MAX_ABS_DIFF = 1e-4


@dataclass
class ExportReport:
    path: Path
    height: int
    width: int
    max_abs_diff: float
    size_bytes: int


def export_onnx(
    model: torch.nn.Module,
    out: str | Path,
    *,
    height: int = 192,
    width: int = 640,
    min_depth: float = 0.1,
    max_depth: float = 100.0,
    source: str = "",
    licence: str = "",
    extra_metadata: dict[str, str] | None = None,
    opset: int = 17,
) -> ExportReport:
    """Write ``model`` (returning N x 1 x H x W disparity) to ``out`` and verify it with onnxruntime."""
    import onnx
    import onnxruntime as ort

    if height % 32 or width % 32:
        raise CompanionError(
            f"input size {height}x{width} is not a multiple of 32", "use e.g. 192x640 (the Monodepth2 default)"
        )
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    model = model.eval()
    dummy = torch.rand(1, 3, height, width, generator=torch.Generator().manual_seed(0))
    buf = io.BytesIO()
    with torch.no_grad(), warnings.catch_warnings():
        warnings.simplefilter("ignore")  # tracer chatter about constant folding; the result is verified below
        torch.onnx.export(
            model, (dummy,), buf, input_names=["image"], output_names=["disparity"], opset_version=opset,
            dynamo=False,
        )
    proto = onnx.load_from_string(buf.getvalue())
    meta = {
        "format": "monodepth2",
        "input_height": str(height),
        "input_width": str(width),
        "input": "RGB float32 in [0,1], NCHW",
        "output": "sigmoid disparity; depth = 1 / (1/max_depth + (1/min_depth - 1/max_depth) * disparity)",
        "min_depth": str(min_depth),
        "max_depth": str(max_depth),
        "source": source,
        "licence": licence,
        **(extra_metadata or {}),
    }
    del proto.metadata_props[:]
    for k, v in meta.items():
        entry = proto.metadata_props.add()
        entry.key, entry.value = k, str(v)
    onnx.checker.check_model(proto)
    out.write_bytes(proto.SerializeToString())

    x = torch.rand(1, 3, height, width, generator=torch.Generator().manual_seed(1))
    with torch.no_grad():
        ref = model(x).numpy()
    sess = ort.InferenceSession(str(out), providers=["CPUExecutionProvider"])
    got = sess.run(None, {"image": x.numpy()})[0]
    diff = float(np.max(np.abs(got - ref)))
    log.info("exported %s: torch vs onnxruntime max abs diff %.3g", out, diff)
    if not diff < MAX_ABS_DIFF:
        raise CompanionError(
            f"onnxruntime output differs from torch by {diff:.3g} (limit {MAX_ABS_DIFF})",
            "re-export with another opset (--opset) or report the model architecture",
        )
    return ExportReport(out, height, width, diff, out.stat().st_size)


def export_checkpoints(
    encoder: str | Path, decoder: str | Path, out: str | Path, *, height: int = 192, width: int = 640,
    source: str | None = None, licence: str = "as licensed by the checkpoint's owner", opset: int = 17,
) -> ExportReport:
    """``companion depth export``: official-layout encoder.pth + depth.pth -> verified ONNX."""
    from companion.depth.training.networks import load_official

    model, extras = load_official(encoder, decoder)
    src = source or f"Monodepth2 checkpoints {Path(encoder).name} + {Path(decoder).name}"
    trained = {k: str(v) for k, v in extras.items()}
    return export_onnx(
        model, out, height=height, width=width, source=src, licence=licence, opset=opset,
        extra_metadata={f"trained_{k}": v for k, v in trained.items()} | {"encoder_width": str(model.width)},
    )

"""Static int8 quantisation (QDQ, per-channel weights) of a Monodepth2 ONNX model, calibrated on real frames.

Kept as a measured option, not the shipped default: on the 2-core reference machine the int8 model ran slower
than fp32 (see docs/BENCHMARKS.md, Depth mask), and the fp32 reduced-width model is already 3.6 MB.
Needs the ``onnx`` package (the ``train`` extra).
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np

from companion.depth.session import DepthSession


def quantise_int8(model: str | Path, out: str | Path, calibration_bgr: list[np.ndarray]) -> Path:
    """Write an int8 QDQ copy of ``model`` to ``out``, calibrated on the given BGR frames (10-50 is plenty)."""
    from onnxruntime.quantization import (
        CalibrationDataReader,
        QuantFormat,
        QuantType,
        quant_pre_process,
        quantize_static,
    )

    sess = DepthSession(model, threads=1)
    inputs = [{sess.info.input_name: sess.preprocess(img)} for img in calibration_bgr]

    class Reader(CalibrationDataReader):
        def __init__(self):
            self._it = iter(inputs)

        def get_next(self):
            return next(self._it, None)

    with tempfile.TemporaryDirectory() as tmp:
        pre = Path(tmp) / "pre.onnx"
        quant_pre_process(str(model), str(pre))
        quantize_static(
            str(pre), str(out), Reader(), quant_format=QuantFormat.QDQ, activation_type=QuantType.QUInt8,
            weight_type=QuantType.QInt8, per_channel=True,
        )
    import onnx

    q = onnx.load(str(out))  # carry the metadata (input size, depth range, metric flag, licence) over
    del q.metadata_props[:]
    for k, v in {**sess.info.metadata, "quantisation": "int8 QDQ per-channel, static calibration"}.items():
        entry = q.metadata_props.add()
        entry.key, entry.value = k, v
    onnx.save(q, str(out))
    return Path(out)

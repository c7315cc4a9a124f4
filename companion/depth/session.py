"""onnxruntime session for any Monodepth2-style ONNX model (1x3xHxW RGB in [0,1] -> disparity).

Needs only onnxruntime, numpy and OpenCV (no torch). The input size comes from the model itself (its input
shape, or the ``input_height``/``input_width`` metadata for models exported with dynamic axes).
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from companion.errors import CompanionError
from companion.resources import DEFAULT_MODEL_NAME, SHIPPED_MODEL_FILES, shipped_model

log = logging.getLogger(__name__)

# The models shipped in the package, selectable by name (mission ``depth_model``, ``--model``): companion/resources.py.
SHIPPED_MODELS = {name: shipped_model(name) for name in SHIPPED_MODEL_FILES}
DEFAULT_MODEL = SHIPPED_MODELS[DEFAULT_MODEL_NAME]


def resolve_model(model: str | Path | None) -> Path:
    """The model file for ``model``: None = the shipped default, a shipped name ("sim", "real-nc"), or a path."""
    if model is None:
        return DEFAULT_MODEL
    return SHIPPED_MODELS.get(str(model), Path(model))
DEFAULT_SIZE = (192, 640)  # (height, width), the Monodepth2 default


@dataclass(frozen=True)
class ModelInfo:
    path: Path
    input_name: str
    height: int
    width: int
    min_depth: float
    max_depth: float
    metadata: dict[str, str]
    metric: bool = False  # trained on metric depth (our simulator model): absolute depth thresholds apply

    def disparity_for_depth(self, depth_m: float) -> float:
        """Sigmoid disparity that the model outputs for ``depth_m`` (inverse of Monodepth2's disp_to_depth)."""
        min_disp, max_disp = 1.0 / self.max_depth, 1.0 / self.min_depth
        return float((1.0 / depth_m - min_disp) / (max_disp - min_disp))

    def depth_from_disparity(self, disparity: np.ndarray) -> np.ndarray:
        min_disp, max_disp = 1.0 / self.max_depth, 1.0 / self.min_depth
        return 1.0 / (min_disp + (max_disp - min_disp) * disparity)


def default_threads() -> int:
    """Intra-op threads: all cores but one (left for capture and the gate), at least 1, at most 4.

    On the 2-core reference machine 1 thread is also the fastest: 2 threads measured slower (bench/depth_latency.py).
    """
    return max(1, min(4, (os.cpu_count() or 2) - 1))


class DepthSession:
    """Runs a Monodepth2-style ONNX model on BGR frames and returns disparity at model resolution."""

    def __init__(self, model_path: str | Path | None = None, *, threads: int | None = None):
        import onnxruntime as ort

        path = resolve_model(model_path)
        if not path.is_file():
            raise CompanionError(
                f"depth model not found: {path}",
                "pass --model (or set depth_model in the mission) to an existing .onnx file or a shipped model name "
                f"({', '.join(SHIPPED_MODELS)}), or omit it to use the shipped default model"
                if model_path is not None
                else "reinstall companion (pip install -e .): the shipped model file is missing",
            )
        opts = ort.SessionOptions()
        opts.intra_op_num_threads = threads or default_threads()
        opts.inter_op_num_threads = 1
        opts.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
        try:
            self._sess = ort.InferenceSession(str(path), sess_options=opts, providers=["CPUExecutionProvider"])
        except Exception as exc:  # onnxruntime raises its own Fail/InvalidProtobuf/InvalidGraph types
            raise CompanionError(
                f"{path} is not a loadable ONNX model: {str(exc).splitlines()[0][:200]}",
                "export one with `companion depth export` or pass a valid Monodepth2-style .onnx file",
            ) from exc
        self.info = self._inspect(path)
        log.debug("depth model %s: input %dx%d", path, self.info.height, self.info.width)

    def _inspect(self, path: Path) -> ModelInfo:
        inputs, outputs = self._sess.get_inputs(), self._sess.get_outputs()
        meta = dict(self._sess.get_modelmeta().custom_metadata_map)
        bad = CompanionError(
            f"{path} is not a Monodepth2-style model (inputs {[(i.name, i.shape) for i in inputs]}, "
            f"outputs {[(o.name, o.shape) for o in outputs]})",
            "use a model with one 1x3xHxW float input (RGB in [0,1]) and a 1x1xHxW disparity output",
        )
        if len(inputs) != 1 or len(inputs[0].shape) != 4 or inputs[0].type != "tensor(float)":
            raise bad
        n, c, h, w = inputs[0].shape
        if c != 3 or (isinstance(n, int) and n != 1):
            raise bad
        if not isinstance(h, int) or not isinstance(w, int):
            h = int(meta.get("input_height", DEFAULT_SIZE[0]))
            w = int(meta.get("input_width", DEFAULT_SIZE[1]))
        out_shape = outputs[0].shape
        channels = out_shape[1] if len(out_shape) == 4 else 1
        if len(out_shape) not in (3, 4) or (isinstance(channels, int) and channels != 1):
            raise bad
        return ModelInfo(
            path=path,
            input_name=inputs[0].name,
            height=h,
            width=w,
            min_depth=float(meta.get("min_depth", 0.1)),
            max_depth=float(meta.get("max_depth", 100.0)),
            metadata=meta,
            metric=meta.get("metric_depth", "false").lower() == "true",
        )

    def preprocess(self, image_bgr: np.ndarray) -> np.ndarray:
        if image_bgr is None or image_bgr.ndim != 3 or image_bgr.shape[2] != 3 or image_bgr.dtype != np.uint8:
            raise CompanionError(
                f"depth input must be an H x W x 3 uint8 BGR image, got {getattr(image_bgr, 'shape', None)}",
                "pass frames as delivered by companion.capture (BGR uint8)",
            )
        interp = cv2.INTER_AREA if image_bgr.shape[1] > self.info.width else cv2.INTER_LINEAR
        small = cv2.resize(image_bgr, (self.info.width, self.info.height), interpolation=interp)
        rgb = cv2.cvtColor(small, cv2.COLOR_BGR2RGB)
        return (rgb.astype(np.float32) * (1.0 / 255.0)).transpose(2, 0, 1)[None]

    def disparity(self, image_bgr: np.ndarray) -> np.ndarray:
        """Sigmoid disparity (H x W float32 at model resolution, higher = nearer) for one BGR frame."""
        out = self._sess.run(None, {self.info.input_name: self.preprocess(image_bgr)})[0]
        d = np.asarray(out, dtype=np.float32)
        while d.ndim > 2:
            d = d[0]
        if d.shape != (self.info.height, self.info.width):
            d = cv2.resize(d, (self.info.width, self.info.height), interpolation=cv2.INTER_LINEAR)
        return d

"""Background removal by monocular depth (paper step 1): onnxruntime Monodepth2 session + ROI extraction.

Runtime needs onnxruntime, numpy and OpenCV only; torch code (architecture, export, training) lives in
``companion.depth.training`` behind the ``train`` extra.
"""

from companion.depth.masker import Masker, MaskerStats
from companion.depth.roi import RoiParams, RoiResult, apply_mask, extract_roi, pixel_error_ratio
from companion.depth.session import DEFAULT_MODEL, DepthSession, ModelInfo

__all__ = [
    "DEFAULT_MODEL",
    "DepthSession",
    "Masker",
    "MaskerStats",
    "ModelInfo",
    "RoiParams",
    "RoiResult",
    "apply_mask",
    "extract_roi",
    "pixel_error_ratio",
]

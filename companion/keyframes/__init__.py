"""Keyframe gate: SIFT overlap ratio between ROI frames and the streaming selection of keyframes (paper Sec. 2.2)."""

from companion.keyframes.features import FeatureConfig, FeatureExtractor, FeatureSet
from companion.keyframes.gate import (
    Comparison,
    GateConfig,
    GateEvent,
    GateEventKind,
    GateStep,
    KeyframeGate,
    StepRole,
)
from companion.keyframes.overlap import (
    OverlapConfig,
    OverlapEstimate,
    OverlapEstimator,
    OverlapStatus,
    eq2_overlap,
    polygon_overlap,
)
from companion.keyframes.sharpness import laplacian_variance

__all__ = [
    "Comparison",
    "FeatureConfig",
    "FeatureExtractor",
    "FeatureSet",
    "GateConfig",
    "GateEvent",
    "GateEventKind",
    "GateStep",
    "KeyframeGate",
    "OverlapConfig",
    "OverlapEstimate",
    "OverlapEstimator",
    "OverlapStatus",
    "StepRole",
    "eq2_overlap",
    "laplacian_variance",
    "polygon_overlap",
]

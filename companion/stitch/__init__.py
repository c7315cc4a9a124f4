"""Stitching worker: turns masked keyframes into a facade map rectified to the wall plane (paper step 3).

Pipeline (one module per job): ``inputs`` (spool manifest or simulator recording) -> ``features`` (SIFT inside
the ROI) -> ``pairs`` (DLT/RANSAC homographies, telemetry gate, affine fallback) -> ``align`` (global
least-squares alignment onto the facade plane, telemetry as prior) -> ``mesh`` (APAP local homographies,
paper Eq. 4) -> ``render`` (tiled warp, seams, feathering, coverage) -> ``output`` (map, scale bar, report).
"""

from companion.stitch.inputs import CameraModel, FacadeGeometry, KeyframeInput, StitchInput, load_input
from companion.stitch.worker import StitchConfig, StitchResult, stitch

__all__ = [
    "CameraModel",
    "FacadeGeometry",
    "KeyframeInput",
    "StitchConfig",
    "StitchInput",
    "StitchResult",
    "load_input",
    "stitch",
]

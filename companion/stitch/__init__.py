"""Stitching worker: turns masked keyframes into a facade map rectified to the wall plane (paper step 3).

``worker.Stitcher`` runs the stages, one module each: ``features`` (SIFT inside the ROI) -> ``priors``
(telemetry on the wall plane) -> ``pairs`` (DLT/RANSAC homographies, telemetry gate, affine fallback) ->
``align`` (global least-squares alignment onto the facade plane, telemetry as prior) -> ``layout`` (map grid,
APAP local homographies of ``mesh``, paper Eq. 4) -> ``canvas`` (tiled warp of ``render``: seams, feathering)
-> ``report`` (coverage, map files with ``output``, report.json); ``debug`` dumps each stage on request.
"""

from companion.stitch.inputs import CameraModel, FacadeGeometry, KeyframeInput, StitchInput, load_input
from companion.stitch.worker import StitchConfig, Stitcher, StitchResult, stitch

__all__ = [
    "CameraModel",
    "FacadeGeometry",
    "KeyframeInput",
    "StitchConfig",
    "StitchInput",
    "StitchResult",
    "Stitcher",
    "load_input",
    "stitch",
]

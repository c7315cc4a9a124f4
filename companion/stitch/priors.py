"""Where telemetry puts each keyframe on the wall plane, and the map's scale: the prior every later stage uses.

With poses, each keyframe gets an image-normalised -> plane homography from its pose (``prior_plane_from_image``)
and the plane is in metres at the median camera distance (the telemetry's, corrected by the distance the images
measure: ``wall_distance.py``). Without, the first placed keyframe fixes the plane
(``reference``) and the scale is known only when the spool gives the standoff.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from companion.errors import CompanionError
from companion.stitch.config import StitchConfig
from companion.stitch.geometry import camera_distance_to_wall, prior_plane_from_image, reference_plane_from_image
from companion.stitch.inputs import StitchInput


@dataclass(frozen=True)
class PlanePriors:
    use_poses: bool  # telemetry is used (the map is rectified to the facade)
    priors: tuple[np.ndarray | None, ...]  # per keyframe position: image-normalised -> plane, or None
    plane_unit_m: float  # metres per plane unit (1 with telemetry; the standoff's scale without)
    scale_known: bool  # the map's mm/px is meaningful
    reference: np.ndarray  # places the first keyframe when none has a prior (fixes the gauge)


def plane_priors(inp: StitchInput, cfg: StitchConfig, out_shift_m: float | Sequence[float] = 0.0) -> PlanePriors:
    """The priors of ``inp``'s keyframes; ``out_shift_m`` moves every camera that far out from the wall first
    (the correction the measured wall distance makes: ``wall_distance.py``), one value for all or one per keyframe
    position (a bias that drifted during the flight)."""
    cam = inp.camera
    use_poses = cfg.use_poses and inp.has_poses
    shifts = ((float(out_shift_m),) * len(inp.keyframes) if isinstance(out_shift_m, int | float)
              else tuple(out_shift_m))
    priors = tuple(
        prior_plane_from_image(kf.pose, inp.facade, shift) if use_poses and kf.pose is not None else None
        for kf, shift in zip(inp.keyframes, shifts, strict=True)
    )
    if use_poses:
        dists = [camera_distance_to_wall(kf.pose, inp.facade) + shift
                 for kf, shift in zip(inp.keyframes, shifts, strict=True) if kf.pose is not None]
        distance = float(np.median(dists))
        if distance <= 0:
            raise CompanionError(
                f"telemetry puts the camera {distance:.1f} m behind the wall plane",
                "check the facade start/end order (drone on the right-hand side) in spool.json",
            )
        return PlanePriors(True, priors, distance / cam.focal_px, True, np.eye(3))
    scale_known = inp.standoff_m is not None
    plane_unit_m = (inp.standoff_m / cam.focal_px) if scale_known else 1.0
    reference = reference_plane_from_image(inp.standoff_m if scale_known else cam.focal_px)
    return PlanePriors(False, priors, plane_unit_m, scale_known, reference)

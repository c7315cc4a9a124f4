"""Telemetry cross-check of the gate's overlap: the overlap two keyframes' poses predict, compared with the image's.

Why: the image estimate trusts what RANSAC agrees on. Where the ROI keeps some background (roof line, sky, or no
mask at all), those far features move less than the wall's and the image overestimates the overlap. The poses do
not depend on the mask. The same prediction (``companion.keyframes.motion``) is handed to the gate, which uses it
to DECIDE (a pair the poses put below Rth - 3 points is never accepted); what is left here flags a keyframe pair
that still contradicts the telemetry (a gate run without poses, or a pose that arrived stale).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from companion.geo import FacadeFrame
from companion.keyframes.motion import WallMotionPredictor
from companion.records import Pose

_NOMINAL_WIDTH_PX = 1000  # the overlap share does not depend on the pixel count, only on the lens and aspect


@dataclass(frozen=True)
class OverlapCrossCheck:
    frame: FacadeFrame
    hfov_deg: float
    aspect: float  # image height / width
    margin_points: float = 3.0  # the gate's guarantee is Rth - 3 points
    standoff_m: float | None = None  # planned camera-to-wall distance (None: the poses' own distance)
    predictor: WallMotionPredictor = field(init=False, repr=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "predictor", WallMotionPredictor(self.frame, self.hfov_deg, self.standoff_m))

    def predicted_percent(self, a: Pose, b: Pose) -> float | None:
        """Overlap (percent) of two frames of the wall-facing camera, from the poses alone (footprints on the wall
        plane, camera attitude included)."""
        width = _NOMINAL_WIDTH_PX
        motion = self.predictor.predict(a, b, width, max(1, round(width * self.aspect)))
        return None if motion is None else motion.overlap_percent

    def suspect(self, image_percent: float | None, a: Pose | None, b: Pose | None, rth_percent: float) -> float | None:
        """The telemetry overlap when it contradicts an image overlap at or above Rth; None when they agree."""
        if image_percent is None or a is None or b is None or image_percent < rth_percent:
            return None
        predicted = self.predicted_percent(a, b)
        if predicted is not None and predicted < rth_percent - self.margin_points:
            return predicted
        return None

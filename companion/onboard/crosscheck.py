"""Telemetry cross-check of the gate's overlap: where the image says enough overlap but the poses say the camera
moved too far, the keyframe pair is flagged (a possible gap to re-fly).

Why: the image estimate trusts the ROI mask. Where the mask keeps some background (roof line, sky), those far
features move less than the wall's and the image overestimates the overlap. The poses do not depend on the mask.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from companion.geo import FacadeFrame
from companion.records import Pose


@dataclass(frozen=True)
class OverlapCrossCheck:
    frame: FacadeFrame
    hfov_deg: float
    aspect: float  # image height / width
    margin_points: float = 3.0  # the gate's guarantee is Rth - 3 points

    def predicted_percent(self, a: Pose, b: Pose) -> float | None:
        """Overlap (percent) of two frames of a wall-facing camera, from the poses alone (paper Eq. 2 form)."""
        (a1, o1, u1), (a2, o2, u2) = (
            (float(v) for v in self.frame.geodetic_to_facade(p.lat, p.lon, p.alt_amsl_m)) for p in (a, b)
        )
        out = (o1 + o2) / 2.0
        if out <= 0.1:
            return None
        width = 2.0 * out * math.tan(math.radians(self.hfov_deg) / 2.0)
        height = width * self.aspect
        return 100.0 * max(0.0, 1.0 - abs(a2 - a1) / width) * max(0.0, 1.0 - abs(u2 - u1) / height)

    def suspect(self, image_percent: float | None, a: Pose | None, b: Pose | None, rth_percent: float) -> float | None:
        """The telemetry overlap when it contradicts an image overlap at or above Rth; None when they agree."""
        if image_percent is None or a is None or b is None or image_percent < rth_percent:
            return None
        predicted = self.predicted_percent(a, b)
        if predicted is not None and predicted < rth_percent - self.margin_points:
            return predicted
        return None

"""``companion mask --standoff M``: the wall's distance known, the network's metric depth is judged against it.

Why: without telemetry the ROI rules judge far relative to the nearest region the network sees (``near_ratio``,
``far_cut_ratio``) and drop a photo only when that region is beyond 15 m. With the standoff known, a pixel the
network puts more than ``STANDOFF_RATIO`` standoffs away cannot be the wall (windows and balconies lie a metre or
two behind it), and a photo with less than ``MIN_KEPT_SHARE`` left shows no wall. Only for a model trained on
metric depth (the shipped ones); a scale-free model cannot be judged in metres.
"""

from __future__ import annotations

from companion.depth.roi import RoiParams
from companion.errors import CompanionError

STANDOFF_RATIO = 2.5  # as the parallax wall_ratio: chosen on the validation passes (docs/DEPTH.md)
MIN_KEPT_SHARE = 0.0  # the ROI's min_roi_fraction under the rule (0: a frame is dropped only when nothing is left)


def standoff_masker(model, standoff_m: float, *, threads: int | None = None, ratio: float = STANDOFF_RATIO):
    """A :class:`companion.depth.masker.Masker` that cuts every pixel the network puts beyond ``ratio`` x
    ``standoff_m`` and drops a photo whose nearest region lies beyond it."""
    from companion.depth.masker import Masker

    if not standoff_m > 0 or not ratio > 1:
        raise CompanionError(f"--standoff {standoff_m} m (ratio {ratio})",
                             "give the camera's distance to the wall in metres, e.g. --standoff 4")
    probe = Masker(model, threads=threads)
    if not probe.session.info.metric:
        raise CompanionError(f"--standoff needs a depth model trained on metric depth; "
                             f"{probe.session.info.path.name} is scale-free",
                             "use a shipped model (--model sim or real-nc), or mask without --standoff")
    params = RoiParams(pixel_depth_cut=True, min_roi_fraction=MIN_KEPT_SHARE)
    return Masker(session=probe.session, params=params, max_roi_depth_m=ratio * standoff_m)

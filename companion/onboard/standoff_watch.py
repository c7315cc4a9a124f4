"""The chain's measured standoff: pairs the gate matched -> measurements -> the current estimate, warnings, summary.

Why: every log says the drone flies at the planned standoff because every log trusts GNSS absolute position; a
non-RTK bias of 1-2 m puts it at 2.5 or 5.5 m from the wall for minutes (issue 26). The gate already matches the
wall between the last keyframe and the frames around each decision, tens of centimetres to a metre apart, and the
poses' relative motion over that baseline is good to centimetres: ``companion.keyframes.standoff`` turns each such
pair into a measured distance. This watch feeds them to a ``StandoffEstimator``, steps it once per frame of the
scan (so it can say how much of the scan had no measurement: a plain wall, the camera blocked, a hover), says
when the measured standoff stays off the plan, and keeps the figures for the cull report.

Hook for the flight: ``CullChain.standoff`` (this watch's ``current``) is the latest estimate, a frozen
``records.StandoffEstimate`` or None; a supervisor that corrects the vehicle's distance reads it (thread-safe to
read: it is replaced whole, never changed) and must treat None as "not measured", never as "on plan".
"""

from __future__ import annotations

import logging

import numpy as np

from companion.geo import FacadeFrame
from companion.keyframes.standoff import StandoffEstimator, StandoffFitConfig, measure_standoff
from companion.records import MaskedFrame, StandoffEstimate

log = logging.getLogger(__name__)


def standoff_line(distance_m: float | None, sigma_m: float | None, planned_m: float | None) -> str:
    """``standoff measured 2.52 +- 0.04 m (plan 4.00)``, or that none was measured."""
    plan = "" if planned_m is None else f" (plan {planned_m:.2f})"
    if distance_m is None:
        return f"standoff not measured{plan}"
    return f"standoff measured {distance_m:.2f} +- {sigma_m or 0.0:.2f} m{plan}"


class StandoffWatch:
    """``observe`` is the gate's ``on_matches`` hook; ``step(time_s)`` once per frame of the scan returns the
    warnings to give now; ``current`` the estimate at the last step; ``summary()`` the report's figures.

    Warnings: the measured standoff more than ``off_m`` from the plan for ``hold_s`` seconds (once per excursion),
    and a louder one as soon as it is below ``low_share`` of the plan (the drone much closer than planned)."""

    def __init__(self, frame: FacadeFrame, hfov_deg: float, planned_m: float | None, *,
                 estimator: StandoffEstimator | None = None, fit: StandoffFitConfig | None = None,
                 off_m: float = 0.3, hold_s: float = 3.0, low_share: float = 0.6):
        self.frame, self.hfov_deg, self.planned_m = frame, hfov_deg, planned_m
        self.estimator = estimator or StandoffEstimator()
        self.fit = fit or StandoffFitConfig()
        self.off_m, self.hold_s, self.low_share = off_m, hold_s, low_share
        self.current: StandoffEstimate | None = None
        self.pairs = 0  # pairs offered by the gate
        self.frames = self.frames_without = 0  # frames of the scan stepped, and of those without an estimate
        self.warnings = 0
        self._distances: list[float] = []
        self._sigmas: list[float] = []
        self._off_since: float | None = None
        self._warned_off = self._warned_low = False

    def observe(self, a: MaskedFrame, b: MaskedFrame, points: np.ndarray, size: tuple[int, int]) -> None:
        """One pair the gate matched: measured when both poses are fresh (any number of matches; the fit picks)."""
        self.pairs += 1
        if a.pose is None or b.pose is None or a.pose_stale or b.pose_stale:
            return
        width, height = size
        when = (a.frame.capture_time_s + b.frame.capture_time_s) / 2.0
        m = measure_standoff(points[:, :2], points[:, 2:4], a.pose, b.pose, self.frame, self.hfov_deg, width,
                             height, time_s=when, config=self.fit)
        if m is None:
            return
        log.debug("standoff pair %d -> %d: %.3f +- %.3f m over %.2f m, %d points", a.index, b.index, m.distance_m,
                  m.sigma_m, m.baseline_m, m.n_points)
        self.estimator.add(m)
        self._distances.append(m.distance_m)
        self._sigmas.append(m.sigma_m)

    def step(self, time_s: float) -> list[str]:
        """A frame of the scan at ``time_s``: the current estimate, and the warnings it calls for now."""
        self.current = est = self.estimator.estimate(time_s)
        self.frames += 1
        self.frames_without += int(est is None)
        if est is None or self.planned_m is None:
            return []
        out = []
        line = standoff_line(est.distance_m, est.sigma_m, self.planned_m)
        if est.distance_m < self.low_share * self.planned_m:
            if not self._warned_low:
                out.append(f"DANGER: {line}: under {100 * self.low_share:.0f} % of the planned standoff, the drone "
                           "is much closer to the wall than its position says (GNSS bias): take over or move out")
            self._warned_low = True
        else:
            self._warned_low = False
        if abs(est.distance_m - self.planned_m) <= self.off_m:
            self._off_since, self._warned_off = None, False
        else:
            self._off_since = time_s if self._off_since is None else self._off_since
            if not self._warned_off and time_s - self._off_since >= self.hold_s:
                out.append(f"{line}: off the plan by more than {self.off_m:.1f} m for {self.hold_s:g} s (GNSS bias?); "
                           "the overlap predictions now use the measured distance, and the stitcher measures the "
                           "map's scale from the images")
                self._warned_off = True
        self.warnings += len(out)
        return out

    def summary(self) -> dict:
        """The cull report's ``standoff``: the measurements' median and robust spread (1.4826 MAD), the plan,
        how many pairs measured it and the share of the scan's frames with no estimate."""
        d = np.array(self._distances)
        median = None if not len(d) else round(float(np.median(d)), 3)
        spread = None if not len(d) else round(1.4826 * float(np.median(np.abs(d - median))), 3)
        return {
            "source": "camera",
            "planned_m": self.planned_m,
            "measured_median_m": median,
            "measured_spread_m": spread,
            "sigma_median_m": None if not self._sigmas else round(float(np.median(self._sigmas)), 3),
            "measurements": int(len(d)),
            "pairs_offered": self.pairs,
            "frames_without_share": None if not self.frames else round(self.frames_without / self.frames, 3),
            "warnings": self.warnings,
        }

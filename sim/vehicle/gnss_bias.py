"""A slowly varying GNSS bias: where a non-RTK receiver puts the vehicle, minus where it is (issue 26).

Why it exists: a real non-RTK fix is off by a bias of 1-2 m that changes over minutes, not by white noise. The
autopilot flies its estimate, so the true vehicle sits offset from the plan by minus the bias while every log says
the planned standoff. ``GpsError`` (environment.py) models the fast zero-mean part; this is the slow part.

The model, per axis (North, East, Down), in metres:

    bias(t) = constant + walk(t),   walk(0) = 0,   walk(t + dt) = walk(t) + sigma * sqrt(dt) * N(0, 1)

a Wiener process whose RMS grows as ``drift_m_per_min * sqrt(t / 60 s)``: after one minute each axis is off its
constant by ``drift_m_per_min`` RMS, after four minutes by twice that. Horizontal and vertical axes drift at the same
rate. With ``max_walk_m`` each axis's walk is clamped to +-that (a receiver's bias does not grow without end);
None leaves it unbounded. The walk draws from its own generator, so turning it on leaves every other fault's
random sequence (wind, noise, glitch, packet loss, stalls) as it was; with drift 0 it draws nothing.
"""

from __future__ import annotations

import math

import numpy as np


def enu_to_ned(enu: tuple[float, float, float]) -> np.ndarray:
    """(East, North, Up) -> (North, East, Down): the command line speaks ENU, the vehicle model NED."""
    e, n, u = (float(v) for v in enu)
    return np.array([n, e, -u])


def ned_to_enu(ned: np.ndarray) -> list[float]:
    """(North, East, Down) -> [East, North, Up], for the truth log."""
    return [float(ned[1]), float(ned[0]), -float(ned[2])]


class GnssBias:
    """The estimator's position error that does not average out: a constant plus a seeded random walk (NED m)."""

    def __init__(self, constant_enu_m: tuple[float, float, float], drift_m_per_min: float, rng: np.random.Generator,
                 max_walk_m: float | None = None):
        if drift_m_per_min < 0 or not math.isfinite(drift_m_per_min):
            raise ValueError("GNSS drift must be a finite rate >= 0 (metres per minute)")
        if max_walk_m is not None and not max_walk_m > 0:
            raise ValueError("the GNSS drift bound must be positive")
        self.constant = enu_to_ned(constant_enu_m)
        self.sigma_m_per_sqrt_s = drift_m_per_min / math.sqrt(60.0)
        self.max_walk_m = max_walk_m
        self.rng = rng
        self.walk = np.zeros(3)

    @property
    def active(self) -> bool:
        """False when it can never be other than zero: the vehicle then adds nothing (the old estimate exactly)."""
        return bool(np.any(self.constant != 0.0)) or self.sigma_m_per_sqrt_s > 0.0

    @property
    def ned(self) -> np.ndarray:
        """The bias now (NED metres): estimate minus truth."""
        return self.constant + self.walk

    def step(self, dt: float) -> np.ndarray:
        """Advance the walk by ``dt`` simulated seconds; returns the bias now."""
        if self.sigma_m_per_sqrt_s > 0.0:
            self.walk = self.walk + self.sigma_m_per_sqrt_s * math.sqrt(dt) * self.rng.standard_normal(3)
            if self.max_walk_m is not None:
                self.walk = np.clip(self.walk, -self.max_walk_m, self.max_walk_m)
        return self.ned

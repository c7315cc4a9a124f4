"""Wind with gusts, GPS error and battery drain: the disturbances the vehicle model is flown through."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


class Wind:
    """Mean wind plus gusts as a first-order Gauss-Markov process (a cheap stand-in for a Dryden model).

    ``gust_m_s`` is the peak gust amplitude: the random part has a standard deviation of a third of it per
    horizontal axis and is clipped to it, vertical gusts are a quarter of the horizontal ones.
    """

    def __init__(self, mean_m_s: float, gust_m_s: float, rng: np.random.Generator, from_deg: float | None = None,
                 tau_s: float = 2.0):
        self.rng = rng
        direction = rng.uniform(0.0, 360.0) if from_deg is None else from_deg
        # Wind "from" a direction blows towards the opposite one.
        to = math.radians(direction + 180.0)
        self.mean = np.array([mean_m_s * math.cos(to), mean_m_s * math.sin(to), 0.0])
        self.gust_m_s = gust_m_s
        self.tau_s = tau_s
        self.sigma = np.array([gust_m_s / 3.0, gust_m_s / 3.0, gust_m_s / 12.0])
        self.gust = np.zeros(3)

    def step(self, dt: float) -> np.ndarray:
        if self.gust_m_s > 0.0:
            phi = math.exp(-dt / self.tau_s)
            self.gust = phi * self.gust + self.sigma * math.sqrt(1.0 - phi * phi) * self.rng.standard_normal(3)
            h = math.hypot(self.gust[0], self.gust[1])
            if h > self.gust_m_s:
                self.gust[:2] *= self.gust_m_s / h
        return self.mean + self.gust


class GpsError:
    """Navigation (GPS) position error: slow random walk with ``noise_m`` standard deviation, plus an optional
    glitch (a step offset for a while) that the controller follows, moving the real vehicle."""

    def __init__(self, noise_m: float, rng: np.random.Generator, glitch_at_s: float | None = None,
                 glitch_m: float = 5.0, glitch_s: float = 3.0, tau_s: float = 5.0):
        self.noise_m = noise_m
        self.rng = rng
        self.tau_s = tau_s
        self.walk = np.zeros(3)
        self.glitch_at_s = glitch_at_s
        self.glitch_s = glitch_s
        angle = rng.uniform(0.0, 2.0 * math.pi)
        self.glitch_offset = np.array([glitch_m * math.cos(angle), glitch_m * math.sin(angle), 0.0])

    def glitching(self, t_s: float) -> bool:
        return self.glitch_at_s is not None and self.glitch_at_s <= t_s < self.glitch_at_s + self.glitch_s

    def step(self, t_s: float, dt: float) -> np.ndarray:
        """Error (NED metres) of the position estimate at time ``t_s``."""
        if self.noise_m > 0.0:
            phi = math.exp(-dt / self.tau_s)
            sigma = np.array([self.noise_m, self.noise_m, 1.5 * self.noise_m])
            self.walk = phi * self.walk + sigma * math.sqrt(1.0 - phi * phi) * self.rng.standard_normal(3)
        return self.walk + (self.glitch_offset if self.glitching(t_s) else 0.0)


@dataclass
class Battery:
    """Linear drain: hover power while armed, nothing on the ground. Cell voltage follows remaining charge."""

    capacity_mah: float = 5000.0
    hover_current_a: float = 18.0
    idle_current_a: float = 0.5
    cells: int = 4
    consumed_mah: float = 0.0
    current_a: float = 0.0

    def step(self, dt: float, armed: bool, speed_m_s: float) -> None:
        self.current_a = (self.hover_current_a * (1.0 + 0.02 * speed_m_s * speed_m_s)) if armed else self.idle_current_a
        self.consumed_mah += self.current_a * dt / 3.6

    @property
    def remaining(self) -> float:
        return max(0.0, 1.0 - self.consumed_mah / self.capacity_mah)

    @property
    def voltage_v(self) -> float:
        return self.cells * (3.5 + 0.7 * self.remaining)

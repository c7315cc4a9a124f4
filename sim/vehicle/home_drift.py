"""PX4's in-flight home altitude correction, driven by SIH's sensor noise: how far home moves, when, how often.

Real PX4 (commander ``HomePosition::update``, COM_HOME_EN 1, the default) keeps correcting home's altitude for
``kHomePositionCorrectionTimeWindow`` (120 s) after take-off. On each GPS sample it compares the barometer (offset
to the GPS altitude of the first sample after take-off) with the *raw* GPS altitude; when the barometer agrees better
with the integral of the GPS vertical velocity than either agrees with the raw GPS altitude, and the two differ by
more than 1 m from the last correction, home's altitude moves by that difference. PX4's barometer "low-pass" is handed
its sample interval in microseconds against a 5 s time constant, so it passes the raw sample through.

SIH feeds it (``sensor_gps_sim``, ``sensor_baro_sim``): GPS at 8 Hz with 0.5 m of white noise on the altitude and
0.158 m/s on the vertical velocity, the barometer at 20 Hz with 1 Pa RMS (0.083 m). So single GPS samples move
home, about once a second: real PX4 SIH moved it 69-169 times (median 135) in the window over 18 flights, swung it up to
-2.4 / +2.8 m off home at arming and left it wherever the last move put it (-0.81 .. +1.52 m), with no move after the
window (``tests/data/real-px4-sih-home.json``, from the flights' own logs). This class runs the same rule on the same
noise, seeded: a flight of the simulator's PX4 flavour moves home the way real SIH does, reproducibly.
"""

from __future__ import annotations

import math

import numpy as np

# commander HomePosition.hpp
PX4_HOME_CORRECTION_WINDOW_S = 120.0
ALTITUDE_DIFFERENCE_THRESHOLD_M = 1.0
# SIH's sensors (PX4 modules/simulation): sample intervals and noise
GPS_INTERVAL_S = 0.125
GPS_ALT_NOISE_M = 0.5
GPS_VEL_D_NOISE_M_S = 0.158
BARO_INTERVAL_S = 0.05
BARO_NOISE_M = 1.0 / 12.0  # 1 Pa RMS: about 12 Pa per metre near sea level


class Px4HomeCorrection:
    """Feed it the true altitude and vertical speed every physics step; ``shift_step`` says how far home moved."""

    def __init__(self, rng: np.random.Generator, window_s: float = PX4_HOME_CORRECTION_WINDOW_S):
        self.rng = rng
        self.window_s = window_s
        self.moves = 0
        self.reset()

    def reset(self) -> None:
        """A new flight (PX4 arms): no take-off seen yet, nothing applied, the velocity integral re-initialised."""
        self._takeoff_t: float | None = None
        self._integral: float | None = None
        self._static_offset = 0.0
        self._applied = 0.0
        self._baro: float | None = None
        self._next_baro_t = 0.0
        self._next_gps_t = 0.0
        self._last_gps_t: float | None = None

    def step(self, t_s: float, alt_m: float, vel_d_m_s: float, in_air: bool) -> float:
        """Advance to simulated time ``t_s`` with the vehicle's true altitude (up) and vertical speed (down);
        returns the change of home's altitude at this step (0.0 almost always; up positive)."""
        if in_air and self._takeoff_t is None:
            self._takeoff_t = t_s
        if t_s >= self._next_baro_t:
            self._baro = alt_m + BARO_NOISE_M * float(self.rng.standard_normal())
            self._next_baro_t = max(self._next_baro_t + BARO_INTERVAL_S, t_s)
        if t_s < self._next_gps_t:
            return 0.0
        self._next_gps_t = max(self._next_gps_t + GPS_INTERVAL_S, t_s)  # 8 Hz on average, whatever the step
        dt = 0.0 if self._last_gps_t is None else t_s - self._last_gps_t
        self._last_gps_t = t_s
        gps_alt = alt_m + GPS_ALT_NOISE_M * float(self.rng.standard_normal())
        gps_vel_d = vel_d_m_s + GPS_VEL_D_NOISE_M_S * float(self.rng.standard_normal())
        if self._takeoff_t is None or t_s - self._takeoff_t >= self.window_s or self._baro is None:
            self._integral = None
            return 0.0
        if self._integral is None:
            self._integral = gps_alt
            self._static_offset = gps_alt - self._baro
        self._integral += dt * -gps_vel_d  # PX4 integrates over the samples' time stamps
        baro = self._baro + self._static_offset
        gps_with_offset = gps_alt + self._applied
        agree = abs(baro - self._integral)
        if not (agree < abs(baro - gps_with_offset) and agree < abs(self._integral - gps_with_offset)):
            return 0.0
        offset_new = baro - gps_alt - self._applied
        if abs(offset_new) <= ALTITUDE_DIFFERENCE_THRESHOLD_M or not math.isfinite(offset_new):
            return 0.0
        self._applied = baro - gps_alt
        self.moves += 1
        return -offset_new


def hover_flight(seed: int, climb_m: float = 18.0, climb_m_s: float = 3.0, seconds: float = 131.0,
                 ground_alt_m: float = 30.0) -> tuple[int, float, float, float]:
    """The correction alone on a demo-like flight (take-off at 1 s, climb ``climb_m`` at ``climb_m_s``, hover) for
    ``seconds``: how many moves, how far home swung down and up, and where it ended (metres from home at arming).
    What ``tests/test_sim_vehicle_home.py`` and ``bench/home_moves.py`` hold against real SIH flights."""
    model = Px4HomeCorrection(np.random.default_rng(seed))
    dt, t, alt, shift, low, high = 0.02, 0.0, ground_alt_m, 0.0, 0.0, 0.0
    climb_end = 1.0 + climb_m / climb_m_s
    while t < seconds:
        t += dt
        vel_d = -climb_m_s if 1.0 < t < climb_end else 0.0
        alt -= vel_d * dt
        move = model.step(t, alt, vel_d, t > 1.0)
        if move:
            shift += move
            low, high = min(low, shift), max(high, shift)
    return model.moves, low, high, shift

"""Gain compensation: auto-exposure makes neighbouring keyframes differ in brightness, which shows as patches.

Each accepted pair measures the log brightness ratio of the same wall points in both keyframes; one gain per
keyframe is solved by least squares over all pairs (a weak pull towards gain 1 fixes the overall level).
"""

from __future__ import annotations

import cv2
import numpy as np

from companion.stitch.pairs import PairResult


def solve_gains(n: int, pairs: list[PairResult], *, prior_weight: float = 0.05, max_gain: float = 2.0) -> np.ndarray:
    """Multiplicative gains g (n,) such that g_i * I_i ~= g_j * I_j on every pair's inliers."""
    rows, rhs, wts = [], [], []
    for r in pairs:
        if r.accepted and r.lum_ratio is not None and np.isfinite(r.lum_ratio):
            row = np.zeros(n)
            row[r.i], row[r.j] = 1.0, -1.0  # log g_i - log g_j = -log(I_i / I_j)
            rows.append(row)
            rhs.append(-r.lum_ratio)
            wts.append(np.sqrt(min(r.inliers, 100)))
    for k in range(n):
        row = np.zeros(n)
        row[k] = 1.0
        rows.append(row)
        rhs.append(0.0)
        wts.append(prior_weight * 10.0)
    A = np.array(rows) * np.array(wts)[:, None]
    b = np.array(rhs) * np.array(wts)
    log_g, *_ = np.linalg.lstsq(A, b, rcond=None)
    return np.clip(np.exp(log_g), 1.0 / max_gain, max_gain)


def apply_gain(image: np.ndarray, gain: float) -> np.ndarray:
    """The image times ``gain``, rounded and saturated: one 256-entry lookup table (``cv2.LUT``), the same
    values as the per-pixel float computation (the reference renderer's, evaluation/stitch/reference_render.py)
    at a fraction of its cost on 4K keyframes."""
    if abs(gain - 1.0) < 1e-3:
        return image
    lut = np.clip(np.arange(256, dtype=np.float32) * gain + 0.5, 0, 255).astype(np.uint8)
    return cv2.LUT(image, lut)

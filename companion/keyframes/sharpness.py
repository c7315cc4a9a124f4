"""Sharpness of a frame inside its ROI: variance of the Laplacian, so the gate can pass over a blurred candidate.

The absolute value depends on the wall's texture, so the gate only compares it with its recent neighbours
(a running reference), never with a fixed number.
"""

from __future__ import annotations

import cv2
import numpy as np


def laplacian_variance(gray: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Variance of the 3x3 Laplacian over the ROI pixels (the whole frame when ``mask`` is None).

    The mask is eroded by the kernel reach so the ROI border itself (a step to black) does not count as detail.
    Measured one octave down (pyrDown): single-pixel grain and sub-pixel resampling change the full-resolution
    value by 2x from frame to frame, while motion or focus blur of a few pixels still drops it 4-20x.
    Returns 0.0 for an ROI with fewer than 16 pixels.
    """
    small = cv2.pyrDown(gray)
    lap = cv2.Laplacian(small, cv2.CV_32F, ksize=3)
    if mask is None:
        return float(lap.var())
    small_mask = cv2.resize(mask, (small.shape[1], small.shape[0]), interpolation=cv2.INTER_NEAREST)
    inner = cv2.erode((small_mask > 127).astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    if int(inner.sum()) < 16:
        return 0.0
    return float(lap[inner].var())


class SharpnessReference:
    """Running reference sharpness of recent frames (exponential moving average of the log value).

    A frame is "blurred" when its sharpness falls below ``blur_ratio`` times the reference. The log average keeps
    one very sharp or very dull frame from swinging the reference.
    """

    def __init__(self, blur_ratio: float = 0.6, smoothing: float = 0.2):
        self.blur_ratio = blur_ratio
        self.smoothing = smoothing
        self._log_ref: float | None = None

    @property
    def value(self) -> float | None:
        return None if self._log_ref is None else float(np.exp(self._log_ref))

    def is_blurred(self, sharpness: float) -> bool:
        ref = self.value
        return ref is not None and sharpness < self.blur_ratio * ref

    def update(self, sharpness: float) -> None:
        v = float(np.log(max(sharpness, 1e-6)))
        self._log_ref = v if self._log_ref is None else (1 - self.smoothing) * self._log_ref + self.smoothing * v

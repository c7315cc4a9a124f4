"""Pictures of what the mask did: frame | disparity | masked frame (| true mask), for a person to look at.

The product's ``companion depth run`` draws them for image files; the evaluation draws them with the truth.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np


def colour_disparity(disp: np.ndarray) -> np.ndarray:
    """Disparity as a colour image (bright/yellow = near), normalised to its own 1st..99th percentile."""
    lo, hi = np.percentile(disp, [1, 99])
    norm = np.clip((disp - lo) / max(hi - lo, 1e-9), 0, 1)
    return cv2.applyColorMap((norm * 255).astype(np.uint8), cv2.COLORMAP_INFERNO)


def save_visual(path: Path, image: np.ndarray, disp: np.ndarray, mask: np.ndarray, truth: np.ndarray | None) -> None:
    """One picture per frame: frame | disparity | masked frame (| true mask), at 640 px width each."""
    path.parent.mkdir(parents=True, exist_ok=True)
    w = 640
    h = int(round(image.shape[0] * w / image.shape[1]))
    tiles = [
        cv2.resize(image, (w, h), interpolation=cv2.INTER_AREA),
        cv2.resize(colour_disparity(disp), (w, h)),
        cv2.resize(cv2.bitwise_and(image, image, mask=mask), (w, h), interpolation=cv2.INTER_AREA),
    ]
    if truth is not None:
        tiles.append(cv2.cvtColor(cv2.resize(truth, (w, h), interpolation=cv2.INTER_NEAREST), cv2.COLOR_GRAY2BGR))
    cv2.imwrite(str(path), np.hstack(tiles))

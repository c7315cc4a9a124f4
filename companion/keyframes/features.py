"""SIFT features of one ROI frame, extracted once on a downscaled working copy and cached by the gate.

Why a working copy: SIFT cost grows with pixel count, and the overlap ratio only needs the mean displacement,
which a 960 px copy measures to well under a full-resolution percent. Keypoints are kept in working pixels
together with the scale, so callers convert displacements back to full-resolution pixels.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from companion.errors import CompanionError


@dataclass(frozen=True)
class FeatureConfig:
    """How features are extracted. ``long_side_px`` <= 0 means full resolution."""

    long_side_px: int = 960
    max_features: int = 2000  # enough for R to 0.1 pt; 4000 costs 2x extraction and 4x matching CPU
    contrast_threshold: float = 0.01  # below OpenCV's 0.04: facade walls are low-contrast
    equalize: bool = True  # CLAHE before SIFT: plain concrete gives 10x more matchable features
    clahe_clip: float = 3.0
    mask_erode_px: int = 3  # keep keypoints away from the ROI border (its edge is not wall texture)

    def __post_init__(self) -> None:
        if self.max_features < 8:
            raise CompanionError(
                f"max_features={self.max_features} is too small to estimate a homography",
                "use at least a few hundred features (default 2000)",
            )


@dataclass
class FeatureSet:
    """Keypoints (working pixels, N x 2 float32) and SIFT descriptors (N x 128 float32) of one frame."""

    points: np.ndarray
    descriptors: np.ndarray | None
    scale: float  # working px per full-resolution px
    full_size: tuple[int, int]  # (width, height) of the full-resolution frame
    work_gray: np.ndarray  # working-resolution grey image (for sharpness); small by construction
    work_mask: np.ndarray | None  # working-resolution ROI mask (0/255) or None for the whole frame

    def __len__(self) -> int:
        return int(self.points.shape[0])


def _to_gray(image: np.ndarray) -> np.ndarray:
    if image is None or not isinstance(image, np.ndarray) or image.size == 0:
        raise CompanionError("frame image is empty", "pass a BGR uint8 image (H x W x 3) or a grey image (H x W)")
    if image.ndim == 3 and image.shape[2] == 3:
        gray = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    elif image.ndim == 3 and image.shape[2] == 4:
        gray = cv2.cvtColor(image, cv2.COLOR_BGRA2GRAY)
    elif image.ndim == 2:
        gray = image
    else:
        raise CompanionError(
            f"frame image has shape {image.shape}", "pass a BGR uint8 image (H x W x 3) or a grey image (H x W)"
        )
    if gray.dtype != np.uint8:
        raise CompanionError(f"frame image has dtype {gray.dtype}", "convert the image to uint8 (0..255) first")
    return gray


def working_scale(width: int, height: int, long_side_px: int) -> float:
    """Scale factor (<= 1) that brings the frame's long side down to ``long_side_px``."""
    long_side = max(width, height)
    if long_side_px <= 0 or long_side <= long_side_px:
        return 1.0
    return long_side_px / long_side


class FeatureExtractor:
    """Holds one SIFT detector (creating it costs time) and turns (image, mask) into a FeatureSet."""

    def __init__(self, config: FeatureConfig | None = None):
        self.config = config or FeatureConfig()
        self._sift = cv2.SIFT_create(
            nfeatures=self.config.max_features, contrastThreshold=self.config.contrast_threshold
        )
        self._clahe = cv2.createCLAHE(clipLimit=self.config.clahe_clip, tileGridSize=(8, 8))

    def extract(self, image: np.ndarray, mask: np.ndarray | None = None) -> FeatureSet:
        gray = _to_gray(image)
        h, w = gray.shape
        if mask is not None:
            if mask.shape[:2] != (h, w):
                raise CompanionError(
                    f"ROI mask is {mask.shape[1]}x{mask.shape[0]} but the frame is {w}x{h}",
                    "give the mask at full frame resolution (MaskedFrame.mask), 255 = facade",
                )
            if mask.ndim == 3:
                mask = mask[:, :, 0]
        s = working_scale(w, h, self.config.long_side_px)
        if s < 1.0:
            size = (max(1, round(w * s)), max(1, round(h * s)))
            work = cv2.resize(gray, size, interpolation=cv2.INTER_AREA)
            work_mask = None if mask is None else cv2.resize(mask, size, interpolation=cv2.INTER_NEAREST)
        else:
            work, work_mask = gray, mask
        det_mask = None
        if work_mask is not None:
            det_mask = (work_mask > 127).astype(np.uint8) * 255
            if self.config.mask_erode_px > 0:
                k = 2 * self.config.mask_erode_px + 1
                det_mask = cv2.erode(det_mask, np.ones((k, k), np.uint8))
        detect_on = self._clahe.apply(work) if self.config.equalize else work
        keypoints, descriptors = self._sift.detectAndCompute(detect_on, det_mask)
        points = np.array([kp.pt for kp in keypoints], dtype=np.float32).reshape(-1, 2)
        return FeatureSet(
            points=points,
            descriptors=descriptors,
            scale=s,
            full_size=(w, h),
            work_gray=work,
            work_mask=det_mask,
        )

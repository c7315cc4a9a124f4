"""Synthetic wall views with exactly known overlap, for the gate's tests, benchmarks and a no-simulator eval.

A large procedurally textured "wall" image is viewed by a virtual camera that translates, rotates and zooms
(a similarity transform, i.e. a fronto-parallel camera at a varying standoff). The true overlap of two views is
the area of view A's footprint on the wall covered by view B's footprint, divided by A's footprint area: the
same definition as the simulator's ``true_overlap``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from companion.keyframes.overlap import convex_intersection_area
from companion.records import Frame, MaskedFrame, TaggedFrame


def textured_wall(width: int, height: int, seed: int = 0) -> np.ndarray:
    """A BGR wall texture: multi-octave noise (stains, render), a block pattern (panels) and fine grain."""
    rng = np.random.default_rng(seed)
    acc = np.zeros((height, width), np.float32)
    for octave, weight in ((256, 0.35), (64, 0.25), (16, 0.25), (4, 0.15)):
        small = rng.random((max(2, height // octave), max(2, width // octave))).astype(np.float32)
        acc += weight * cv2.resize(small, (width, height), interpolation=cv2.INTER_CUBIC)
    # Panels with slightly different shades and dark joints, like cladding or brickwork at a coarse scale.
    pw, ph = 97, 61
    shade = rng.normal(0.0, 0.06, size=(height // ph + 2, width // pw + 2)).astype(np.float32)
    yy = np.arange(height, dtype=np.int32)[:, None]  # broadcast, not full-size index grids: big walls fit
    xx = np.arange(width, dtype=np.int32)[None, :]
    offset = ((yy // ph) % 2) * (pw // 2)
    acc += shade[yy // ph, (xx + offset) // pw]
    acc -= 0.25 * (((yy % ph) < 3) | (((xx + offset) % pw) < 3))
    acc += rng.normal(0.0, 0.03, size=acc.shape).astype(np.float32)
    del yy, xx, offset
    gray = cv2.normalize(acc, None, 20, 235, cv2.NORM_MINMAX).astype(np.uint8)
    tint = np.array([0.92, 0.97, 1.0], np.float32)  # warm grey
    return np.clip(gray[:, :, None].astype(np.float32) * tint, 0, 255).astype(np.uint8)


@dataclass(frozen=True)
class View:
    """A camera footprint on the wall texture: centre (texture px), rotation (deg) and zoom (texture px per px)."""

    cx: float
    cy: float
    width: int
    height: int
    angle_deg: float = 0.0
    zoom: float = 1.0

    def image_to_texture(self) -> np.ndarray:
        """2x3 affine matrix mapping image pixel coordinates to texture coordinates."""
        c, s = math.cos(math.radians(self.angle_deg)), math.sin(math.radians(self.angle_deg))
        a = self.zoom * np.array([[c, -s], [s, c]])
        t = np.array([self.cx, self.cy]) - a @ np.array([self.width / 2.0, self.height / 2.0])
        return np.hstack([a, t[:, None]])

    def corners(self) -> np.ndarray:
        m = self.image_to_texture()
        rect = np.array([[0, 0, 1], [self.width, 0, 1], [self.width, self.height, 1], [0, self.height, 1]], float)
        return (rect @ m.T).astype(np.float32)


def render(texture: np.ndarray, view: View, blur_sigma: float = 0.0) -> np.ndarray:
    img = cv2.warpAffine(
        texture,
        view.image_to_texture(),
        (view.width, view.height),
        flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
        borderMode=cv2.BORDER_REFLECT,
    )
    if blur_sigma > 0:
        img = cv2.GaussianBlur(img, (0, 0), blur_sigma)
    return img


def true_overlap(a: View, b: View) -> float:
    """Share (0..1) of A's wall footprint that B also shows."""
    area = convex_intersection_area(b.corners(), a.corners())
    return area / float(cv2.contourArea(a.corners()))


def masked_frame(index: int, image: np.ndarray, mask: np.ndarray | None = None, t_s: float | None = None):
    """Wrap an image as the gate's input record (mask all-facade when None)."""
    if mask is None:
        mask = np.full(image.shape[:2], 255, np.uint8)
    frame = Frame(index=index, capture_time_s=float(index) / 30.0 if t_s is None else t_s, image=image)
    return MaskedFrame(tagged=TaggedFrame(frame=frame, pose=None), mask=mask)


def sweep(
    texture: np.ndarray, n: int, step_px: float, width: int, height: int, *, start_x: float | None = None,
    y: float | None = None, jitter_px: float = 0.0, seed: int = 0,
) -> list[View]:
    """Views moving right by ``step_px`` texture px per frame (a horizontal scan leg), optional hand jitter."""
    rng = np.random.default_rng(seed)
    x0 = width / 2.0 + 8 if start_x is None else start_x
    y0 = texture.shape[0] / 2.0 if y is None else y
    return [
        View(x0 + i * step_px + rng.normal(0, jitter_px), y0 + rng.normal(0, jitter_px), width, height)
        for i in range(n)
    ]


def lawnmower(
    n: int, step_px: float, width: int, height: int, texture_shape: tuple[int, ...], *, zoom: float = 1.0,
    margin_px: float = 8.0,
) -> list[View]:
    """``n`` views in horizontal passes joined by vertical moves, each ``step_px`` texture px from the last.

    A continuous serpentine path (no jumps), so a long pass fits a texture a few frames wide.
    """
    th, tw = texture_shape[:2]
    half_w, half_h = zoom * width / 2 + margin_px, zoom * height / 2 + margin_px
    x, y, direction = half_w, half_h, 1.0
    row_target = None
    views = []
    for _ in range(n):
        views.append(View(x, y, width, height, zoom=zoom))
        if row_target is not None:  # moving down to the next pass
            y = min(row_target, y + step_px)
            if y >= row_target:
                row_target, direction = None, -direction
            continue
        nx = x + direction * step_px
        if half_w <= nx <= tw - half_w:
            x = nx
        else:
            row_target = y + zoom * height * 0.5
            if row_target > th - half_h:
                raise ValueError("texture too small for this many views")
            y = min(row_target, y + step_px)
    return views

"""What the worker hands the engineer: coverage analysis (where to re-fly), a scale bar, and the preview."""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from companion.stitch.render import MapGrid


@dataclass(frozen=True)
class UncoveredArea:
    """An axis-aligned box on the wall (metres) that no keyframe shows: a re-fly target."""

    along_min_m: float
    along_max_m: float
    up_min_m: float
    up_max_m: float
    area_m2: float

    def as_dict(self) -> dict:
        return {k: round(v, 3) for k, v in self.__dict__.items()}


def uncovered_areas(
    coverage: np.ndarray,
    grid: MapGrid,
    region_px: tuple[int, int, int, int],
    *,
    cell_m: float = 0.1,
    min_area_m2: float = 0.02,
) -> list[UncoveredArea]:
    """Uncovered parts of ``region_px`` (x0, y0, x1, y1 in ``coverage`` pixels) as wall rectangles in metres.

    ``coverage`` (0/255) spans the whole map, possibly downscaled. The region is cut into ``cell_m`` cells; a
    cell at least half uncovered is a hole; holes are merged greedily into maximal rectangles (a thin ring of
    missing edge and a missing window do not become one useless box covering the whole wall).
    """
    sx = grid.width / coverage.shape[1]
    x0, y0, x1, y1 = region_px
    cell_px = max(1, int(round(cell_m / (grid.m_per_px * sx))))
    nx, ny = -(-(x1 - x0) // cell_px), -(-(y1 - y0) // cell_px)
    sub = (coverage[y0:y1, x0:x1] == 0).astype(np.float32)
    pad = np.zeros((ny * cell_px, nx * cell_px), np.float32)
    pad[: sub.shape[0], : sub.shape[1]] = sub
    frac = pad.reshape(ny, cell_px, nx, cell_px).mean(axis=(1, 3))
    # cells cut by the region edge count only their inside part
    inside = np.zeros_like(pad)
    inside[: sub.shape[0], : sub.shape[1]] = 1.0
    frac = frac / np.maximum(inside.reshape(ny, cell_px, nx, cell_px).mean(axis=(1, 3)), 1e-9)
    hole = frac >= 0.5
    used = np.zeros_like(hole)
    out = []
    for r in range(ny):
        for c in range(nx):
            if not hole[r, c] or used[r, c]:
                continue
            c1 = c
            while c1 + 1 < nx and hole[r, c1 + 1] and not used[r, c1 + 1]:
                c1 += 1
            r1 = r
            while r1 + 1 < ny and np.all(hole[r1 + 1, c : c1 + 1] & ~used[r1 + 1, c : c1 + 1]):
                r1 += 1
            used[r : r1 + 1, c : c1 + 1] = True
            px0 = np.array([(x0 + c * cell_px) * sx, (y0 + r * cell_px) * sx])
            px1 = np.array([min(x1, x0 + (c1 + 1) * cell_px) * sx, min(y1, y0 + (r1 + 1) * cell_px) * sx])
            a0, up1 = grid.to_plane(px0)
            a1, up0 = grid.to_plane(px1)
            area = float((a1 - a0) * (up1 - up0))
            if area >= min_area_m2:
                out.append(UncoveredArea(float(a0), float(a1), float(up0), float(up1), area))
    return sorted(out, key=lambda u: (u.along_min_m, -u.up_max_m))


def nice_length_m(max_m: float) -> float:
    """Largest 1/2/5 x 10^k metres not above ``max_m``."""
    if max_m <= 0:
        return 0.0
    e = math.floor(math.log10(max_m))
    for f in (5, 2, 1):
        if f * 10**e <= max_m:
            return f * 10**e
    return 10 ** (e - 1)


def draw_scale_bar(image: np.ndarray, m_per_px: float | None, *, label_unit: str = "m") -> np.ndarray:
    """Appends a white strip under the map with a scale bar (the map pixels themselves stay untouched)."""
    h, w = image.shape[:2]
    strip_h = max(40, h // 20)
    strip = np.full((strip_h, w, 3), 255, np.uint8)
    font_scale = strip_h / 60.0
    if m_per_px:
        length_m = nice_length_m(0.3 * w * m_per_px)
        bar_px = int(round(length_m / m_per_px))
        x0, y = int(0.03 * w), strip_h // 2
        thick = max(2, strip_h // 8)
        cv2.rectangle(strip, (x0, y - thick), (x0 + bar_px, y + thick), (0, 0, 0), -1)
        for k in range(1, 5):  # alternating ticks every fifth
            if k % 2:
                xa, xb = x0 + bar_px * k // 5, x0 + bar_px * (k + 1) // 5
                cv2.rectangle(strip, (xa, y - thick + 2), (xb, y + thick - 2), (255, 255, 255), -1)
        text = f"{length_m:g} m   ({m_per_px * 1000:.2f} mm/px)"
        cv2.putText(
            strip,
            text,
            (x0 + bar_px + 15, y + thick),
            cv2.FONT_HERSHEY_SIMPLEX,
            font_scale,
            (0, 0, 0),
            max(1, strip_h // 25),
            cv2.LINE_AA,
        )
    else:
        cv2.putText(
            strip,
            "scale unknown (no camera pose or standoff)",
            (10, strip_h // 2 + 5),
            cv2.FONT_HERSHEY_SIMPLEX,
            font_scale,
            (0, 0, 0),
            1,
            cv2.LINE_AA,
        )
    return np.vstack((image, strip))


def annotate_uncovered(preview: np.ndarray, grid: MapGrid, areas: list[UncoveredArea]) -> np.ndarray:
    """Outlines re-fly areas in red on a (possibly downscaled) preview of the map."""
    out = preview.copy()
    s = preview.shape[1] / grid.width
    for a in areas:
        p0 = grid.to_px(np.array([a.along_min_m, a.up_max_m])) * s
        p1 = grid.to_px(np.array([a.along_max_m, a.up_min_m])) * s
        cv2.rectangle(
            out,
            tuple(int(round(v)) for v in p0),
            tuple(int(round(v)) for v in p1),
            (0, 0, 255),
            max(1, preview.shape[1] // 800),
        )
    return out

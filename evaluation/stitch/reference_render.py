"""The per-pixel reference renderer the product's OpenCV renderer is held to (tests/test_stitch_render.py).

It is the render stage as it was before ``companion/stitch/render.py`` drew each mesh cell with
``cv2.warpPerspective``: every map pixel of a region is pulled back through its cell's homography in numpy (a 3x3
matrix gathered per pixel), the keyframe sampled with ``cv2.remap``, and the seams blended per pixel in numpy.
Tiles are drawn row by row with every keyframe whose box reaches the tile (no render plan, no blend-weight cut),
the gains applied per pixel in float. Slow, simple and independent of the fast path's optimisations: where the
two maps agree, those optimisations changed nothing. The product never imports it (tests/test_dependencies.py).
"""

from __future__ import annotations

import cv2
import numpy as np

from companion.stitch.align import AlignedKeyframes
from companion.stitch.config import StitchConfig
from companion.stitch.exposure import solve_gains
from companion.stitch.features import load_image_and_mask
from companion.stitch.inputs import StitchInput
from companion.stitch.layout import MapLayout
from companion.stitch.render import PlacedKeyframe, SourceCache, region_quads


def apply_gain_numpy(image: np.ndarray, gain: float) -> np.ndarray:
    """The image times ``gain``, rounded and saturated, per pixel in float (the product's ``apply_gain`` is a
    lookup table of the same values)."""
    if abs(gain - 1.0) < 1e-3:
        return image
    return np.clip(image.astype(np.float32) * gain + 0.5, 0, 255).astype(np.uint8)


def pullback(pk: PlacedKeyframe, x0: int, y0: int, w: int, h: int) -> tuple[np.ndarray, np.ndarray] | None:
    """Per map pixel of the region, the keyframe pixel it shows (-1 outside the mesh), from the cell label of every
    pixel and its cell's homography in numpy."""
    label = np.zeros((h, w), np.int32)
    for k, quad in region_quads(pk, x0, y0, w, h):
        cv2.fillConvexPoly(label, np.round(quad * 16).astype(np.int32), k + 1, lineType=cv2.LINE_8, shift=4)
    ys, xs = np.nonzero(label)
    if len(xs) == 0:
        return None
    Hinv = pk.cell_inv[label[ys, xs] - 1]
    u, v = xs + float(x0), ys + float(y0)
    den = Hinv[:, 2, 0] * u + Hinv[:, 2, 1] * v + Hinv[:, 2, 2]
    sx = (Hinv[:, 0, 0] * u + Hinv[:, 0, 1] * v + Hinv[:, 0, 2]) / den
    sy = (Hinv[:, 1, 0] * u + Hinv[:, 1, 1] * v + Hinv[:, 1, 2]) / den
    mx = np.full((h, w), -1.0, np.float32)
    my = np.full((h, w), -1.0, np.float32)
    mx[ys, xs], my[ys, xs] = sx, sy
    return mx, my


def render_tile_pullback(
    x0: int, y0: int, w: int, h: int, placed: list[PlacedKeyframe], sources: SourceCache, *, feather_px: float = 4.0
) -> tuple[np.ndarray, np.ndarray]:
    """(BGR uint8 tile, coverage uint8 0/255) for one map region, as the product's ``render_tile`` draws it."""
    layers = []
    for pk in placed:
        bx0, by0, bx1, by1 = pk.bbox
        rx0, ry0, rx1, ry1 = max(bx0, x0), max(by0, y0), min(bx1, x0 + w), min(by1, y0 + h)
        if rx1 <= rx0 or ry1 <= ry0:
            continue
        maps = pullback(pk, rx0, ry0, rx1 - rx0, ry1 - ry0)
        if maps is None:
            continue
        img, weight = sources.get(pk.position)
        mx, my = maps
        nearest = cv2.remap(weight, mx, my, cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        m = nearest > 0  # the ROI mask's nearest pixel
        if not m.any():
            continue
        im = cv2.remap(img, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        d = cv2.remap(weight, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        d = np.where(m, np.maximum(d, 1e-3), 0.0).astype(np.float32)
        layers.append(((rx0 - x0, ry0 - y0), im, d))
    out = np.zeros((h, w, 3), np.float32)
    if not layers:
        return out.astype(np.uint8), np.zeros((h, w), np.uint8)
    dmax = np.zeros((h, w), np.float32)
    for (ox, oy), _im, d in layers:
        sl = (slice(oy, oy + d.shape[0]), slice(ox, ox + d.shape[1]))
        dmax[sl] = np.maximum(dmax[sl], d)
    wsum = np.zeros((h, w), np.float32)
    for (ox, oy), im, d in layers:
        sl = (slice(oy, oy + d.shape[0]), slice(ox, ox + d.shape[1]))
        wgt = np.where(d > 0, np.exp((d - dmax[sl]) / max(feather_px, 1e-3)), 0.0).astype(np.float32)
        out[sl] += im.astype(np.float32) * wgt[..., None]
        wsum[sl] += wgt
    covered = wsum > 0
    out[covered] /= wsum[covered][:, None]
    return np.clip(out + 0.5, 0, 255).astype(np.uint8), np.where(covered, 255, 0).astype(np.uint8)


def render_map_pullback(
    inp: StitchInput, aligned: AlignedKeyframes, layout: MapLayout, cfg: StitchConfig
) -> tuple[np.ndarray, np.ndarray]:
    """(BGR map, coverage 0/255) of a stitch's layout drawn by the reference: the render stage's inputs (the ones
    ``Stitcher.render`` gets), tiles row by row, each with every keyframe whose box reaches it."""
    kfs = inp.keyframes
    gains = solve_gains(len(kfs), aligned.accepted) if cfg.gain_compensation else np.ones(len(kfs))

    def load(k):
        img, mask = load_image_and_mask(kfs[k])
        return apply_gain_numpy(img, float(gains[k])), mask

    sources = SourceCache(load, size=8)
    gw, gh = layout.grid.width, layout.grid.height
    order = sorted(layout.placed.values(), key=lambda p: p.bbox[0])
    canvas = np.zeros((gh, gw, 3), np.uint8)
    coverage = np.zeros((gh, gw), np.uint8)
    for y0 in range(0, gh, cfg.tile_px):
        for x0 in range(0, gw, cfg.tile_px):
            w, h = min(cfg.tile_px, gw - x0), min(cfg.tile_px, gh - y0)
            near = [p for p in order if p.bbox[0] < x0 + w and p.bbox[2] > x0 and p.bbox[1] < y0 + h and p.bbox[3] > y0]
            img, cov = render_tile_pullback(x0, y0, w, h, near, sources, feather_px=cfg.feather_px)
            canvas[y0 : y0 + h, x0 : x0 + w], coverage[y0 : y0 + h, x0 : x0 + w] = img, cov
    return canvas, coverage

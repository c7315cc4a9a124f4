"""Which keyframes each map tile needs, and the tile order that decodes each keyframe the fewest times.

At 80 % overlap every map pixel lies inside ~5 keyframes (10-17 per 1024 px tile of 4K keyframes), but the
feathered Voronoi seam draws only the one or two whose seam weight is within ``feather * ln(1 / MIN_BLEND_WEIGHT)``
of the best. Decoding a 4K keyframe and its seam weight costs more than drawing it, and only a few fit in memory,
so drawing tile by tile with every overlapping keyframe re-decodes each one several times (5.3x on the 35-keyframe
4K bench). A planning pass over the seam weights alone, at 1/8 resolution, bounds every keyframe's weight and
the best weight per block from above and below; a keyframe is kept for a tile only where its upper bound reaches
the best lower bound minus the feather cut-off, so the map is exactly the one drawn with every keyframe.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass

import cv2
import numpy as np

from companion.stitch.render import MIN_BLEND_WEIGHT, PlacedKeyframe, next_use, request_indices

Tile = tuple[int, int]


@dataclass(frozen=True)
class RenderPlan:
    order: list[Tile]  # top-left corners of the tiles, in drawing order
    needs: dict[Tile, set[int]]  # per tile, the positions of the keyframes that can be drawn there
    decodes: int  # keyframe decodes this order costs with the renderer's cache


def _block_bounds(weight: np.ndarray, block: int) -> tuple[np.ndarray, np.ndarray]:
    """Max and min of the seam weight over block x block pixels (the image's edge blocks padded with 0).

    Reduced first across the block's rows (numpy, whole-row operations), then across its columns (OpenCV's row
    reduction over each block's ``block`` values: numpy reduces such a short last axis pixel by pixel, and that
    pass was half the planning pass's time at 4K). One 4D reduction over both axes is 10x slower."""
    h, w = weight.shape
    ph, pw = -(-h // block) * block, -(-w // block) * block
    padded = cv2.copyMakeBorder(weight, 0, ph - h, 0, pw - w, cv2.BORDER_CONSTANT, value=0)
    rows = padded.reshape(ph // block, block, pw)
    shape = (ph // block, pw // block)
    hi = cv2.reduce(rows.max(axis=1).reshape(-1, block), 1, cv2.REDUCE_MAX).reshape(shape)
    lo = cv2.reduce(rows.min(axis=1).reshape(-1, block), 1, cv2.REDUCE_MIN).reshape(shape)
    return hi, lo


def _to_block(block: float) -> np.ndarray:
    """Pixel -> block index of a grid of ``block`` px blocks (block centres at integer indices)."""
    return np.array([[1.0 / block, 0.0, 0.5 / block - 0.5], [0.0, 1.0 / block, 0.5 / block - 0.5], [0, 0, 1.0]])


def _warp_bounds(pk: PlacedKeyframe, hi: np.ndarray, lo: np.ndarray, k_block: int, m_block: int, shape):
    """The keyframe's block bounds drawn onto the block map through its mesh: (x, y, upper, lower) over its box."""
    gh, gw = shape
    x0, y0 = int(pk.bbox[0] // m_block), int(pk.bbox[1] // m_block)
    x1, y1 = min(gw, -(-pk.bbox[2] // m_block)), min(gh, -(-pk.bbox[3] // m_block))
    w, h = x1 - x0, y1 - y0
    up = np.zeros((h, w), np.float32)
    low = np.zeros((h, w), np.float32)
    cy, cx = pk.src_px.shape[0] - 1, pk.src_px.shape[1] - 1
    to_map_block = _to_block(m_block)
    from_map_block = np.linalg.inv(to_map_block)
    to_k_block = _to_block(k_block)
    m = pk.mesh_px
    for r in range(cy):
        for c in range(cx):
            quad = np.array([m[r, c], m[r, c + 1], m[r + 1, c + 1], m[r + 1, c]])
            q = (quad + 0.5) / m_block - 0.5 - np.array([x0, y0])
            bx0, by0 = max(int(np.floor(q[:, 0].min())) - 1, 0), max(int(np.floor(q[:, 1].min())) - 1, 0)
            bx1, by1 = min(int(np.ceil(q[:, 0].max())) + 2, w), min(int(np.ceil(q[:, 1].max())) + 2, h)
            if bx1 <= bx0 or by1 <= by0:
                continue
            inside = np.zeros((by1 - by0, bx1 - bx0), np.uint8)
            cv2.fillConvexPoly(inside, np.round((q - [bx0, by0]) * 16).astype(np.int32), 255, cv2.LINE_8, shift=4)
            shift = np.array([[1.0, 0, x0 + bx0], [0, 1.0, y0 + by0], [0, 0, 1.0]])
            M = to_k_block @ pk.cell_inv[r * cx + c] @ from_map_block @ shift
            size = (bx1 - bx0, by1 - by0)
            flags = cv2.INTER_NEAREST | cv2.WARP_INVERSE_MAP
            wu = cv2.warpPerspective(hi, M, size, flags=flags, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
            wl = cv2.warpPerspective(lo, M, size, flags=flags, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
            box_u, box_l = up[by0:by1, bx0:bx1], low[by0:by1, bx0:bx1]
            cv2.copyTo(cv2.max(box_u, wu), inside, box_u)
            cv2.copyTo(wl, inside, box_l)
    # a block of the map sees parts of up to 2 x 2 keyframe blocks around the one its centre samples, and the
    # quads are rasterised by block centres: widen the upper bound and narrow the lower bound by one block
    kernel = np.ones((3, 3), np.uint8)
    up = cv2.dilate(up, kernel, borderType=cv2.BORDER_CONSTANT, borderValue=0)
    low = cv2.erode(low, kernel, borderType=cv2.BORDER_CONSTANT, borderValue=0)
    return x0, y0, up, low


def plan_render(
    placed: list[PlacedKeyframe],
    weights: Iterable[np.ndarray],
    width: int,
    height: int,
    tile_px: int,
    feather_px: float,
    cache_size: int,
    *,
    block_px: int = 8,
) -> RenderPlan:
    """``weights``: the full-resolution seam weight (render.drawable) of each of ``placed``, in that order (an
    iterator is read one at a time: each weight is reduced to block bounds and dropped)."""
    shape = (-(-height // block_px), -(-width // block_px))
    best_low = np.zeros(shape, np.float32)
    bounds = []
    for pk, weight in zip(placed, weights, strict=True):
        src_cell = np.linalg.norm(pk.src_px[0, 1] - pk.src_px[0, 0])
        dst_cell = np.median(np.linalg.norm(np.diff(pk.mesh_px, axis=1), axis=2))
        k_block = max(1, round(block_px * src_cell / max(dst_cell, 1e-9)))  # the same area in keyframe pixels
        hi, lo = _block_bounds(weight, k_block)
        x0, y0, up, low = _warp_bounds(pk, hi, lo, k_block, block_px, shape)
        box = best_low[y0 : y0 + low.shape[0], x0 : x0 + low.shape[1]]
        cv2.max(box, low, dst=box)
        bounds.append((pk.position, x0, y0, up))
    cut = feather_px * math.log(1.0 / MIN_BLEND_WEIGHT) + 1.0  # + 1 px: float rounding at the renderer's cut
    xs, ys = list(range(0, width, tile_px)), list(range(0, height, tile_px))
    needs: dict[Tile, set[int]] = {(x, y): set() for y in ys for x in xs}
    for pos, x0, y0, up in bounds:
        best = best_low[y0 : y0 + up.shape[0], x0 : x0 + up.shape[1]]
        by, bx = np.nonzero((up > 0) & (up >= best - cut))
        if len(bx) == 0:
            continue
        # every tile a candidate block touches (a block can straddle two tiles when tile_px % block_px != 0)
        tx = np.concatenate(((x0 + bx) * block_px // tile_px, ((x0 + bx + 1) * block_px - 1) // tile_px))
        ty = np.concatenate(((y0 + by) * block_px // tile_px, ((y0 + by + 1) * block_px - 1) // tile_px))
        for t in set(zip(tx.tolist(), ty.tolist(), strict=True)):
            tile = (t[0] * tile_px, t[1] * tile_px)
            if tile in needs:
                needs[tile].add(pos)
    order = best_order(width, height, tile_px, needs, cache_size)
    return RenderPlan(order, needs, decodes(order, needs, cache_size))


def best_order(width: int, height: int, tile_px: int, needs: dict[Tile, set[int]], cache_size: int) -> list[Tile]:
    """Rows, columns and both serpentines, simulated with the renderer's LRU cache: the one with fewest decodes."""
    xs, ys = list(range(0, width, tile_px)), list(range(0, height, tile_px))
    candidates = [
        [(x, y) for y in ys for x in xs],
        [(x, y) for x in xs for y in ys],
        [(x, y) for i, y in enumerate(ys) for x in (xs if i % 2 == 0 else xs[::-1])],
        [(x, y) for i, x in enumerate(xs) for y in (ys if i % 2 == 0 else ys[::-1])],
    ]
    return min(candidates, key=lambda order: decodes(order, needs, cache_size))


def requests(order: list[Tile], needs: dict[Tile, set[int]]) -> list[int]:
    """The keyframe requests drawing the tiles in ``order`` makes (ascending position within a tile)."""
    return [k for tile in order for k in sorted(needs.get(tile, ()))]


def decodes(order: list[Tile], needs: dict[Tile, set[int]], cache_size: int) -> int:
    """How many keyframe decodes drawing the tiles in ``order`` costs with the renderer's cache of ``cache_size``
    keyframes, which drops the one needed again furthest ahead (render.SourceCache with a schedule)."""
    seq = requests(order, needs)
    uses = request_indices(seq)
    cached: set[int] = set()
    count = 0
    for now, k in enumerate(seq):
        if k in cached:
            continue
        count += 1
        cached.add(k)
        if len(cached) > cache_size:
            cached.remove(max(cached - {k}, key=lambda j: next_use(uses, j, now)))
    return count


def needs_by_box(width: int, height: int, tile_px: int, boxes: dict[int, tuple[int, int, int, int]]):
    """Per tile, every keyframe whose map box overlaps it (what drawing without a plan decodes)."""
    needs: dict[Tile, set[int]] = {}
    for y in range(0, height, tile_px):
        for x in range(0, width, tile_px):
            needs[(x, y)] = {
                k for k, (a, b, c, d) in boxes.items() if a < x + tile_px and c > x and b < y + tile_px and d > y
            }
    return needs

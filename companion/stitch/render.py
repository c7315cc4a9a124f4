"""Draws keyframes onto the rectified map, tile by tile, so memory stays bounded for long facades.

Each keyframe is warped cell by cell with its mesh (every map pixel of a cell is pulled back through that
cell's homography), only through its ROI mask: background pixels are never drawn. Seams run where two
keyframes are equally far inside their valid areas (a Voronoi seam on the distance to the mask edge), and a
narrow feather of width ``feather_px`` hides residual steps without ghosting large areas.
"""

from __future__ import annotations

import bisect
import itertools
import math
from collections import OrderedDict
from collections.abc import Callable
from concurrent.futures import Executor, Future
from dataclasses import dataclass

import cv2
import numpy as np

from companion.stitch.mesh import WarpedMesh


@dataclass(frozen=True)
class MapGrid:
    """Plane (along_m, up_m) <-> map pixel (u right, v down): u = (along - along0)/s, v = (up_top - up)/s."""

    along0_m: float
    up_top_m: float
    m_per_px: float
    width: int
    height: int

    def to_px(self, plane: np.ndarray) -> np.ndarray:
        plane = np.asarray(plane, dtype=float)
        return np.stack(
            ((plane[..., 0] - self.along0_m) / self.m_per_px, (self.up_top_m - plane[..., 1]) / self.m_per_px), axis=-1
        )

    def to_plane(self, px: np.ndarray) -> np.ndarray:
        px = np.asarray(px, dtype=float)
        return np.stack(
            (self.along0_m + px[..., 0] * self.m_per_px, self.up_top_m - px[..., 1] * self.m_per_px), axis=-1
        )


@dataclass
class PlacedKeyframe:
    """A keyframe ready to draw: its mesh in map pixels and the inverse homography of every cell."""

    position: int
    mesh_px: np.ndarray  # (Cy+1, Cx+1, 2) vertices in map pixels
    src_px: np.ndarray  # (Cy+1, Cx+1, 2) vertices in the keyframe
    cell_inv: np.ndarray  # (Cy*Cx, 3, 3) map pixel -> keyframe pixel
    bbox: tuple[int, int, int, int]  # x0, y0, x1, y1 (exclusive) in map pixels, clipped to the map


def place(position: int, mesh: WarpedMesh, grid: MapGrid) -> PlacedKeyframe | None:
    dst = grid.to_px(mesh.dst_plane)
    src = mesh.src_px
    cy, cx = src.shape[0] - 1, src.shape[1] - 1
    inv = np.zeros((cy * cx, 3, 3))
    for r in range(cy):
        for c in range(cx):
            q_src = np.float32([src[r, c], src[r, c + 1], src[r + 1, c + 1], src[r + 1, c]])
            q_dst = np.float32([dst[r, c], dst[r, c + 1], dst[r + 1, c + 1], dst[r + 1, c]])
            inv[r * cx + c] = cv2.getPerspectiveTransform(q_dst, q_src)
    if not np.all(np.isfinite(dst)):
        return None
    x0, y0 = np.floor(dst.reshape(-1, 2).min(axis=0)).astype(int)
    x1, y1 = np.ceil(dst.reshape(-1, 2).max(axis=0)).astype(int) + 1
    x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, grid.width), min(y1, grid.height)
    if x1 <= x0 or y1 <= y0:
        return None
    return PlacedKeyframe(position, dst, src, inv, (int(x0), int(y0), int(x1), int(y1)))


def seam_weight(mask: np.ndarray) -> np.ndarray:
    """Distance (px) from each ROI pixel to the nearest background pixel or image border (float32; a view into the
    padded transform, which OpenCV reads as it is: no 4K copy per decode)."""
    padded = cv2.copyMakeBorder(mask, 1, 1, 1, 1, cv2.BORDER_CONSTANT, value=0)
    return cv2.distanceTransform(padded, cv2.DIST_L2, 3)[1:-1, 1:-1]


def drawable(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(the ROI that is drawn, its seam weight). One pixel of erosion: JPEG ringing and mask resampling at the
    ROI edge never reach the map."""
    mask = cv2.erode(mask, np.ones((3, 3), np.uint8))
    return mask, seam_weight(mask)


class SourceCache:
    """Decoded keyframes (image, seam weight), a few at a time, so tiles do not re-read every file. The drawn ROI
    is where the seam weight is > 0 (``drawable``): it is not kept beside it, so one more 4K keyframe fits in the
    same memory (46 decodes instead of 55 on the 35-keyframe 4K bench).

    With the ``schedule`` of requests known in advance (the render plan), a full cache drops the keyframe that
    is needed again furthest in the future (Belady's rule: the fewest decodes possible for that order);
    without one, or once the requests leave the schedule, the least recently used.

    With a ``prefetch`` executor and a schedule, the next keyframe the schedule will have to decode is decoded
    on that thread while the tiles before it are drawn (decoding a 4K keyframe and its seam weight is a third of
    the render's work, in OpenCV without the GIL): the same decodes in the same order, one more keyframe held."""

    def __init__(
        self,
        loader: Callable[[int], tuple[np.ndarray, np.ndarray]],
        size: int = 12,
        schedule: list[int] | None = None,
        prefetch: Executor | None = None,
    ):
        self.loader, self.size = loader, size
        self.decoded = 0  # how many times a keyframe was decoded (the render's main cost at 4K)
        self.items: OrderedDict[int, tuple[np.ndarray, np.ndarray]] = OrderedDict()
        self.schedule, self.step = schedule, 0
        self.uses = request_indices(schedule) if schedule is not None else {}
        self.prefetch = prefetch
        self.pending: dict[int, Future] = {}  # at most one: the next keyframe the schedule decodes

    def _decode(self, position: int) -> tuple[np.ndarray, np.ndarray]:
        img, mask = self.loader(position)
        return img, drawable(mask)[1]

    def get(self, position: int):
        now = self.step
        if self.schedule is not None and (now >= len(self.schedule) or self.schedule[now] != position):
            self.schedule = None  # off the plan: plain LRU from here on
        self.step += 1
        if position in self.items:
            self.items.move_to_end(position)
            self._prefetch_next(now)
            return self.items[position]
        ahead = self.pending.pop(position, None)
        item = ahead.result() if ahead is not None else self._decode(position)
        self.decoded += 1
        self.items[position] = item
        if len(self.items) > self.size:
            if self.schedule is None:
                self.items.popitem(last=False)
            else:
                others = [k for k in self.items if k != position]
                del self.items[max(others, key=lambda k: next_use(self.uses, k, now))]
        self._prefetch_next(now)
        return item

    def _prefetch_next(self, now: int) -> None:
        """Starts decoding the first keyframe after request ``now`` that the cache will not hold (every request
        before it is a hit, so it is exactly the cache's next decode)."""
        if self.prefetch is None or self.schedule is None or self.pending:
            return
        for k in itertools.islice(self.schedule, now + 1, None):
            if k not in self.items:
                self.pending[k] = self.prefetch.submit(self._decode, k)
                return


def request_indices(schedule: list[int]) -> dict[int, list[int]]:
    """Per keyframe, the (ascending) indices at which ``schedule`` requests it."""
    uses: dict[int, list[int]] = {}
    for i, k in enumerate(schedule):
        uses.setdefault(k, []).append(i)
    return uses


def next_use(uses: dict[int, list[int]], k: int, now: int) -> float:
    """Index of the first request of ``k`` after ``now`` (infinity when it is not needed again)."""
    lst = uses.get(k, [])
    i = bisect.bisect_right(lst, now)
    return lst[i] if i < len(lst) else math.inf


def region_quads(pk: PlacedKeyframe, x0: int, y0: int, w: int, h: int):
    """(cell number, quad in region pixels) of every mesh cell that reaches the region, in drawing order.

    A later cell wins the pixels on an edge it shares with an earlier one (the reference renderer the tests hold
    this one to, evaluation/stitch/reference_render.py, keeps the same order)."""
    cy, cx = pk.src_px.shape[0] - 1, pk.src_px.shape[1] - 1
    off = np.array([x0, y0], dtype=float)
    m = pk.mesh_px
    for r in range(cy):
        for c in range(cx):
            quad = np.array([m[r, c], m[r, c + 1], m[r + 1, c + 1], m[r + 1, c]]) - off
            if quad[:, 0].max() < 0 or quad[:, 1].max() < 0 or quad[:, 0].min() >= w or quad[:, 1].min() >= h:
                continue
            yield r * cx + c, quad


_INVERSE = cv2.WARP_INVERSE_MAP
_CONST = {"borderMode": cv2.BORDER_CONSTANT, "borderValue": 0}
# A keyframe whose seam weight is below this fraction of the best one at a pixel is not drawn there: it would
# move the blended value by < 0.03 grey levels per keyframe, and skipping it saves warping and blending the
# ~5 keyframes that cover each map pixel at 80 % overlap where only the seam's two neighbours matter.
MIN_BLEND_WEIGHT = 1e-4
_LOG_MIN_BLEND_WEIGHT = math.log(MIN_BLEND_WEIGHT) - 0.01


def _shift(x: float, y: float) -> np.ndarray:
    return np.array([[1.0, 0.0, x], [0.0, 1.0, y], [0.0, 0.0, 1.0]])


@dataclass
class _Cell:
    """One mesh cell of a layer: the box (region pixels) where it shows ROI, its quad inside that box, and the
    homography from box pixels to keyframe pixels."""

    x: int
    y: int
    w: int
    h: int
    inside: np.ndarray  # uint8 0/255, (h, w): the cell's rasterised quad
    to_src: np.ndarray


@dataclass
class _Layer:
    """A keyframe over one map region: its ROI mask and seam weight there, and the cells that draw it."""

    pk: PlacedKeyframe
    image: np.ndarray  # the whole (gain-corrected) keyframe
    x: int  # region origin in tile pixels
    y: int
    mask: np.ndarray  # uint8 0/255 (h, w)
    weight: np.ndarray  # float32 (h, w): distance to the ROI edge, 0 outside the ROI
    cells: list[_Cell]


def _warp_seams(pk, weight, x0, y0, w, h) -> tuple[np.ndarray, np.ndarray, list[_Cell]] | None:
    """ROI mask and seam weight of keyframe ``pk`` over the map region, one ``cv2.warpPerspective`` per mesh
    cell over the cell's box (homography, pixel positions and interpolation in OpenCV's C++), copied in through
    the cell's rasterised quad. The mask is the nearest keyframe pixel's seam weight > 0 (the nearest pixel of
    the ROI mask, which is not kept). Cells that show only background are not kept (no image is needed there)."""
    m = np.zeros((h, w), np.uint8)
    d = np.zeros((h, w), np.float32)
    cells = []
    for k, quad in region_quads(pk, x0, y0, w, h):
        fixed = np.round(quad * 16).astype(np.int32)
        # the quad's box (one pixel of margin), clipped to the region: the same pixels as rasterising the region
        bx0 = max(int(np.floor(quad[:, 0].min())) - 1, 0)
        by0 = max(int(np.floor(quad[:, 1].min())) - 1, 0)
        bx1 = min(int(np.ceil(quad[:, 0].max())) + 2, w)
        by1 = min(int(np.ceil(quad[:, 1].max())) + 2, h)
        if bx1 <= bx0 or by1 <= by0:
            continue
        size = (bx1 - bx0, by1 - by0)
        inside = np.zeros((size[1], size[0]), np.uint8)
        cv2.fillConvexPoly(inside, fixed - np.int32([bx0 * 16, by0 * 16]), 255, lineType=cv2.LINE_8, shift=4)
        to_src = pk.cell_inv[k] @ _shift(x0 + bx0, y0 + by0)
        cw = cv2.warpPerspective(weight, to_src, size, flags=cv2.INTER_NEAREST | _INVERSE, **_CONST)
        cm = _compare(cw, 0.0, cv2.CMP_GT)
        cv2.copyTo(cm, inside, m[by0:by1, bx0:bx1])
        cv2.bitwise_and(cm, inside, dst=cm)
        ex, ey, ew, eh = cv2.boundingRect(cm)
        if ew == 0:
            continue  # background only
        keep = np.ascontiguousarray(inside[ey : ey + eh, ex : ex + ew])
        to_src = to_src @ _shift(ex, ey)
        cd = cv2.warpPerspective(weight, to_src, (ew, eh), flags=cv2.INTER_LINEAR | _INVERSE, **_CONST)
        cv2.copyTo(cd, keep, d[by0 + ey : by0 + ey + eh, bx0 + ex : bx0 + ex + ew])
        cells.append(_Cell(bx0 + ex, by0 + ey, ew, eh, keep, to_src))
    if not cells:
        return None
    d = cv2.max(d, 1e-3)  # inside the ROI the weight is never 0 (0 means "not drawn")
    return m, cv2.bitwise_and(d, d, mask=m), cells


def _warp_image(layer: _Layer, where: np.ndarray) -> np.ndarray:
    """The keyframe's pixels over the region, warped cell by cell, but only inside the boxes of ``where``."""
    h, w = layer.mask.shape
    im = np.zeros((h, w, 3), np.uint8)
    for c in layer.cells:
        need = cv2.bitwise_and(where[c.y : c.y + c.h, c.x : c.x + c.w], c.inside)
        sx, sy, sw, sh = cv2.boundingRect(need)
        if sw == 0:
            continue
        ci = cv2.warpPerspective(
            layer.image, c.to_src @ _shift(sx, sy), (sw, sh), flags=cv2.INTER_LINEAR | _INVERSE, **_CONST
        )
        y, x = c.y + sy, c.x + sx
        cv2.copyTo(ci, c.inside[sy : sy + sh, sx : sx + sw], im[y : y + sh, x : x + sw])
    return im


def _compare(a: np.ndarray, value: float, op: int) -> np.ndarray:
    """``cv2.compare`` of an array with a scalar. OpenCV's Python binding reads a 1 x 1 array as a scalar too and
    refuses scalar-with-scalar, so a one-pixel region (a keyframe's weight box of one pixel in a tile) stopped the
    whole stitch (fresh-clone demo, 2026-12-02); there the scalar is given as an array of the same shape."""
    if a.size == 1:
        return cv2.compare(a, np.full(a.shape, value, a.dtype), op)
    return cv2.compare(a, value, op)


def render_tile(
    x0: int,
    y0: int,
    w: int,
    h: int,
    placed: list[PlacedKeyframe],
    sources: SourceCache,
    *,
    feather_px: float = 4.0,
) -> tuple[np.ndarray, np.ndarray]:
    """(BGR uint8 tile, coverage uint8 0/255) for one map region: seam weights of every keyframe first, then each
    keyframe's image is warped and blended only where its weight matters (``MIN_BLEND_WEIGHT``); all per-pixel
    work in OpenCV. tests/test_stitch_render.py holds it to the per-pixel numpy reference
    (evaluation/stitch/reference_render.py)."""
    layers: list[_Layer] = []
    for pk in placed:
        bx0, by0, bx1, by1 = pk.bbox
        rx0, ry0, rx1, ry1 = max(bx0, x0), max(by0, y0), min(bx1, x0 + w), min(by1, y0 + h)
        if rx1 <= rx0 or ry1 <= ry0:
            continue
        img, weight = sources.get(pk.position)
        seams = _warp_seams(pk, weight, rx0, ry0, rx1 - rx0, ry1 - ry0)
        if seams is not None:
            layers.append(_Layer(pk, img, rx0 - x0, ry0 - y0, *seams))
    if not layers:
        return np.zeros((h, w, 3), np.uint8), np.zeros((h, w), np.uint8)
    dmax = np.zeros((h, w), np.float32)
    for L in layers:
        box = dmax[L.y : L.y + L.mask.shape[0], L.x : L.x + L.mask.shape[1]]
        cv2.max(box, L.weight, dst=box)
    acc = np.zeros((h, w, 3), np.float32)
    wsum = np.zeros((h, w), np.float32)
    inv_f = 1.0 / max(feather_px, 1e-3)
    for L in layers:
        lh, lw = L.mask.shape
        # the feather: weight exp((d - dmax) / feather), 1 for the keyframe that owns the pixel (Voronoi seam)
        e = cv2.addWeighted(L.weight, inv_f, dmax[L.y : L.y + lh, L.x : L.x + lw], -inv_f, 0.0)
        # exp only over the box where the weight can reach MIN_BLEND_WEIGHT (a keyframe's share of a tile is
        # often a band along its seam): below the threshold's log, less a margin for exp's rounding, it cannot,
        # so every pixel kept below lies in the box (the same pixels and values as exp over the whole layer)
        near = cv2.bitwise_and(_compare(e, _LOG_MIN_BLEND_WEIGHT, cv2.CMP_GE), L.mask)
        nx, ny, nw, nh = cv2.boundingRect(near)
        if nw == 0:
            continue
        box = (slice(ny, ny + nh), slice(nx, nx + nw))
        cv2.exp(e[box], dst=e[box])
        where = np.zeros((lh, lw), np.uint8)
        cv2.bitwise_and(_compare(e[box], MIN_BLEND_WEIGHT, cv2.CMP_GE), L.mask[box], dst=where[box])
        bx, by, bw, bh = cv2.boundingRect(where)
        if bw == 0:
            continue
        im = _warp_image(L, where)
        sub = (slice(by, by + bh), slice(bx, bx + bw))
        wgt = cv2.bitwise_and(e[sub], e[sub], mask=where[sub])
        tile = (slice(L.y + by, L.y + by + bh), slice(L.x + bx, L.x + bx + bw))
        cv2.add(wsum[tile], wgt, dst=wsum[tile])
        cv2.add(acc[tile], cv2.multiply(im[sub], cv2.merge((wgt, wgt, wgt)), dtype=cv2.CV_32F), dst=acc[tile])
    covered = _compare(wsum, 0.0, cv2.CMP_GT)
    # 1 / wsum, 0 where nothing was drawn: OpenCV gives inf there, acc * inf is NaN, and OpenCV 5.1's
    # convertScaleAbs turns NaN into 255 (5.0: 0), which drew uncovered map white
    inv = np.reciprocal(wsum, where=wsum > 0, out=np.zeros_like(wsum))
    out = cv2.multiply(acc, cv2.merge((inv, inv, inv)))
    return cv2.convertScaleAbs(out), covered

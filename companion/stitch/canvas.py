"""The render stage: every placed keyframe drawn onto the map, tile by tile, in memory or as tile files.

Tiles are drawn in the order the render plan (``render_plan.py``) finds cheapest for the keyframe cache, each
with only the keyframes that reach it; a map larger than ``max_in_memory_px`` is written only as tile PNGs (BGR
+ coverage as alpha), and a preview at most ``preview_width`` wide is kept either way.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterator
from concurrent.futures import Executor, Future, ThreadPoolExecutor
from dataclasses import dataclass
from functools import partial
from pathlib import Path

import cv2
import numpy as np

from companion.errors import CompanionError
from companion.progress import progress_bar
from companion.stitch.align import AlignedKeyframes
from companion.stitch.config import StitchConfig, worker_count
from companion.stitch.exposure import apply_gain, solve_gains
from companion.stitch.features import load_image_and_mask, load_mask
from companion.stitch.inputs import StitchInput
from companion.stitch.layout import MapLayout
from companion.stitch.render import PlacedKeyframe, SourceCache, drawable, render_tile
from companion.stitch.render_plan import plan_render

Tile = tuple[int, int]


@dataclass(frozen=True)
class RenderedMap:
    """The render stage's output. ``canvas``/``coverage`` only when the map fits in memory (else ``tiles_dir``)."""

    canvas: np.ndarray | None  # BGR
    coverage: np.ndarray | None  # 0/255
    preview: np.ndarray  # BGR, ``preview_scale`` x the map
    coverage_preview: np.ndarray  # 0/255
    preview_scale: float
    covered_px: int  # map pixels drawn
    tiles_dir: Path | None
    gains: np.ndarray  # per keyframe position: exposure gain applied
    info: dict  # tiles, keyframe decodes (and the plan's figures)


@dataclass(frozen=True)
class _TileSchedule:
    tiles: list[Tile]  # in drawing order
    drawn: dict[Tile, list[PlacedKeyframe]]  # the keyframes each tile draws
    cache_schedule: list[int]  # every keyframe request in order (the cache evicts by next use)
    planned: dict


def render_map(
    inp: StitchInput, aligned: AlignedKeyframes, layout: MapLayout, cfg: StitchConfig, out: Path, *, progress: bool
) -> RenderedMap:
    kfs = inp.keyframes
    W, H = inp.camera.width, inp.camera.height
    gains = solve_gains(len(kfs), aligned.accepted) if cfg.gain_compensation else np.ones(len(kfs))

    def load(k):
        img, mask = load_image_and_mask(kfs[k])
        return apply_gain(img, float(gains[k])), mask

    def weight_of(k):
        return drawable(load_mask(kfs[k], (W, H)))[1]

    # decoded keyframes kept for neighbouring tiles: image + float32 seam weight (7 bytes a pixel), within
    # ~600 MB (and the next one decoded ahead on a second thread while tiles are drawn)
    cache_size = int(np.clip(6e8 / (W * H * 7), 3, 16))
    workers = worker_count(cfg)
    with ThreadPoolExecutor(workers) as pool, ThreadPoolExecutor(workers) as draw:
        schedule = _schedule(layout, cfg, weight_of, cache_size, pool)
        sources = SourceCache(load, size=cache_size, schedule=schedule.cache_schedule, prefetch=pool)
        sink = _MapSink(layout, cfg, out / "tiles")
        drawing: deque[tuple[Tile, Future]] = deque()
        for x0, y0 in progress_bar(schedule.tiles, desc="render", disable=not progress, leave=False, unit="it"):
            # the keyframes are taken from the cache here, in the plan's order (the cache's schedule), and the
            # tile is drawn (and its file written) on a drawing thread: OpenCV releases the GIL, so tiles are
            # drawn on every core; at most ``workers`` tiles hold keyframes at a time, so memory stays bounded
            while len(drawing) >= workers or (drawing and drawing[0][1].done()):
                (tx, ty), done = drawing.popleft()
                sink.put(tx, ty, *done.result())
            near = schedule.drawn[(x0, y0)]
            taken = _Taken({p.position: sources.get(p.position) for p in near})
            job = partial(_draw_tile, x0, y0, near, taken, layout, cfg, sink)
            drawing.append(((x0, y0), draw.submit(job) if workers > 1 else _done(job())))
        while drawing:
            (tx, ty), done = drawing.popleft()
            sink.put(tx, ty, *done.result())
    info = {
        "tiles": len(schedule.tiles),
        "keyframe_decodes": sources.decoded,
        **schedule.planned,
    }
    return sink.finish(gains, info)


class _Taken(dict):
    """The keyframes one tile draws, taken from the cache beforehand (``render_tile`` asks for them by ``get``)."""


def _done(value) -> Future:
    f: Future = Future()
    f.set_result(value)
    return f


def _draw_tile(x0: int, y0: int, near, taken: _Taken, layout: MapLayout, cfg: StitchConfig, sink: _MapSink):
    """One tile drawn (and written, when the map is kept as tiles): what a drawing thread does."""
    w, h = min(cfg.tile_px, layout.grid.width - x0), min(cfg.tile_px, layout.grid.height - y0)
    img, cov = render_tile(x0, y0, w, h, near, taken, feather_px=cfg.feather_px)
    sink.write_tile(x0, y0, img, cov)
    return img, cov


def _schedule(layout: MapLayout, cfg: StitchConfig, weight_of, cache_size: int, pool: Executor) -> _TileSchedule:
    """Which tiles, in which order, each drawing which keyframes: the plan skips keyframes whose seam weight loses
    everywhere in a tile."""
    gw, gh = layout.grid.width, layout.grid.height
    order = sorted(layout.placed.values(), key=lambda p: p.bbox[0])
    # the seam weights, in the plan's order, decoded side by side on the pool's threads
    weights = _ordered_map(pool, weight_of, [p.position for p in order], ahead=worker_count(cfg))
    plan = plan_render(order, weights, gw, gh, cfg.tile_px, cfg.feather_px, cache_size)
    tiles, needs = plan.order, plan.needs
    per_tile = [len(v) for v in needs.values() if v]
    planned = {
        "planned_decodes": plan.decodes,
        "keyframes_per_tile": {"max": max(per_tile, default=0), "mean": round(float(np.mean(per_tile or [0])), 2)},
    }
    drawn: dict[Tile, list[PlacedKeyframe]] = {}
    for x0, y0 in tiles:
        w, h = min(cfg.tile_px, gw - x0), min(cfg.tile_px, gh - y0)
        near = [p for p in order if p.bbox[0] < x0 + w and p.bbox[2] > x0 and p.bbox[1] < y0 + h and p.bbox[3] > y0]
        drawn[(x0, y0)] = [p for p in near if p.position in needs[(x0, y0)]]
    # with the plan, the cache knows every request ahead and keeps what is needed soonest
    cache_schedule = [p.position for tile in tiles for p in drawn[tile]]
    return _TileSchedule(tiles, drawn, cache_schedule, planned)


def _ordered_map(pool: Executor, fn, items: list, *, ahead: int) -> Iterator:
    """``fn`` of each item, in order, computed on ``pool`` with at most ``ahead`` results waiting (each holds a
    4K seam weight: ``Executor.map`` would start them all and keep every result until it is read)."""
    waiting: deque[Future] = deque()
    for item in items:
        waiting.append(pool.submit(fn, item))
        if len(waiting) > ahead:
            yield waiting.popleft().result()
    while waiting:
        yield waiting.popleft().result()


class _MapSink:
    """Where rendered tiles go: the in-memory map or tile files, and always the preview and the coverage count."""

    def __init__(self, layout: MapLayout, cfg: StitchConfig, tiles_dir: Path):
        gw, gh = layout.grid.width, layout.grid.height
        self.in_memory = gw * gh <= cfg.max_in_memory_px
        self.canvas = np.zeros((gh, gw, 3), np.uint8) if self.in_memory else None
        self.coverage = np.zeros((gh, gw), np.uint8) if self.in_memory else None
        self.scale = min(1.0, cfg.preview_width / gw)
        self.pw, self.ph = max(1, round(gw * self.scale)), max(1, round(gh * self.scale))
        self.preview = np.zeros((self.ph, self.pw, 3), np.uint8)
        self.coverage_preview = np.zeros((self.ph, self.pw), np.uint8)
        self.tiles_dir = tiles_dir
        self.covered_px = 0
        self._blanks: dict[tuple[int, int], bytes] = {}  # an all-transparent tile's PNG, per tile size

    def write_tile(self, x0: int, y0: int, img: np.ndarray, cov: np.ndarray) -> None:
        """The tile's file, when the map is kept as tiles (called on the drawing threads: one file each)."""
        if not self.in_memory:
            self.tiles_dir.mkdir(exist_ok=True)
            path = self.tiles_dir / f"tile_y{y0:07d}_x{x0:07d}.png"
            if cv2.countNonZero(cov) == 0 and cv2.countNonZero(img.reshape(img.shape[0], -1)) == 0:
                png = self._blank_png(cov.shape)  # most tiles of a big map hold nothing: the same PNG each time
            else:
                ok, png = cv2.imencode(".png", cv2.merge((img, cov)))
                png = png.tobytes() if ok else None
            try:
                if png is None:
                    raise OSError("the PNG encoder failed")
                path.write_bytes(png)
            except OSError as exc:
                raise CompanionError(
                    f"cannot write {path} ({exc})", "check free disk space and permissions of --out"
                ) from exc

    def _blank_png(self, shape: tuple[int, int]) -> bytes:
        png = self._blanks.get(shape)
        if png is None:
            png = self._blanks[shape] = cv2.imencode(".png", np.zeros((*shape, 4), np.uint8))[1].tobytes()
        return png

    def put(self, x0: int, y0: int, img: np.ndarray, cov: np.ndarray) -> None:
        """The tile in the map (in memory), the preview and the coverage count (on the stage's thread)."""
        h, w = cov.shape
        covered = cv2.countNonZero(cov)
        self.covered_px += covered  # the grid is the region measured (facade or content)
        if self.in_memory:
            self.canvas[y0 : y0 + h, x0 : x0 + w] = img
            self.coverage[y0 : y0 + h, x0 : x0 + w] = cov
        if covered == 0 and cv2.countNonZero(img.reshape(h, -1)) == 0:
            return  # a blank tile (most of a long facade's margin) leaves the preview's zeros as they are
        ps = self.scale
        px0, py0 = round(x0 * ps), round(y0 * ps)
        px1, py1 = min(self.pw, round((x0 + w) * ps)), min(self.ph, round((y0 + h) * ps))
        if px1 > px0 and py1 > py0:
            size = (px1 - px0, py1 - py0)
            self.preview[py0:py1, px0:px1] = cv2.resize(img, size, interpolation=cv2.INTER_AREA)
            self.coverage_preview[py0:py1, px0:px1] = cv2.resize(cov, size, interpolation=cv2.INTER_AREA)

    def finish(self, gains: np.ndarray, info: dict) -> RenderedMap:
        return RenderedMap(
            self.canvas,
            self.coverage,
            self.preview,
            self.coverage_preview,
            self.scale,
            self.covered_px,
            None if self.in_memory else self.tiles_dir,
            gains,
            info,
        )

"""The render stage: every placed keyframe drawn onto the map, tile by tile, in memory or as tile files.

Tiles are drawn in the order the render plan (``render_plan.py``) finds cheapest for the keyframe cache, each
with only the keyframes that reach it; a map larger than ``max_in_memory_px`` is written only as tile PNGs (BGR
+ coverage as alpha), and a preview at most ``preview_width`` wide is kept either way.

A map kept as tiles can also be drawn by a :class:`TileRunner` (the site's Dask cluster): the plan's tile order is
cut into runs of tiles (:class:`TileBatch`: paths, meshes and gains, no pixels), each drawn by
:func:`render_batch` wherever the runner sends it, which writes its tiles' files itself (atomically, on the
shared output path) and returns only their preview pieces and coverage counts. The tiles are the same pixels as
drawn here: the same keyframes and gains per tile.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import Executor, Future, ThreadPoolExecutor
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Protocol

import cv2
import numpy as np

from companion.errors import CompanionError
from companion.files import write_atomic
from companion.progress import progress_bar
from companion.stitch.align import AlignedKeyframes
from companion.stitch.config import StitchConfig, worker_count
from companion.stitch.exposure import apply_gain, solve_gains
from companion.stitch.features import load_image_and_mask, load_mask
from companion.stitch.inputs import KeyframeInput, StitchInput
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


class TileRunner(Protocol):
    """Runs render tasks elsewhere (the site's cluster): ``slots`` of them at a time; ``map`` yields ``fn`` of each
    item, in any order, as they finish."""

    slots: int

    def map(self, fn: Callable, items: list) -> Iterable: ...


BATCHES_PER_SLOT = 4  # a map's tiles are cut into this many runs per slot: balance, against keyframe re-decodes


def render_map(
    inp: StitchInput, aligned: AlignedKeyframes, layout: MapLayout, cfg: StitchConfig, out: Path, *, progress: bool,
    tiles: TileRunner | None = None,
) -> RenderedMap:
    """The map drawn tile by tile; with ``tiles`` (and a map kept as tiles), the tiles are drawn as tasks of the
    runner instead of on this process's threads."""
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
    sink = _MapSink(layout, cfg, out / "tiles")
    if tiles is not None and not sink.in_memory:
        with ThreadPoolExecutor(workers) as pool:
            schedule = _schedule(layout, cfg, weight_of, cache_size, pool)
        return _render_as_tasks(schedule, kfs, gains, layout, cfg, sink, cache_size, tiles)
    with ThreadPoolExecutor(workers) as pool, ThreadPoolExecutor(workers) as draw:
        schedule = _schedule(layout, cfg, weight_of, cache_size, pool)
        sources = SourceCache(load, size=cache_size, schedule=schedule.cache_schedule, prefetch=pool)
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


@dataclass(frozen=True)
class TileBatch:
    """A run of tiles, in the plan's order, as one render task: what it needs to draw and write them (paths,
    meshes, gains: a few kB a tile, no pixels)."""

    tiles: tuple[Tile, ...]
    drawn: dict[Tile, list[PlacedKeyframe]]  # the keyframes each tile draws
    keyframes: dict[int, KeyframeInput]  # position -> keyframe (its image and mask paths)
    gains: dict[int, float]  # position -> exposure gain
    width: int  # the map's grid
    height: int
    tile_px: int
    feather_px: float
    cache_size: int
    tiles_dir: Path
    preview: tuple[float, int, int]  # the preview's scale, width, height


@dataclass(frozen=True)
class TileDone:
    """A drawn tile as its task returns it: its coverage count and its piece of the preview (None when blank)."""

    x0: int
    y0: int
    covered: int
    piece: tuple[int, int, np.ndarray, np.ndarray] | None


def render_batch(batch: TileBatch) -> tuple[int, list[TileDone]]:
    """Draws and writes a batch's tiles (one file each, atomically); returns the keyframe decodes and each tile's
    preview piece. Runs anywhere that reads the keyframes and writes ``tiles_dir`` (a Dask worker)."""
    kfs = batch.keyframes

    def load(k):
        img, mask = load_image_and_mask(kfs[k])
        return apply_gain(img, batch.gains[k]), mask

    requests = [p.position for tile in batch.tiles for p in batch.drawn[tile]]
    sources = SourceCache(load, size=batch.cache_size, schedule=requests)
    blanks: dict[tuple[int, int], bytes] = {}
    done = []
    for x0, y0 in batch.tiles:
        w, h = min(batch.tile_px, batch.width - x0), min(batch.tile_px, batch.height - y0)
        near = batch.drawn[(x0, y0)]
        taken = _Taken({p.position: sources.get(p.position) for p in near})
        img, cov = render_tile(x0, y0, w, h, near, taken, feather_px=batch.feather_px)
        _write_tile_file(batch.tiles_dir, x0, y0, img, cov, blanks)
        done.append(TileDone(x0, y0, cv2.countNonZero(cov), preview_piece(x0, y0, img, cov, *batch.preview)))
    return sources.decoded, done


def _render_as_tasks(schedule: _TileSchedule, kfs, gains: np.ndarray, layout: MapLayout, cfg: StitchConfig,
                     sink: _MapSink, cache_size: int, runner: TileRunner) -> RenderedMap:
    """The plan's tiles cut into runs (``BATCHES_PER_SLOT`` per slot of the runner), each a :func:`render_batch`
    task; their preview pieces and counts gathered here as they finish."""
    order = schedule.tiles
    n = max(1, min(len(order), BATCHES_PER_SLOT * max(1, runner.slots)))
    bounds = [round(i * len(order) / n) for i in range(n + 1)]
    batches = []
    for a, b in zip(bounds, bounds[1:], strict=False):
        run = tuple(order[a:b])
        if not run:
            continue
        drawn = {t: schedule.drawn[t] for t in run}
        used = {p.position for t in run for p in drawn[t]}
        batches.append(TileBatch(run, drawn, {k: kfs[k] for k in used}, {k: float(gains[k]) for k in used},
                                 layout.grid.width, layout.grid.height, cfg.tile_px, cfg.feather_px, cache_size,
                                 sink.tiles_dir, (sink.scale, sink.pw, sink.ph)))
    sink.tiles_dir.mkdir(parents=True, exist_ok=True)
    decoded = 0
    for decodes, done in runner.map(render_batch, batches):
        decoded += decodes
        for t in done:
            sink.put_piece(t.covered, t.piece)
    info = {"tiles": len(order), "render_tasks": len(batches),
            "keyframe_decodes": decoded, **schedule.planned}
    return sink.finish(gains, info)


def preview_piece(
    x0: int, y0: int, img: np.ndarray, cov: np.ndarray, scale: float, pw: int, ph: int
) -> tuple[int, int, np.ndarray, np.ndarray] | None:
    """Where a tile lands on the preview and its downscaled pixels and coverage; None for a blank tile (the
    preview's zeros stay) or one too small to reach a preview pixel."""
    h, w = cov.shape
    if cv2.countNonZero(cov) == 0 and cv2.countNonZero(img.reshape(h, -1)) == 0:
        return None
    px0, py0 = round(x0 * scale), round(y0 * scale)
    px1, py1 = min(pw, round((x0 + w) * scale)), min(ph, round((y0 + h) * scale))
    if px1 <= px0 or py1 <= py0:
        return None
    size = (px1 - px0, py1 - py0)
    return (px0, py0, cv2.resize(img, size, interpolation=cv2.INTER_AREA),
            cv2.resize(cov, size, interpolation=cv2.INTER_AREA))


def _write_tile_file(tiles_dir: Path, x0: int, y0: int, img: np.ndarray, cov: np.ndarray,
                     blanks: dict[tuple[int, int], bytes]) -> None:
    """One tile's BGRA PNG, written atomically (a reader, or a task run again after its worker died, never sees
    half a tile)."""
    tiles_dir.mkdir(exist_ok=True)
    path = tiles_dir / f"tile_y{y0:07d}_x{x0:07d}.png"
    if cv2.countNonZero(cov) == 0 and cv2.countNonZero(img.reshape(img.shape[0], -1)) == 0:
        png = blanks.get(cov.shape)  # most tiles of a big map hold nothing: the same PNG each time
        if png is None:
            png = blanks[cov.shape] = cv2.imencode(".png", np.zeros((*cov.shape, 4), np.uint8))[1].tobytes()
    else:
        ok, encoded = cv2.imencode(".png", cv2.merge((img, cov)))
        png = encoded.tobytes() if ok else None
    try:
        if png is None:
            raise OSError("the PNG encoder failed")
        write_atomic(path, png)
    except OSError as exc:
        raise CompanionError(f"cannot write {path} ({exc})", "check free disk space and permissions of --out") from exc


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
    plan = plan_render(order, weights, gw, gh, cfg.tile_px, cfg.feather_px, cache_size,
                       block_px=plan_block_px(gw, gh))
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


PLAN_BLOCK_PX = 8  # the render plan's block (render_plan.py), on maps up to PLAN_MAX_BLOCKS of them
PLAN_MAX_BLOCKS = 4e6  # larger maps get coarser blocks: the plan's bounds (float32 a block) do not grow with the map


def plan_block_px(width: int, height: int) -> int:
    """The plan's block size for a ``width`` x ``height`` map: 8 px, doubled until the map has at most
    ``PLAN_MAX_BLOCKS`` blocks (a 1 GP map: 16 px). Coarser blocks only make the plan more cautious (a tile may
    draw a keyframe more), never change a pixel."""
    block = PLAN_BLOCK_PX
    while (width / block) * (height / block) > PLAN_MAX_BLOCKS:
        block *= 2
    return block


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
            _write_tile_file(self.tiles_dir, x0, y0, img, cov, self._blanks)

    def put(self, x0: int, y0: int, img: np.ndarray, cov: np.ndarray) -> None:
        """The tile in the map (in memory), the preview and the coverage count (on the stage's thread)."""
        h, w = cov.shape
        if self.in_memory:
            self.canvas[y0 : y0 + h, x0 : x0 + w] = img
            self.coverage[y0 : y0 + h, x0 : x0 + w] = cov
        self.put_piece(cv2.countNonZero(cov), preview_piece(x0, y0, img, cov, self.scale, self.pw, self.ph))

    def put_piece(self, covered: int, piece: tuple[int, int, np.ndarray, np.ndarray] | None) -> None:
        """A tile's coverage count (the grid is the region measured: facade or content) and preview piece."""
        self.covered_px += covered
        if piece is not None:
            px0, py0, img, cov = piece
            self.preview[py0 : py0 + img.shape[0], px0 : px0 + img.shape[1]] = img
            self.coverage_preview[py0 : py0 + cov.shape[0], px0 : px0 + cov.shape[1]] = cov

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

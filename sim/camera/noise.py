"""Deterministic coordinate-hashed noise: the same world point gets the same value in every frame and tile.

Textures are functions of metric coordinates rather than stored images, so a wall of any size costs no memory
and two overlapping frames see exactly the same surface detail (which the overlap gate and stitcher rely on).
"""

from __future__ import annotations

import numpy as np

_M1 = np.uint32(0x27D4EB2D)
_M2 = np.uint32(0x165667B1)
_M3 = np.uint32(0x9E3779B9)


def hash2(ix: np.ndarray, iy: np.ndarray, seed: int) -> np.ndarray:
    """Integer lattice coordinates -> uniform floats in [0, 1)."""
    with np.errstate(over="ignore"):
        ux = ix if ix.dtype == np.uint32 else ix.astype(np.int64).astype(np.uint32)
        uy = iy if iy.dtype == np.uint32 else iy.astype(np.int64).astype(np.uint32)
        h = ux * _M1
        h ^= uy * _M2
        h ^= np.uint32((seed * 0x85EBCA6B) & 0xFFFFFFFF)
        h ^= h >> np.uint32(15)
        h *= _M3
        h ^= h >> np.uint32(13)
        h *= _M1
        h ^= h >> np.uint32(16)
    return (h >> np.uint32(8)).astype(np.float32) * np.float32(1.0 / (1 << 24))


def value_noise(x: np.ndarray, y: np.ndarray, cell: float, seed: int) -> np.ndarray:
    """Smooth noise in [0, 1) with features of size ``cell`` (same units as x, y).

    A regular grid given as broadcast views (``grid_coords``: x varies along columns only, y along rows only) is
    evaluated separably, bit for bit the same values: the lattice is hashed once per lattice point instead of four
    times per texel, which makes texture tiles several times cheaper."""
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    if _is_grid(x, y):
        got = _value_noise_grid(x[0], y[:, 0], cell, seed)
        if got is not None:
            return got
    xs = x / cell
    ys = y / cell
    x0 = np.floor(xs)
    y0 = np.floor(ys)
    fx = (xs - x0).astype(np.float32)
    fy = (ys - y0).astype(np.float32)
    # lattice indices as wrapped uint32 (what the hash consumes); +1 wraps the same way as int64 -> uint32
    with np.errstate(over="ignore"):
        ix = x0.astype(np.int64).astype(np.uint32)
        iy = y0.astype(np.int64).astype(np.uint32)
        ix1 = ix + np.uint32(1)
        iy1 = iy + np.uint32(1)
    sx = fx * fx * (3 - 2 * fx)
    sy = fy * fy * (3 - 2 * fy)
    a = hash2(ix, iy, seed)
    b = hash2(ix1, iy, seed)
    c = hash2(ix, iy1, seed)
    d = hash2(ix1, iy1, seed)
    top = a + (b - a) * sx
    bot = c + (d - c) * sx
    return top + (bot - top) * sy


def grid_coords(xs: np.ndarray, ys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Like ``np.meshgrid(xs, ys)`` but as read-only broadcast views, which the noise functions recognise as a
    regular grid and evaluate separably (same values as on the full arrays)."""
    xs = np.asarray(xs, dtype=np.float64)
    ys = np.asarray(ys, dtype=np.float64)
    shape = (len(ys), len(xs))
    return np.broadcast_to(xs[None, :], shape), np.broadcast_to(ys[:, None], shape)


def _is_grid(x: np.ndarray, y: np.ndarray) -> bool:
    return (x.ndim == 2 and x.shape == y.shape and x.shape[0] > 1 and x.shape[1] > 1 and x.strides[0] == 0
            and y.strides[1] == 0)


def _axis(v: np.ndarray, cell: float):
    """Per-axis part of value noise: lattice cell (int64), smoothstep weight (float32), as the point path."""
    s = v / cell
    v0 = np.floor(s)
    f = (s - v0).astype(np.float32)
    return v0.astype(np.int64), f * f * (3 - 2 * f)


def _value_noise_grid(xs: np.ndarray, ys: np.ndarray, cell: float, seed: int) -> np.ndarray | None:
    """Value noise on the grid xs (columns) x ys (rows): the same float32 operations as the point path on the
    same operands (lattice hashes, smoothstep weights), so the result is identical, at the cost of hashing the
    few lattice points once, interpolating each lattice row along x and the rows along y. None when the lattice
    is finer than the grid (noise cells smaller than the grid spacing): the point path is cheaper there."""
    ix, sx = _axis(xs, cell)
    iy, sy = _axis(ys, cell)
    kx0, ky0 = int(ix.min()), int(iy.min())
    nx, ny = int(ix.max()) - kx0 + 2, int(iy.max()) - ky0 + 2
    if nx > len(xs) + 1 or ny > len(ys) + 1:
        return None
    with np.errstate(over="ignore"):
        kx = np.arange(kx0, kx0 + nx, dtype=np.int64).astype(np.uint32)
        ky = np.arange(ky0, ky0 + ny, dtype=np.int64).astype(np.uint32)
    kxx, kyy = np.broadcast_arrays(kx[None, :], ky[:, None])
    lattice = hash2(kxx, kyy, seed)  # (rows, cols) of lattice values
    cx = ix - kx0
    a = lattice[:, cx]
    rows = a + (lattice[:, cx + 1] - a) * sx[None, :]  # each lattice row interpolated along x
    cy = iy - ky0
    top = rows[cy]
    bot = rows[cy + 1]
    return top + (bot - top) * sy[:, None]


def fbm(x: np.ndarray, y: np.ndarray, cell: float, seed: int, octaves: int = 4, min_cell: float = 0.0) -> np.ndarray:
    """Fractal noise in about [-1, 1]: octaves of halving size; octaves finer than ``min_cell`` are left out
    (band limiting, so a coarse rendering does not alias the fine detail)."""
    out = np.zeros(np.shape(x), dtype=np.float32)
    amp, total = 1.0, 0.0
    for k in range(octaves):
        c = cell / (2**k)
        if c < min_cell:
            break
        out += np.float32(amp) * (value_noise(x, y, c, seed + 7919 * k) * 2 - 1)
        total += amp
        amp *= 0.5
    return out / np.float32(max(total, 1e-6)) if total > 0 else out

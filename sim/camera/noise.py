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
    """Smooth noise in [0, 1) with features of size ``cell`` (same units as x, y)."""
    xs = np.asarray(x, dtype=np.float64) / cell
    ys = np.asarray(y, dtype=np.float64) / cell
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

"""Procedural facade texture: wall material, window grid, stains and cracks, chosen by seed.

The texture is a function of facade coordinates (along_m, up_m) in metres, evaluated lazily in square tiles at
power-of-two resolutions (1, 2, 4, ... mm per texel), so a 26 x 12 m wall at 1 mm per texel never has to exist
in memory at once. Cracks are recorded with their true width and length for damage-mapping accuracy checks.
"""

from __future__ import annotations

import math
from collections import OrderedDict
from dataclasses import dataclass, field

import numpy as np

from sim.camera.noise import fbm, grid_coords, hash2, value_noise

MATERIALS = ("brick", "concrete", "panels")


@dataclass(frozen=True)
class Crack:
    """A crack drawn on the wall: polyline in facade metres (along_m, up_m), constant width."""

    points: tuple[tuple[float, float], ...]
    width_m: float

    @property
    def length_m(self) -> float:
        p = np.asarray(self.points)
        return float(np.sum(np.hypot(*np.diff(p, axis=0).T)))

    def to_json(self) -> dict:
        return {"points": [list(p) for p in self.points], "width_m": self.width_m, "length_m": self.length_m}


@dataclass(frozen=True)
class WindowGrid:
    floor_h: float
    sill_h: float
    win_w: float
    win_h: float
    margin: float
    n_bays: int
    bay_w: float
    n_floors: int
    frame_w: float = 0.06

    def windows(self) -> list[tuple[float, float, float, float]]:
        """(along_min, up_min, along_max, up_max) of every window."""
        out = []
        for k in range(self.n_floors):
            for j in range(self.n_bays):
                cx = self.margin + (j + 0.5) * self.bay_w
                u0 = k * self.floor_h + self.sill_h
                out.append((cx - self.win_w / 2, u0, cx + self.win_w / 2, u0 + self.win_h))
        return out


@dataclass
class FacadeStyle:
    """Everything the seed decides about the wall's look."""

    seed: int
    length_m: float
    height_m: float
    material: str
    base_bgr: tuple[float, float, float]
    mortar_bgr: tuple[float, float, float]
    frame_bgr: tuple[float, float, float]
    glass_tint: tuple[float, float, float]
    grid: WindowGrid
    cracks: list[Crack] = field(default_factory=list)
    stain: float = 0.12
    brick_len: float = 0.225
    course: float = 0.075
    mortar: float = 0.010
    panel_w: float = 1.5
    panel_h: float = 0.75

    @classmethod
    def from_seed(cls, seed: int, length_m: float, height_m: float, n_cracks: int | None = None) -> FacadeStyle:
        rng = np.random.default_rng([seed, 4])
        material = MATERIALS[int(rng.integers(len(MATERIALS)))]
        if material == "brick":
            base = tuple(float(v) for v in rng.uniform([0.18, 0.25, 0.45], [0.32, 0.40, 0.70]))
            mortar = (0.62, 0.64, 0.66)
        elif material == "concrete":
            g = float(rng.uniform(0.5, 0.68))
            base = (g * 0.97, g, g * 1.01)
            mortar = (g * 0.6, g * 0.6, g * 0.62)
        else:
            base = tuple(float(v) for v in rng.uniform([0.45, 0.5, 0.5], [0.8, 0.78, 0.75]))
            mortar = (0.18, 0.18, 0.2)
        floor_h = float(rng.uniform(3.0, 3.6))
        win_h = float(rng.uniform(1.3, 1.8))
        bay_target = float(rng.uniform(2.4, 3.6))
        margin = 1.0
        usable = max(length_m - 2 * margin, 0.5)
        n_bays = max(1, int(round(usable / bay_target)))
        bay_w = usable / n_bays
        win_w = min(float(rng.uniform(1.1, 1.7)), 0.7 * bay_w)
        sill = 0.9
        n_floors = max(0, int((height_m - 0.8 - sill - win_h) // floor_h) + 1) if height_m > sill + win_h + 0.8 else 0
        grid = WindowGrid(floor_h, sill, win_w, win_h, margin, n_bays, bay_w, n_floors)
        frame = (0.82, 0.82, 0.8) if rng.random() < 0.5 else (0.16, 0.16, 0.17)
        glass = tuple(float(v) for v in rng.uniform([0.85, 0.8, 0.6], [1.0, 0.95, 0.8]))
        style = cls(seed, length_m, height_m, material, base, mortar, frame, glass, grid,
                    stain=float(rng.uniform(0.05, 0.2)))
        if material == "panels":
            style.panel_w = float(rng.uniform(1.0, 2.0))
            style.panel_h = float(rng.uniform(0.5, 1.0))
        count = int(rng.integers(1, 4)) if n_cracks is None else n_cracks
        style.cracks = _make_cracks(rng, count, length_m, height_m, grid)
        return style

    def to_json(self) -> dict:
        return {
            "seed": self.seed,
            "material": self.material,
            "windows": [list(w) for w in self.grid.windows()],
            "cracks": [c.to_json() for c in self.cracks],
        }


def _make_cracks(rng, count: int, length_m: float, height_m: float, grid: WindowGrid) -> list[Crack]:
    wins = grid.windows()
    cracks: list[Crack] = []
    tries = 0
    while len(cracks) < count and tries < 200:
        tries += 1
        total = float(rng.uniform(0.4, 1.5))
        a = float(rng.uniform(0.5, max(length_m - 0.5, 0.6)))
        u = float(rng.uniform(0.6, max(height_m - 0.6, 0.7)))
        heading = float(rng.uniform(-2.2, -0.9)) if rng.random() < 0.5 else float(rng.uniform(0.9, 2.2))
        pts = [(a, u)]
        step = 0.04
        for _ in range(int(total / step)):
            heading += float(rng.normal(0.0, 0.35))
            heading = float(np.clip(heading, -2.8, 2.8)) if abs(heading) > 0.3 else heading + 0.4
            a += step * math.sin(heading)
            u -= step * abs(math.cos(heading)) + 0.3 * step
            pts.append((a, u))
        p = np.asarray(pts)
        inside = (p[:, 0] > 0.05).all() and (p[:, 0] < length_m - 0.05).all() and (p[:, 1] > 0.05).all()
        on_window = any(
            ((p[:, 0] > w[0] - 0.1) & (p[:, 0] < w[2] + 0.1) & (p[:, 1] > w[1] - 0.1) & (p[:, 1] < w[3] + 0.1)).any()
            for w in wins
        )
        if inside and not on_window:
            cracks.append(Crack(tuple((round(x, 4), round(y, 4)) for x, y in pts), float(rng.uniform(0.0005, 0.004))))
    return cracks


def _smooth_cover(d: np.ndarray, half_w: float, px: float) -> np.ndarray:
    """Fraction of a texel of size px covered by a line of half width half_w at distance d."""
    px = max(px, 1e-5)
    if 2 * half_w < px:
        return (2 * half_w / px) * np.clip(1.0 - d / px, 0.0, 1.0)
    return np.clip(0.5 + (half_w - d) / px, 0.0, 1.0)


class TiledTexture:
    """A surface colour function ``evaluate(a, u, px)`` (plane metres -> BGR float32 0..1, rendered with texel
    size ``px``) cached as uint8 tiles at power-of-two texel sizes, so renderers sample a patch at the level that
    matches their pixel footprint instead of evaluating the function per pixel."""

    TILE = 256

    def __init__(self, max_tiles: int = 384):
        self._tiles: OrderedDict[tuple[int, int, int], np.ndarray] = OrderedDict()
        self.max_tiles = max_tiles

    def evaluate(self, a: np.ndarray, u: np.ndarray, px: float) -> np.ndarray:
        raise NotImplementedError

    # ---- tiled rendering ---------------------------------------------------------------------------------
    def tile(self, level: int, ix: int, iy: int) -> np.ndarray:
        """uint8 BGR tile of TILE x TILE texels of 2**level mm; row index grows with up_m."""
        key = (level, ix, iy)
        t = self._tiles.get(key)
        if t is not None:
            self._tiles.move_to_end(key)
            return t
        px = (2**level) / 1000.0
        n = self.TILE
        c = (np.arange(n) + 0.5) * px
        aa, uu = grid_coords(ix * n * px + c, iy * n * px + c)  # a regular grid: separable noise
        t = (self.evaluate(aa, uu, px) * 255 + 0.5).astype(np.uint8)
        self._tiles[key] = t
        while len(self._tiles) > self.max_tiles:
            self._tiles.popitem(last=False)
        return t

    def has_tile(self, level: int, ix: int, iy: int) -> bool:
        return (level, ix, iy) in self._tiles

    def patch(self, a0: float, u0: float, a1: float, u1: float, level: int) -> tuple[np.ndarray, float, float, float]:
        """Texture covering [a0, a1] x [u0, u1]: (image uint8 with rows growing upwards, a_org, u_org, px_m)."""
        px = (2**level) / 1000.0
        span = self.TILE * px
        ix0, ix1 = int(math.floor(a0 / span)), int(math.floor(a1 / span))
        iy0, iy1 = int(math.floor(u0 / span)), int(math.floor(u1 / span))
        rows = [np.concatenate([self.tile(level, ix, iy) for ix in range(ix0, ix1 + 1)], axis=1)
                for iy in range(iy0, iy1 + 1)]
        return np.concatenate(rows, axis=0), ix0 * span, iy0 * span, px


class FacadeTexture(TiledTexture):
    """Evaluates the wall's colour (BGR float32, 0..1) at facade points; cached tiles for rendering."""

    def __init__(self, style: FacadeStyle, max_tiles: int = 384):
        super().__init__(max_tiles)
        self.style = style

    # ---- point evaluation -------------------------------------------------------------------------------
    def evaluate(self, a: np.ndarray, u: np.ndarray, px: float) -> np.ndarray:
        """Colour at points (along_m, up_m) rendered with texel size ``px`` metres; shape (..., 3)."""
        s = self.style
        a = np.asarray(a, dtype=np.float64)
        u = np.asarray(u, dtype=np.float64)
        base = np.array(s.base_bgr, dtype=np.float32)
        col = np.empty(a.shape + (3,), dtype=np.float32)
        grain = fbm(a, u, 0.08, s.seed + 11, octaves=4, min_cell=px * 1.5)
        if s.material == "brick":
            row = np.floor(u / s.course)
            ca = a + (row % 2) * (s.brick_len / 2)
            colid = np.floor(ca / s.brick_len)
            fa = ca - colid * s.brick_len
            fu = u - row * s.course
            tone = hash2(row.astype(np.int64), colid.astype(np.int64), s.seed)
            brick = base * (0.8 + 0.4 * tone)[..., None]
            brick *= (1 + 0.08 * grain)[..., None]
            if px > 0.02:
                frac = 1 - (1 - s.mortar / s.brick_len) * (1 - s.mortar / s.course)
                m = np.full(a.shape, frac, dtype=np.float32)
                brick = base * (1 + 0.05 * grain)[..., None]
            else:
                d = np.minimum(np.minimum(fa, s.brick_len - fa), np.minimum(fu, s.course - fu))
                m = _smooth_cover(d, s.mortar / 2, px).astype(np.float32)
            col[:] = brick * (1 - m)[..., None] + np.array(s.mortar_bgr, np.float32) * m[..., None]
        elif s.material == "concrete":
            blot = fbm(a, u, 0.8, s.seed + 3, octaves=4, min_cell=px * 1.5)
            col[:] = base * (1 + 0.10 * blot + 0.16 * grain)[..., None]
            fa = np.mod(a, 1.2)
            fu = np.mod(u, 0.6)
            d = np.minimum(np.minimum(fa, 1.2 - fa), np.minimum(fu, 0.6 - fu))
            m = _smooth_cover(d, 0.002, px) * 0.6
            ha = np.mod(a - 0.3, 0.6) - 0.3
            hu = np.mod(u - 0.3, 0.6) - 0.3
            m = np.maximum(m, _smooth_cover(np.hypot(ha, hu), 0.012, px) * 0.8)
            col[:] = col * (1 - m)[..., None] + np.array(s.mortar_bgr, np.float32) * m[..., None]
        else:
            pa = np.floor(a / s.panel_w)
            pu = np.floor(u / s.panel_h)
            tone = hash2(pa.astype(np.int64), pu.astype(np.int64), s.seed + 5)
            col[:] = base * (0.92 + 0.16 * tone + 0.10 * grain)[..., None]
            fa = a - pa * s.panel_w
            fu = u - pu * s.panel_h
            d = np.minimum(np.minimum(fa, s.panel_w - fa), np.minimum(fu, s.panel_h - fu))
            m = _smooth_cover(d, 0.007, px)
            # fixings: a dark rivet 6 cm in from each panel corner
            ra = np.minimum(np.abs(fa - 0.06), np.abs(s.panel_w - 0.06 - fa))
            ru = np.minimum(np.abs(fu - 0.06), np.abs(s.panel_h - 0.06 - fu))
            m = np.maximum(m, 0.8 * _smooth_cover(np.hypot(ra, ru), 0.008, px))
            col[:] = col * (1 - m)[..., None] + np.array(s.mortar_bgr, np.float32) * m[..., None]
        if s.material != "brick":
            # pores, spatter and dirt specks: the small features real render and cladding give a matcher
            for cell, depth, k in ((0.012, 0.35, 13), (0.03, 0.3, 17)):
                if px < cell:
                    sp = value_noise(a, u, cell, s.seed + k)
                    col *= (1 - depth * np.clip((sp - 0.8) * 6, 0, 1))[..., None]
        # plinth and parapet coping
        plinth = (u < 0.5).astype(np.float32)
        col *= (1 - 0.25 * plinth)[..., None]
        coping = u > s.height_m - 0.3
        col[coping] = np.float32(0.7) * (1 + 0.05 * grain[coping])[..., None]
        shadow = (u > s.height_m - 0.34) & ~coping
        col[shadow] *= np.float32(0.55)
        self._windows(a, u, px, col)
        # large-scale stains (water, dirt)
        st = fbm(a, u, 2.5, s.seed + 21, octaves=3, min_cell=px * 1.5)
        col *= (1 - s.stain * np.clip(st + 0.2, 0, 1))[..., None]
        self._cracks(a, u, px, col)
        return np.clip(col, 0, 1)

    def _windows(self, a, u, px, col):
        s, g = self.style, self.style.grid
        if g.n_floors == 0:
            return
        k = np.floor(u / g.floor_h)
        j = np.floor((a - g.margin) / g.bay_w)
        cx = g.margin + (j + 0.5) * g.bay_w
        u0 = k * g.floor_h + g.sill_h
        valid = (k >= 0) & (k < g.n_floors) & (j >= 0) & (j < g.n_bays)
        la = a - cx
        lu = u - u0
        # rain streaks under the sill
        below = valid & (np.abs(la) < g.win_w / 2) & (lu < 0) & (lu > -1.6)
        if below.any():
            streak = value_noise(a[below] / 0.03, u[below] / 0.7, 1.0, s.seed + 31)
            fade = 1 + lu[below] / 1.6
            col[below] *= (1 - s.stain * 1.5 * fade * streak)[..., None]
        sill = valid & (np.abs(la) < g.win_w / 2 + 0.06) & (lu < 0) & (lu > -0.06)
        col[sill] = np.float32(0.75)
        inwin = valid & (np.abs(la) < g.win_w / 2) & (lu >= 0) & (lu < g.win_h)
        if not inwin.any():
            return
        wa, wu = la[inwin], lu[inwin]
        v = (wu / g.win_h).astype(np.float32)
        # reflection: sky gradient with clouds above a tree line
        zen = np.array([0.75, 0.45, 0.25], np.float32)
        hor = np.array([0.85, 0.78, 0.72], np.float32)
        sky = hor + (zen - hor) * v[..., None]
        cloud = np.clip(fbm(a[inwin] * 0.6, u[inwin], 0.5, s.seed + 41, octaves=3, min_cell=px) * 1.8, 0, 1)
        sky = sky + (np.float32(0.92) - sky) * cloud[..., None]
        tree_line = 0.3 + 0.18 * fbm(a[inwin], np.zeros_like(wu), 0.35, s.seed + 43, octaves=3, min_cell=px)
        tree = v < tree_line
        leaf = 0.7 + 0.3 * value_noise(a[inwin], u[inwin], 0.05, s.seed + 47)
        glass = sky * np.array(s.glass_tint, np.float32)
        glass[tree] = np.array([0.12, 0.22, 0.14], np.float32) * leaf[tree][..., None]
        tone = hash2(np.floor(a[inwin] / 50 + j[inwin]).astype(np.int64), k[inwin].astype(np.int64), s.seed + 9)
        glass *= (0.55 + 0.35 * tone)[..., None]
        # frame, mullion and transom
        fw = g.frame_w
        dx = g.win_w / 2 - np.abs(wa)
        dist = np.minimum(np.minimum(dx, wu), g.win_h - wu)
        fr = _smooth_cover(np.maximum(dist - fw / 2, 0), fw / 2, px)
        fr = np.maximum(fr, _smooth_cover(np.abs(wa), fw / 3, px))
        fr = np.maximum(fr, _smooth_cover(np.abs(wu - 0.72 * g.win_h), fw / 3, px))
        col[inwin] = glass * (1 - fr)[..., None] + np.array(s.frame_bgr, np.float32) * fr[..., None]

    def _cracks(self, a, u, px, col):
        if not self.style.cracks or a.size == 0:
            return
        amin, amax, umin, umax = a.min(), a.max(), u.min(), u.max()
        for c in self.style.cracks:
            p = np.asarray(c.points)
            pad = max(px, c.width_m) * 2
            if p[:, 0].max() + pad < amin or p[:, 0].min() - pad > amax:
                continue
            if p[:, 1].max() + pad < umin or p[:, 1].min() - pad > umax:
                continue
            sel = (a > p[:, 0].min() - pad) & (a < p[:, 0].max() + pad) & (u > p[:, 1].min() - pad) & (
                u < p[:, 1].max() + pad
            )
            if not sel.any():
                continue
            qa, qu = a[sel][:, None], u[sel][:, None]
            p0, p1 = p[:-1], p[1:]
            da, du = (p1 - p0).T
            L2 = np.maximum(da * da + du * du, 1e-12)
            t = np.clip(((qa - p0[:, 0]) * da + (qu - p0[:, 1]) * du) / L2, 0, 1)
            d = np.hypot(qa - (p0[:, 0] + t * da), qu - (p0[:, 1] + t * du)).min(axis=1)
            cov = _smooth_cover(d, c.width_m / 2, px) * 0.85
            col[sel] *= (1 - cov)[..., None].astype(np.float32)

    def full_image(self, mm_per_px: float) -> np.ndarray:
        """The whole wall as one BGR uint8 image (row 0 = top of the wall), for map-accuracy references."""
        s = self.style
        px = mm_per_px / 1000.0
        w = int(math.ceil(s.length_m / px))
        h = int(math.ceil(s.height_m / px))
        out = np.empty((h, w, 3), np.uint8)
        step = 512
        for r0 in range(0, h, step):
            rr = np.arange(r0, min(h, r0 + step))
            uu = s.height_m - (rr + 0.5) * px
            aa, ug = grid_coords((np.arange(w) + 0.5) * px, uu)
            out[r0:r0 + len(rr)] = (self.evaluate(aa, ug, px) * 255 + 0.5).astype(np.uint8)
        return out

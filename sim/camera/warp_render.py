"""Real-time rendering of the facade scene: every plane is a texture warped into the image by its homography.

The scene is a handful of planes (the target building's faces, the ground, the far buildings' and trunks' faces),
the tree crowns (ellipsoids) and the sky at infinity. The ray caster (``render.Renderer``) intersects every pixel's
ray with all of them and evaluates the procedural textures per pixel; that costs 0.2 s per 1280 px frame, so the
live camera could not deliver 30 fps. Here, per plane: clip its rectangle to the view frustum, fill the image
polygon, take its inverse depth (affine in the pixel coordinates for a plane) and keep the pixels where it is
nearer than what is already drawn (a depth test, planes drawn near to far so few pixels are drawn twice), then
warp the plane's pre-built texture patch (``TiledTexture`` tiles at the level matching the pixel footprint) there
with ``cv2.warpPerspective``. The sky is a cube map built once from the ray caster's sky panorama, each cube face
a plane at infinity. Tree crowns keep the exact per-pixel ray test inside their small image rectangles.

Ground truth is the ray caster's: the same surfaces, z-depth from the same plane equations (float32), the same ROI
mask, up to polygon rasterisation on boundary pixels (``tests/test_camera_warp_render.py`` checks it on poses
facing the wall, off its end, looking down and from above the roof). Colours agree closely but not texel for
texel (textures are sampled from cached tiles, haze on the coarse grid). The camera effects are the ray caster's
model (auto exposure, motion blur, read + shot noise) done on uint8 images, except that the noise has one level per
frame, the per-pixel model's root mean square (``_expose``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from companion.errors import CompanionError
from companion.geo import FacadeFrame
from sim.camera.model import CameraModel, TruePose
from sim.camera.noise import fbm
from sim.camera.render import (
    FAR,
    GROUND,
    ROOF,
    SIDE,
    TARGET,
    TREE,
    TRUNK,
    AutoExposure,
    RenderedFrame,
    Renderer,
    _box_hit,
    _ellipsoid_hit,
)
from sim.camera.scene import Scene
from sim.camera.textures import TiledTexture

_NEAR = 0.05  # near clipping plane (m); the ray caster's surfaces start at 1 mm but nothing is that close
_GROUND_FAR_M = 1.0e5  # the ground plane's half extent: the ray caster's ground is infinite
_GROUND_NEAR_M = 40.0  # ground within this distance of the camera is drawn at the footprint's texture level
_FAR_PATCH_M = 2000.0  # the coarse far ground texture covers this far around the camera (hazed beyond)
_SPAN_FILL_PX = 20000  # polygon masks larger than this are filled row by row (cheaper than a per-pixel compare)
_NOISE_ZERO = 15  # the noise table's offset: it holds unit triangular noise (-15..15) + this, as uint8
RENDERERS = ("warp", "raycast")


@dataclass(frozen=True)
class Face:
    """A textured rectangle: points origin + s e1 + t e2 for s in [0, size[0]], t in [0, size[1]], seen from the
    side ``normal`` points to. Texture coordinates are (s + uv_offset[0], t + uv_offset[1])."""

    surface: int
    origin: np.ndarray
    e1: np.ndarray
    e2: np.ndarray
    normal: np.ndarray
    size: tuple[float, float]
    texture: TiledTexture | None  # None: constant ``colour``
    colour: tuple[float, float, float] = (0.0, 0.0, 0.0)
    shade: float = 1.0  # Lambert factor applied to the texture
    haze: bool = False
    min_cos: float = 0.15  # footprint estimate's floor on the viewing angle's cosine
    uv_offset: tuple[float, float] = (0.0, 0.0)
    level: int | None = None  # fixed texture level (2**level mm per texel); None: from the pixel footprint
    max_level: int = 10
    patch_window_m: float | None = None  # texture patch limited to this distance around the camera

    def corners(self) -> np.ndarray:
        s, t = self.size
        o = self.origin
        return np.array([o, o + s * self.e1, o + s * self.e1 + t * self.e2, o + t * self.e2])


class FunctionTexture(TiledTexture):
    """A :class:`TiledTexture` of a colour function ``fn(a, u, px)``."""

    def __init__(self, fn, max_tiles: int = 256):
        super().__init__(max_tiles)
        self._fn = fn

    def evaluate(self, a, u, px):
        return np.clip(self._fn(np.asarray(a, np.float64), np.asarray(u, np.float64), px), 0, 1)


class WarpFrame(RenderedFrame):
    """A :class:`RenderedFrame` whose z-depth and ROI mask are made from the inverse depth buffer and the surface
    ids when first read: the live camera streams only the image, so it does not pay for truth nobody reads (a
    recording reads both, and gets the same values as if they had been made with the frame)."""

    def __init__(self, image: np.ndarray, inverse_depth: np.ndarray, surface: np.ndarray, pose: TruePose,
                 K: np.ndarray, gain: float, pending: _OuterSum | None = None):
        self.image, self.surface, self.pose, self.K, self.gain = image, surface, pose, K, gain
        self._inverse_depth = inverse_depth
        self._pending = pending  # a face covering the frame whose inverse depth is not yet written into the buffer
        self._depth: np.ndarray | None = None
        self._roi: np.ndarray | None = None

    @property
    def inverse_depth(self) -> np.ndarray:
        """float32 1 / z-depth, 0 for sky."""
        if self._pending is not None:
            self._pending.write(self._inverse_depth)
            self._pending = None
        return self._inverse_depth

    def largest_inverse_depth(self) -> float:
        """At least the largest value of ``inverse_depth`` (exactly it when a face covers the frame)."""
        if self._pending is not None:
            return self._pending.largest()
        return float(self._inverse_depth.max())

    @property
    def depth(self) -> np.ndarray:
        if self._depth is None:
            with np.errstate(divide="ignore"):
                self._depth = np.float32(1.0) / self.inverse_depth
        return self._depth

    @property
    def roi_mask(self) -> np.ndarray:
        if self._roi is None:
            self._roi = cv2.compare(self.surface, TARGET, cv2.CMP_EQ)
        return self._roi


class _OuterSum:
    """The inverse depth of a plane over a pixel rectangle, ``row[None, :] + col[:, None]``, computed only where
    read: a face covering the whole frame (the wall face-on) needs its depth buffer only when something else is
    drawn or its truth is read, and most frames draw nothing else."""

    def __init__(self, row: np.ndarray, col: np.ndarray):
        self.row, self.col = row, col
        self.shape = (len(col), len(row))
        self.size = len(col) * len(row)

    def __getitem__(self, key) -> np.ndarray:
        return np.add.outer(self.col[key[0]], self.row[key[1]])

    def write(self, out: np.ndarray) -> None:
        np.add(self.row[None, :], self.col[:, None], out=out)

    def largest(self) -> float:
        return float(np.float32(self.row.max()) + np.float32(self.col.max()))

    def least(self) -> float:
        return float(np.float32(self.row.min()) + np.float32(self.col.min()))


def _vec(*v) -> np.ndarray:
    return np.array(v, dtype=float)


class WarpRenderer(Renderer):
    """Drop-in replacement of :class:`Renderer` (same constructor, ``render`` and truth) at real-time speed."""

    def __init__(self, scene: Scene, frame: FacadeFrame, camera: CameraModel, *, exposure_s: float = 1 / 240,
                 noise: bool = True, blur: bool = True, seed: int = 0):
        super().__init__(scene, frame, camera, exposure_s=exposure_s, noise=noise, blur=blur, seed=seed)
        K = self.K
        self._fx, self._fy = float(K[0, 0]), float(K[1, 1])
        self._cx, self._cy = float(K[0, 2]), float(K[1, 2])
        self._rx_row = self._rx[0].copy()
        self._ry_col = self._ry[:, 0].copy()
        self._faces = self._static_faces()
        self._ground = self._ground_texture()
        self._cube: dict[int, np.ndarray] = {}
        self._patch_cache: dict[int, tuple] = {}
        self._arrays: tuple | None = None
        self._crowns: dict[int, np.ndarray] = {}
        sc = scene
        self._horizon_u8 = tuple(float(c) * 255.0 for c in sc.sky_horizon)
        self._tri = (np.arange(256) % 16 + np.arange(256) // 16).astype(np.uint8)  # sum of two nibbles: 0..30
        self._tri_std = math.sqrt(2 * (16**2 - 1) / 12.0)
        self._noise: np.ndarray | None = None  # the noise table (uint8, _NOISE_ZERO = no noise)
        # the depth buffer only grows while a frame is drawn (nearer surfaces overwrite), so a lower bound of its
        # least value stays one: faces and crowns nearer than nothing of what covers the frame are skipped on it
        self._zb_low = 0.0  # lower bound of the frame's least inverse depth (0: something may still be empty)
        self._zb_exact = True  # _zb_low is the least value itself (nothing drawn since it was read)
        self._drawn = False  # anything drawn in this frame yet
        self._blank: tuple | None = None  # this frame's buffers while not yet zeroed nor written whole (_clear)
        self._dnorm_max = float(self._dnorm.max())  # a surface at distance d has inverse z-depth <= this / d
        self._median_dn2: float | None = None
        W, H = camera.width, camera.height
        self._clip_rays = np.array([[(u + 0.5 - self._cx) / self._fx, (v + 0.5 - self._cy) / self._fy, 1.0]
                                    for u in (-1, W) for v in (-1, H)])  # _polygon's clipping rectangle's corners
        self._dnorm32 = self._dnorm.astype(np.float32)
        self._horizon_img: np.ndarray | None = None

    # ---- the scene as planes -----------------------------------------------------------------------------
    def _lambert(self, n) -> float:
        sc = self.scene
        return float(sc.light * (0.55 + 0.5 * max(0.0, float(np.dot(n, sc.sun_dir)))))

    def _static_faces(self) -> list[Face]:
        sc = self.scene
        L, H, D = sc.length_m, sc.height_m, sc.depth_m
        x, y, z = _vec(1, 0, 0), _vec(0, 1, 0), _vec(0, 0, 1)
        faces = [
            Face(TARGET, _vec(0, 0, 0), x, z, y, (L, H), sc.texture, shade=self._lambert(y)),
            Face(SIDE, _vec(L, 0, 0), -y, z, x, (D, H), sc.side_texture, shade=self._lambert(x)),
            Face(SIDE, _vec(0, -D, 0), y, z, -x, (D, H), sc.side_texture, shade=self._lambert(-x)),
            Face(SIDE, _vec(L, -D, 0), -x, z, -y, (L, H), sc.side_texture, shade=self._lambert(-y)),
            Face(ROOF, _vec(0, -D, H), x, y, z, (L, D), self._roof_texture(), shade=self._lambert(z),
                 uv_offset=(0.0, -D)),
        ]
        for j, b in enumerate(sc.boxes):
            lo, hi = _vec(*b.lo), _vec(*b.hi)
            w, d, h = hi - lo
            sides = [  # (origin, e1, e2, normal, size): the four walls and the roof
                (lo, x, z, -y, (w, h)), (_vec(hi[0], hi[1], lo[2]), -x, z, y, (w, h)),
                (_vec(lo[0], hi[1], lo[2]), -y, z, -x, (d, h)), (_vec(hi[0], lo[1], lo[2]), y, z, x, (d, h)),
                (_vec(lo[0], lo[1], hi[2]), x, y, z, (w, d)),
            ]
            if b.kind == "trunk":
                continue  # thin constant-colour boxes: one exact ray test each (_draw_trunks), not 3 planes
            for o, e1, e2, n, size in sides:
                faces.append(Face(FAR, o, e1, e2, n, size, self._far_texture(j, o, e1, e2, n), haze=True,
                                  max_level=12))
        return faces

    def _roof_texture(self) -> TiledTexture:
        sc = self.scene

        def roof(pa, po, px):
            n = fbm(pa, po, 0.5, sc.seed + 61, octaves=3)
            return (np.float32(0.45) + 0.06 * n)[..., None] * np.array([1.0, 1.0, 1.02], np.float32)

        return FunctionTexture(roof)

    def _far_texture(self, j: int, o, e1, e2, n) -> TiledTexture:
        """A far building's face as the ray caster shades it: colour x Lambert, a window grid on the walls."""
        b = self.scene.boxes[j]
        col = np.array(b.bgr, np.float32) * np.float32(self._lambert(n))
        vertical = abs(n[2]) < 0.5

        def face(s, t, px):
            P = o[None, None, :] + s[..., None] * e1 + t[..., None] * e2
            out = np.broadcast_to(col, s.shape + (3,)).copy()
            if vertical:
                horiz = P[..., 1] if abs(n[0]) > 0.5 else P[..., 0]
                fu = np.mod(P[..., 2], 3.2) / 3.2
                fh = np.mod(horiz, 2.8) / 2.8
                win = (fu > 0.35) & (fu < 0.75) & (fh > 0.2) & (fh < 0.75) & (P[..., 2] > 1.0)
                out[win] = out[win] * 0.45 + np.array([0.35, 0.3, 0.25], np.float32) * 0.4
            return out

        return FunctionTexture(face, max_tiles=16)

    def _ground_texture(self) -> TiledTexture:
        sc = self.scene

        def ground(pa, po, px):
            gsd = px
            paved = (po > -sc.depth_m - 4) & (po < 8) & (pa > -6) & (pa < sc.length_m + 6)
            n1 = fbm(pa, po, 3.0, sc.seed + 71, octaves=5, min_cell=gsd * 2)
            grass = np.array([0.16, 0.36, 0.26], np.float32) * (1 + 0.35 * n1)[..., None]
            slab = np.array([0.55, 0.56, 0.57], np.float32) * (1 + 0.12 * n1)[..., None]
            fa, fo = np.mod(pa, 0.6), np.mod(po, 0.6)
            joint = np.minimum(np.minimum(fa, 0.6 - fa), np.minimum(fo, 0.6 - fo)) < max(0.004, gsd / 2)
            slab[joint] *= np.float32(0.75 if gsd < 0.05 else 0.95)
            return np.where(paved[..., None], slab, grass)

        return FunctionTexture(ground, max_tiles=384)

    def _ground_faces(self, orig) -> list[Face]:
        """The ground plane as two faces: a square around the camera at the footprint's level, and the rest of
        the (practically infinite) plane at a coarse level, drawn after it (same plane: the test keeps the near)."""
        z = _vec(0, 0, 1)
        x, y = _vec(1, 0, 0), _vec(0, 1, 0)
        shade = self._lambert(z)
        r = _GROUND_NEAR_M
        near = Face(GROUND, _vec(orig[0] - r, orig[1] - r, 0.0), x, y, z, (2 * r, 2 * r), self._ground, shade=shade,
                    haze=True, min_cos=0.05, uv_offset=(orig[0] - r, orig[1] - r))
        R = _GROUND_FAR_M
        far = Face(GROUND, _vec(-R, -R, 0.0), x, y, z, (2 * R, 2 * R), self._ground, shade=shade, haze=True,
                   min_cos=0.05, uv_offset=(-R, -R), level=11, max_level=12, patch_window_m=_FAR_PATCH_M)
        return [near, far]

    # ---- projection helpers ------------------------------------------------------------------------------
    def _polygon(self, cam: np.ndarray) -> np.ndarray | None:
        """Camera-frame polygon -> image polygon (pixel index coordinates), clipped to the frustum (1 px
        margin, so its corners are the visible part's extent on the plane), or None if nothing of it is in view."""
        W, H = self.camera.width, self.camera.height
        fx, fy, cx, cy = self._fx, self._fy, self._cx, self._cy
        z = cam[:, 2]
        if (z > _NEAR).all():
            u = fx * cam[:, 0] / z + cx - 0.5
            v = fy * cam[:, 1] / z + cy - 0.5
            if u.max() < -1 or u.min() > W or v.max() < -1 or v.min() > H:
                return None
            if u.min() >= -1 and u.max() <= W and v.min() >= -1 and v.max() <= H:
                return np.column_stack([u, v])
        planes = (
            np.array([0.0, 0.0, 1.0, -_NEAR]),
            np.array([fx, 0.0, cx + 0.5, 0.0]),
            np.array([-fx, 0.0, W - cx + 0.5, 0.0]),
            np.array([0.0, fy, cy + 0.5, 0.0]),
            np.array([0.0, -fy, H - cy + 0.5, 0.0]),
        )
        poly = cam
        for p in planes:
            if len(poly) == 0:
                return None
            d = poly @ p[:3] + p[3]
            out = []
            for i in range(len(poly)):
                a, b = poly[i], poly[(i + 1) % len(poly)]
                da, db = d[i], d[(i + 1) % len(poly)]
                if da >= 0:
                    out.append(a)
                if (da >= 0) != (db >= 0):
                    out.append(a + (b - a) * (da / (da - db)))
            poly = np.array(out)
        if len(poly) < 3:
            return None
        z = poly[:, 2]
        return np.column_stack([fx * poly[:, 0] / z + cx - 0.5, fy * poly[:, 1] / z + cy - 0.5])

    def _rect_mask(self, uv: np.ndarray):
        """Bounding rectangle (x0, y0, x1, y1) of an image polygon and the pixels whose centres lie inside it
        there (the ray caster's rule, so boundaries agree to the pixel): a uint8 0/1 mask, or None when the polygon
        covers the whole rectangle, or None for the whole answer when no pixel centre is inside."""
        W, H = self.camera.width, self.camera.height
        y0, y1 = max(int(math.ceil(uv[:, 1].min())), 0), min(int(math.floor(uv[:, 1].max())) + 1, H)
        if y0 >= y1:
            return None
        # a convex polygon covers one interval of each row: intersect the half-planes of its edges
        # (all edges at once: the same operations per edge and row as one edge at a time, the same values)
        ys = np.arange(y0, y1, dtype=float)
        p, q = uv, np.roll(uv, -1, axis=0)
        area = float(np.sum(p[:, 0] * q[:, 1] - q[:, 0] * p[:, 1]))
        sign = 1.0 if area > 0 else -1.0
        nx, ny = -(q[:, 1] - p[:, 1]) * sign, (q[:, 0] - p[:, 0]) * sign  # inward normal: n . (X - p) >= 0 inside
        flat = np.abs(nx) < 1e-12  # horizontal edges: a row is inside or outside as a whole
        k = ~flat
        bound = p[k, 0][:, None] - ny[k, None] * (ys[None, :] - p[k, 1][:, None]) / nx[k, None]
        lo = np.max(bound[nx[k] > 0], axis=0, initial=-np.inf)
        hi = np.min(bound[nx[k] < 0], axis=0, initial=np.inf)
        for j in np.nonzero(flat & (np.abs(ny) > 1e-12))[0]:
            out = ny[j] * (ys - p[j, 1]) < 0
            lo[out], hi[out] = np.inf, -np.inf
        xl = np.maximum(np.ceil(lo), 0)
        xr = np.minimum(np.floor(hi) + 1, W)  # exclusive
        rows = np.nonzero(xr > xl)[0]
        if len(rows) == 0:
            return None
        r0, r1 = int(rows[0]), int(rows[-1]) + 1
        xl, xr = xl[r0:r1].astype(int), xr[r0:r1].astype(int)
        x0, x1 = int(xl.min()), int(xr.max())
        if (xl == x0).all() and (xr == x1).all():
            mask = None
        elif (r1 - r0) * (x1 - x0) < _SPAN_FILL_PX:
            cols = np.arange(x0, x1)
            mask = ((cols[None, :] >= xl[:, None]) & (cols[None, :] < xr[:, None])).view(np.uint8)
        else:  # a large polygon (the ground, a sky face): its rows' spans filled one by one, not compared per pixel
            mask = np.zeros((r1 - r0, x1 - x0), np.uint8)
            for k, (a, b) in enumerate(zip((xl - x0).tolist(), (xr - x0).tolist(), strict=True)):
                mask[k, a:b] = 1
        return (x0, y0 + r0, x1, y0 + r1), mask

    def _kidx(self, x0: int, y0: int) -> np.ndarray:
        """Camera frame -> pixel index coordinates inside a rectangle starting at (x0, y0)."""
        return np.array([[self._fx, 0.0, self._cx - 0.5 - x0], [0.0, self._fy, self._cy - 0.5 - y0], [0, 0, 1.0]])

    # ---- textures ----------------------------------------------------------------------------------------
    def wall_level(self, distance_m: float) -> int:
        """The wall's texture level (2**level mm per texel) when seen face-on from ``distance_m``: ``_level``'s
        rule (texel about 1.5 x the median pixel footprint) for a fronto-parallel plane, whose footprint at a
        pixel is distance x (1 + rx^2 + ry^2) / fx."""
        if self._median_dn2 is None:
            self._median_dn2 = float(np.median(self._rx_row[None, ::8] ** 2 + self._ry_col[::8, None] ** 2 + 1.0))
        texel_mm = distance_m * self._median_dn2 / self._fx * 1000.0 * 1.5
        return int(np.clip(math.floor(math.log2(max(texel_mm, 1.0))), 0, self._faces[0].max_level))

    def prefetch_wall(self, level: int, along_m: float, up_m: float, max_tiles: int = 1) -> int:
        """Build up to ``max_tiles`` missing wall texture tiles at ``level``, nearest to the wall point (along_m,
        up_m) first, among the nearest half of the tile cache's capacity (so prefetching never evicts what it
        built). The live camera calls this while it waits for the vehicle's next pose, so the tiles a climb
        needs are ready before it gets there instead of costing ~30 ms each in the middle of a frame. Returns
        the number built (0: everything near is ready)."""
        tex, sc = self.scene.texture, self.scene
        span = tex.TILE * (2**level) / 1000.0
        nx, ny = int(math.floor(sc.length_m / span)) + 1, int(math.floor(sc.height_m / span)) + 1
        ix, iy = np.meshgrid(np.arange(nx), np.arange(ny))
        d = np.hypot((ix + 0.5) * span - along_m, (iy + 0.5) * span - up_m).ravel()
        near = np.argsort(d, kind="stable")[: max(1, tex.max_tiles // 2)]
        built = 0
        for k in near:
            i, j = int(ix.flat[k]), int(iy.flat[k])
            if not tex.has_tile(level, i, j):
                tex.tile(level, i, j)
                built += 1
                if built >= max_tiles:
                    break
        return built

    def _level(self, f: Face, w, vis, g, X0: int, Y0: int) -> int:
        """Texture level of a face from its median pixel footprint (a 1-in-16 sample), as the ray caster picks
        it: texel about 1.5 x the footprint, rounded down to a power of two."""
        if f.level is not None:
            return f.level
        # about 2000 samples; 400 for the hazed faces (far buildings, ground), whose level matters less
        step = max(1, int(math.sqrt(w.size / (400 if f.haze else 2000))))
        if vis is None:  # every pixel visible
            sub = np.ones(w[::step, ::step].shape, bool)
        else:
            if not vis[::step, ::step].any():
                step = 1
            sub = vis[::step, ::step] != 0
        ys, xs = np.nonzero(sub)
        ws = w[::step, ::step][sub]
        px = X0 + xs * step
        py = Y0 + ys * step
        rx, ry = self._rx_row[px], self._ry_col[py]
        dn = np.sqrt(rx * rx + ry * ry + 1.0)
        g = g / np.linalg.norm(g)  # the face normal in camera axes
        cos = np.maximum(np.abs(g[0] * rx + g[1] * ry + g[2]) / dn, f.min_cos)
        gsd = float(np.median(dn / ws / self._fx / cos))
        texel_mm = gsd * 1000.0 * 1.5
        return int(np.clip(math.floor(math.log2(max(texel_mm, 1.0))), 0, f.max_level))

    def _patch(self, f: Face, key: int, s0, t0, s1, t1, level, pixels: int):
        """Shaded BGRA texture patch covering face coordinates [s0, s1] x [t0, t1] (cached while it covers them).
        At most about 4 texels per pixel drawn: a plane seen at a grazing angle (the ground) spans footprints
        from millimetres to metres, and tiles at the median footprint over all of it would cost more than the
        frame; its far part is hazed and sampled below its texel size anyway."""
        tex = f.texture
        a0, a1 = s0 + f.uv_offset[0], s1 + f.uv_offset[0]
        u0, u1 = t0 + f.uv_offset[1], t1 + f.uv_offset[1]
        cap = min(12e6, max(4.0 * pixels, 4.0 * tex.TILE**2))
        while ((a1 - a0) * 1000 / 2**level) * ((u1 - u0) * 1000 / 2**level) > cap and level < f.max_level + 2:
            level += 1
        hit = self._patch_cache.get(key)
        if hit is not None:  # the cached patch still covers the range at this level: no rebuild
            (lvl, ca0, cu0, ca1, cu1), got = hit
            if lvl == level and ca0 <= a0 and a1 <= ca1 and cu0 <= u0 and u1 <= cu1:
                return got
        # a new patch reaches a tile further on every side (within the face), so a moving camera rebuilds it
        # about once per tile it travels, and a hovering or wobbling one across a tile border not every frame
        pad = tex.TILE * (2**level) / 1000.0
        fa0, fu0 = f.uv_offset
        fa1, fu1 = fa0 + f.size[0], fu0 + f.size[1]
        a0, u0 = max(min(a0, a0 - pad), min(a0, fa0)), max(min(u0, u0 - pad), min(u0, fu0))
        a1, u1 = min(max(a1, a1 + pad), max(a1, fa1)), min(max(u1, u1 + pad), max(u1, fu1))
        patch, ao, uo, px = tex.patch(a0, u0, max(a1, a0 + 1e-3), max(u1, u0 + 1e-3), level)
        if f.shade != 1.0:  # the face's Lambert factor, applied once per patch rather than per frame
            patch = cv2.convertScaleAbs(patch, alpha=f.shade)
        patch = cv2.cvtColor(patch, cv2.COLOR_BGR2BGRA)  # 4 channels: see _warp
        got = (patch, ao, uo, px)
        self._patch_cache[key] = ((level, ao, uo, ao + patch.shape[1] * px, uo + patch.shape[0] * px), got)
        return got

    def _cube_face(self, k: int, n, e1, e2) -> np.ndarray:
        """Sky cube face ``k`` (uint8, N x N over tan -1..1) resampled from the ray caster's sky panorama."""
        if k not in self._cube:
            pano = self._sky_panorama()
            h, w = pano.shape[0], pano.shape[1] - 1
            N = int(np.clip(self._fx, 64, 2048))
            c = -1.0 + (np.arange(N) + 0.5) * 2.0 / N
            S, T = np.meshgrid(c, c)
            d = n[None, None] + S[..., None] * e1 + T[..., None] * e2
            d /= np.linalg.norm(d, axis=-1, keepdims=True)
            az = np.mod(np.arctan2(d[..., 0], d[..., 1]), 2 * math.pi)
            el = np.degrees(np.arcsin(np.clip(d[..., 2], -1, 1)))
            mx = (az / (2 * math.pi) * w - 0.5).astype(np.float32)
            my = ((el + 1.0) / 91.0 * h - 0.5).astype(np.float32)
            img = cv2.remap(pano, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
            self._cube[k] = cv2.cvtColor(cv2.convertScaleAbs(img, alpha=255.0), cv2.COLOR_BGR2BGRA)
        return self._cube[k]

    # ---- drawing -----------------------------------------------------------------------------------------
    def radiance_u8(self, pose: TruePose):
        """Scene colour (BGR uint8, radiance x 255 before exposure), z-depth (float32, inf for sky), surfaces."""
        img, zb, sid = self._radiance(pose)
        self._settle(zb)  # a face filling the frame leaves its inverse depth pending (render's frame writes it)
        with np.errstate(divide="ignore"):
            return img, np.float32(1.0) / zb, sid

    def _radiance(self, pose: TruePose):
        """``radiance_u8`` with inverse z-depth (0 for sky) instead of z-depth: what the drawing keeps."""
        A = self.M @ pose.R_world_from_cam  # facade <- camera
        orig = self.M @ pose.position_enu
        W, H = self.camera.width, self.camera.height
        img = np.empty((H, W, 3), np.uint8)
        zb = np.empty((H, W), np.float32)  # inverse z-depth: 0 = nothing (sky)
        sid = np.empty((H, W), np.uint8)
        # zeroed (_clear) before the first partial write; a first face filling the frame writes every pixel of
        # all three (the wall face-on: most frames), which then are never zeroed
        self._blank = (img, zb, sid)
        faces = self._faces + self._ground_faces(orig)
        cams, order, dist = self._candidates(faces, A, orig)
        self._zb_low, self._zb_exact, self._drawn = 0.0, True, False
        self._zb_pending: _OuterSum | None = None
        for i in order:
            if self._zb_low * float(dist[i]) > self._dnorm_max * 1.001:  # behind what covers the whole frame
                continue
            self._draw_face(faces[i], i, cams[i], A, orig, img, zb, sid)
        # trunks and crowns (boxes, then crowns, as _object_rects lists them), unless all are behind what covers
        # the frame (the wall face-on): their tests below would skip every one on the same bound
        near = np.linalg.norm(np.maximum(np.maximum(self._obj_lo - orig, 0.0), orig - self._obj_hi), axis=1)
        if not (self._zb_low * near > self._dnorm_max * 1.001).all():
            self._clear()
            self._settle(zb)
            rects, near = self._object_rects(orig, A)
            self._draw_trunks(A, orig, img, zb, sid, rects, near)
            self._draw_trees(A, orig, img, zb, sid, rects[len(self.scene.boxes):], near[len(self.scene.boxes):])
        if self._zb_low == 0.0:  # else every pixel is drawn: no sky in view
            self._clear()
            self._settle(zb)
            self._draw_sky(A, img, zb)
        self._clear()  # (nothing was drawn: all sky, already cleared above)
        return img, zb, sid

    def _clear(self) -> None:
        """Zero the frame's image, depth and surface buffers unless done or a face filling the frame wrote them."""
        if self._blank is not None:
            for b in self._blank:
                b.fill(0)
            self._blank = None

    def _settle(self, zb: np.ndarray) -> None:
        """Write a pending face's inverse depth into the depth buffer before anything reads it."""
        if self._zb_pending is not None:
            self._zb_pending.write(zb)
            self._zb_pending = None

    def _candidates(self, faces: list[Face], A, orig) -> tuple[np.ndarray, list[int], np.ndarray]:
        """Camera-frame corners of all faces, the faces turned towards the camera that may be in view, nearest
        first (fewer pixels drawn twice; the far ground last), and each face's distance from the camera (its
        nearest point). One vectorised pass over all faces."""
        if self._arrays is None or len(self._arrays[0]) != len(faces):
            self._arrays = tuple(np.array(v) for v in zip(*[(f.origin, f.e1, f.e2, f.normal, f.size, f.corners())
                                                             for f in faces], strict=True))
        org, E1, E2, N, S, C = self._arrays
        org, C = org.copy(), C.copy()
        for k in (-2, -1):  # the ground faces follow the camera
            f = faces[k]
            org[k], C[k] = f.origin, f.corners()
        rel = orig - org
        front = np.einsum("ij,ij->i", rel, N) > 0
        s = np.clip(np.einsum("ij,ij->i", rel, E1), 0.0, S[:, 0])
        t = np.clip(np.einsum("ij,ij->i", rel, E2), 0.0, S[:, 1])
        dist = np.linalg.norm(rel - s[:, None] * E1 - t[:, None] * E2, axis=1)
        cams = (C - orig) @ A
        z = cams[..., 2]
        ahead = z > _NEAR
        W, H = self.camera.width, self.camera.height
        with np.errstate(divide="ignore", invalid="ignore"):
            u = self._fx * cams[..., 0] / z + self._cx - 0.5
            v = self._fy * cams[..., 1] / z + self._cy - 0.5
        outside = ahead.all(axis=1) & ((u.max(1) < -1) | (u.min(1) > W) | (v.max(1) < -1) | (v.min(1) > H))
        keep = np.nonzero(front & ahead.any(axis=1) & ~outside)[0]
        # the ground faces (the last two) go after everything else: everything stands on the ground and the
        # camera is above it, so the ground never hides anything, while drawn first (low over the ground, it is
        # the nearest face) it would be warped and hazed only to be covered by the wall
        rank = dist.copy()
        rank[-2], rank[-1] = np.finfo(np.float64).max / 2, np.inf  # near ground, then far ground
        return cams, [int(i) for i in keep[np.argsort(rank[keep], kind="stable")]], dist

    def _draw_face(self, f: Face, key: int, cam, A, orig, img, zb, sid):
        # inverse depth of the plane n.X = n.O along the ray A (rx, ry, 1): affine in (rx, ry)
        g = (A.T @ f.normal) / float(f.normal @ (f.origin - orig))
        # behind what covers the frame everywhere in it (its largest value there is at a corner of the clipping
        # rectangle, 1 px outside the frame, so _hidden would say so too): not even projected and clipped
        if self._zb_low > float((self._clip_rays @ g).max()) * 1.001:
            return
        uv = self._polygon(cam)
        if uv is None:
            return
        if self._hidden(uv, g, zb):
            return
        got = self._rect_mask(uv)
        if got is None:
            return
        (x0, y0, x1, y1), mask = got
        w_row = np.float32(g[0]) * self._rx_row[x0:x1]
        w_col = np.float32(g[1]) * self._ry_col[y0:y1] + np.float32(g[2])
        if not (not self._drawn and mask is None and (x1 - x0) * (y1 - y0) == zb.size):
            self._clear()  # a partial write: the buffers must hold 0 (nothing) everywhere else
        else:
            self._blank = None  # the face fills the frame: every pixel of image, depth, surfaces written below
        if not self._drawn and mask is None:  # (nothing drawn yet: the depth buffer is all 0)
            # the first face drawn there and its polygon covers the rectangle (the wall filling the view): every
            # pixel is visible; its inverse depth goes straight into the depth buffer
            X0, Y0, bw, bh = x0, y0, x1 - x0, y1 - y0
            out = (slice(Y0, Y0 + bh), slice(X0, X0 + bw))
            if bw * bh == zb.size:  # the whole frame: written when read (_settle), maybe never
                w = self._zb_pending = _OuterSum(w_row, w_col)
            else:
                w = np.add(w_row[None, :], w_col[:, None], out=zb[out])
            vis = None
            full = True
        else:  # the depth test as a uint8 mask (non-zero: visible), OpenCV masked copies below
            w = w_row[None, :] + w_col[:, None]
            vis = cv2.compare(w, zb[y0:y1, x0:x1], cv2.CMP_GT)
            if mask is not None:
                vis = cv2.bitwise_and(vis, mask)
            bx, by, bw, bh = cv2.boundingRect(vis)
            if bw == 0 or bh == 0:
                return
            sl = (slice(by, by + bh), slice(bx, bx + bw))
            vis, w = vis[sl], w[sl]
            X0, Y0 = x0 + bx, y0 + by
            out = (slice(Y0, Y0 + bh), slice(X0, X0 + bw))
            full = cv2.countNonZero(vis) == bw * bh  # the nearest face where nothing was drawn yet
        self._drawn, self._zb_exact = True, False
        if full and bw * bh == zb.size:  # the face covers the frame: its least inverse depth is at a corner (affine)
            least = w.least() if isinstance(w, _OuterSum) else float(min(w[0, 0], w[0, -1], w[-1, 0], w[-1, -1]))
            self._zb_low, self._zb_exact = least, True
        if full:
            if vis is not None:
                zb[out] = w
            sid[out] = f.surface
        else:
            cv2.copyTo(w, vis, dst=zb[out])
            cv2.copyTo(np.full((bh, bw), f.surface, np.uint8), vis, dst=sid[out])
        if f.texture is None:
            col = np.clip(np.array(f.colour) * 255.0 + 0.5, 0, 255).astype(np.uint8)
            if full:
                img[out] = col
            else:
                cv2.copyTo(np.broadcast_to(col, (bh, bw, 3)).copy(), vis, dst=img[out])
            return
        self._draw_texture(f, key, A, orig, uv, g, w, vis, (X0, Y0, bw, bh), full, img)

    def _draw_texture(self, f: Face, key: int, A, orig, uv, g, w, vis, box, full: bool, img) -> None:
        """The visible part of a textured face: its patch at the level the frame needs, warped by the face's
        homography into ``box`` (X0, Y0, width, height) of ``img``, hazed if the face is, copied where ``vis``."""
        X0, Y0, bw, bh = box
        out = (slice(Y0, Y0 + bh), slice(X0, X0 + bw))
        level = self._level(f, w, vis, g, X0, Y0)
        # the visible part's extent on the face (from the clipped polygon's corners, in face coordinates)
        s0, t0, s1, t1 = self._face_extent(f, A, orig, uv)
        if f.patch_window_m is not None:
            r = f.patch_window_m
            cs, ct = float((orig - f.origin) @ f.e1), float((orig - f.origin) @ f.e2)
            s0, s1 = max(s0, cs - r), min(s1, cs + r)
            t0, t1 = max(t0, ct - r), min(t1, ct + r)
            if s0 >= s1 or t0 >= t1:
                s0, s1, t0, t1 = cs - 1, cs + 1, ct - 1, ct + 1
        patch, ao, uo, px = self._patch(f, key, s0, t0, s1, t1, level, bw * bh)
        T1 = np.array([[px, 0.0, ao + 0.5 * px - f.uv_offset[0]], [0.0, px, uo + 0.5 * px - f.uv_offset[1]],
                       [0.0, 0.0, 1.0]])
        P = np.column_stack([A.T @ f.e1, A.T @ f.e2, A.T @ (f.origin - orig)])
        Hm = self._kidx(X0, Y0) @ P @ T1
        if full and not f.haze:
            self._warp(patch, Hm, (bw, bh), dst=img[out])
            return
        col = self._warp(patch, Hm, (bw, bh))
        if f.haze:
            col = self._hazed(col, w, X0, Y0)
        if full:
            img[out] = col
        else:
            cv2.copyTo(col, vis, dst=img[out])

    @staticmethod
    def _warp(patch4: np.ndarray, Hm: np.ndarray, size: tuple[int, int], dst: np.ndarray | None = None) -> np.ndarray:
        """Bilinear perspective warp of a BGRA patch to BGR. OpenCV vectorises the 4-channel warp (about half the
        time of the 3-channel one at 1280 x 720); dropping the alpha channel afterwards costs far less."""
        col = cv2.warpPerspective(patch4, Hm, size, flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        if dst is None:
            return cv2.cvtColor(col, cv2.COLOR_BGRA2BGR)
        return cv2.cvtColor(col, cv2.COLOR_BGRA2BGR, dst=dst)

    def _hidden(self, uv, g, zb) -> bool:
        """True if something nearer already covers the polygon's whole bounding box (far buildings behind the
        wall): the plane's inverse depth is affine, so its largest value is at a corner."""
        W, H = self.camera.width, self.camera.height
        x0, y0 = max(int(uv[:, 0].min()), 0), max(int(uv[:, 1].min()), 0)
        x1, y1 = min(int(uv[:, 0].max()) + 2, W), min(int(uv[:, 1].max()) + 2, H)
        if x0 >= x1 or y0 >= y1:
            return True
        w_max = float(np.max(g[0] * (uv[:, 0] + 0.5 - self._cx) / self._fx + g[1] * (uv[:, 1] + 0.5 - self._cy)
                             / self._fy + g[2]))
        if self._zb_low > w_max * 1.001:  # the frame is covered by nearer surfaces
            return True
        if not self._drawn:  # the depth buffer is still all 0
            return w_max * 1.001 < 0.0
        # a small box (a far building's) reads only its own pixels; a large one the whole frame, whose least value
        # then serves the faces after it (the wall filling the view hides them all)
        self._settle(zb)
        if not self._zb_exact and 4 * (x1 - x0) * (y1 - y0) >= W * H:
            self._zb_low, self._zb_exact = float(zb.min()), True
            if self._zb_low > w_max * 1.001:
                return True
        return float(zb[y0:y1, x0:x1].min()) > w_max * 1.001

    def _face_extent(self, f: Face, A, orig, uv) -> tuple[float, float, float, float]:
        """Face coordinates spanned by the image polygon (its corners cast back onto the plane)."""
        rx = (uv[:, 0] + 0.5 - self._cx) / self._fx
        ry = (uv[:, 1] + 0.5 - self._cy) / self._fy
        D = np.column_stack([rx, ry, np.ones_like(rx)]) @ A.T
        with np.errstate(divide="ignore", invalid="ignore"):
            t = float(f.normal @ (f.origin - orig)) / (D @ f.normal)
            P = orig + D * t[:, None] - f.origin
            s, tt = P @ f.e1, P @ f.e2
        ok = np.isfinite(s) & np.isfinite(tt) & (t > 0)
        if not ok.all():  # a corner on the horizon (grazing ray): the whole face, bounded by its size
            return 0.0, 0.0, f.size[0], f.size[1]
        return (max(float(s.min()), 0.0), max(float(tt.min()), 0.0), min(float(s.max()), f.size[0]),
                min(float(tt.max()), f.size[1]))

    def _hazed(self, col, w, X0, Y0):
        """Aerial perspective (the ray caster's: exp(-range / 900 m) towards the horizon colour), from the range
        on an 8x coarser grid (smooth on a plane) bilinearly resized."""
        h, wd = w.shape
        ws = w[::8, ::8]
        rx = self._rx_row[X0:X0 + wd:8][None, :]
        ry = self._ry_col[Y0:Y0 + h:8][:, None]
        with np.errstate(divide="ignore", invalid="ignore"):
            r = np.sqrt(rx * rx + ry * ry + 1.0) / np.maximum(ws, 1e-9)
        keep = np.exp(-r / np.float32(900.0)).astype(np.float32)
        lo, hi = float(keep.min()), float(keep.max())
        if lo > 0.998:
            return col
        if self._horizon_img is None:  # the horizon colour as an image, made once
            self._horizon_img = np.empty((self.camera.height, self.camera.width, 3), np.uint8)
            self._horizon_img[:] = np.round(self._horizon_u8).astype(np.uint8)
        if hi - lo < 0.004:  # a small or far face: one blend weight, within 0.002 x 255 = 0.5 DN of the per-pixel one
            k = 0.5 * (lo + hi)
            return cv2.addWeighted(col, k, self._horizon_img[:h, :wd], 1.0 - k, 0.0)
        keep = cv2.resize(keep, (wd, h), interpolation=cv2.INTER_LINEAR)
        return cv2.blendLinear(col, self._horizon_img[:h, :wd], keep, np.float32(1.0) - keep)

    def _rect_rays(self, rect, A):
        """Ray directions (facade axes, camera z = 1) of the pixels of an image rectangle."""
        rx = self._rx_row[rect[1]][None, :]
        ry = self._ry_col[rect[0]][:, None]
        return tuple(np.float32(A[k, 0]) * rx + np.float32(A[k, 1]) * ry + np.float32(A[k, 2]) for k in range(3))

    def _draw_trunks(self, A, orig, img, zb, sid, rects, nears):
        """Tree trunks: the ray caster's box test inside each trunk's small image rectangle."""
        col = np.clip(np.array([0.1, 0.15, 0.2]) * self._lambert(_vec(0, 1, 0)) * 255 + 0.5, 0, 255).astype(np.uint8)
        for j, b in enumerate(self.scene.boxes):
            rect = rects[j]
            if b.kind != "trunk" or rect is None or self._zb_low * float(nears[j]) > self._dnorm_max * 1.001:
                continue  # (the last: behind what covers the whole frame)
            lo, hi = np.array(b.lo), np.array(b.hi)
            zr = zb[rect]
            near = float(nears[j])
            if near > 0 and float(zr.min()) * near > 1.001:
                continue
            th, _ = _box_hit(orig.astype(np.float32), self._rect_rays(rect, A), lo, hi)
            with np.errstate(divide="ignore"):
                w = np.float32(1.0) / th
            vis = w > zr
            if vis.any():
                zr[vis] = w[vis]
                sid[rect][vis] = TRUNK
                img[rect][vis] = col

    def _draw_trees(self, A, orig, img, zb, sid, rects, nears):
        sc = self.scene
        for ti, tr in enumerate(sc.trees):
            rect = rects[ti]
            if rect is None or self._zb_low * float(nears[ti]) > self._dnorm_max * 1.001:
                continue  # (the last: behind what covers the whole frame)
            rad = np.array([tr.radius, tr.radius, tr.radius * tr.squash])
            c = np.array(tr.centre)
            rect = self._ellipse_rect(c, rad, orig, A, rect)
            if rect is None:
                continue
            zr = zb[rect]
            near = float(nears[ti])
            if near > 0 and float(zr.min()) * near > 1.001:  # everything there is nearer than the crown's box
                continue
            # the crown's inverse z-depth at a pixel is at most dnorm / near (its nearest point, seen along that
            # pixel's ray); pixels where something at least that near is drawn (the wall in front) are skipped
            cand = None
            if near > 0:
                cand = cv2.compare(zr * np.float32(near), self._dnorm32[rect] * np.float32(1.001), cv2.CMP_LT)
                n_cand = cv2.countNonZero(cand)
                if n_cand == 0:
                    continue
                if n_cand > cand.size // 2:
                    cand = None  # mostly uncovered: the whole rectangle is cheaper than gathering
            if cand is None:
                Dc = self._rect_rays(rect, A)
                th = _ellipsoid_hit(orig.astype(np.float32), Dc, c, rad)
                with np.errstate(divide="ignore"):
                    w = (np.float32(1.0) / th).astype(np.float32)
                vis = w > zr
                if not vis.any():
                    continue
                where = vis  # a boolean mask indexes faster than index arrays
                Dv, t = [d[vis] for d in Dc], th[vis]
                w = w[vis]
            else:  # the same ray test on the candidate pixels only (same float32 operations, same values)
                ys, xs = np.nonzero(cand)
                rx = self._rx_row[rect[1]][xs]
                ry = self._ry_col[rect[0]][ys]
                Dc = tuple(np.float32(A[k, 0]) * rx + np.float32(A[k, 1]) * ry + np.float32(A[k, 2]) for k in range(3))
                th = _ellipsoid_hit(orig.astype(np.float32), Dc, c, rad)
                with np.errstate(divide="ignore"):
                    w = (np.float32(1.0) / th).astype(np.float32)
                vis = w > zr[ys, xs]
                if not vis.any():
                    continue
                where = (ys[vis], xs[vis])
                Dv, t = [d[vis] for d in Dc], th[vis]
                w = w[vis]
            zr[where] = w
            sid[rect][where] = TREE
            unit = [(orig[k] + Dv[k] * t - c[k]) / rad[k] for k in range(3)]
            col = self._crown_colour(ti, unit)
            keep = math.exp(-float(np.linalg.norm(c - orig)) / 900.0)  # haze: a crown is small against 900 m
            col = col.astype(np.float32) * np.float32(keep) + np.array(self._horizon_u8, np.float32) * (1 - keep)
            img[rect][where] = np.clip(col + 0.5, 0, 255).astype(np.uint8)

    def _ellipse_rect(self, c, rad, orig, A, rect):
        """The image rectangle of an ellipsoid's outline (its projection is an ellipse, whose extent in x/z is
        where a plane through the camera touches the ellipsoid), within ``rect`` (its bounding box's, which can
        be twice the area): the ray test then runs only where a ray can hit. ``rect`` itself when the ellipsoid
        reaches behind the camera's near plane; None when no pixel centre can see it."""
        m = (c - orig) @ A  # centre in camera axes; a point of the ellipsoid is m + s @ Q for |s| = 1
        Q = rad[:, None] * A
        qz = Q[:, 2]
        a = m[2] * m[2] - qz @ qz
        if m[2] - math.sqrt(qz @ qz) <= 0.05 or a <= 0:
            return rect
        bounds = []
        for j, f, cc, n in ((0, self._fx, self.K[0, 2], self.camera.width), (1, self._fy, self.K[1, 2],
                                                                                  self.camera.height)):
            q = Q[:, j]
            b = m[j] * m[2] - q @ qz
            disc = b * b - a * (m[j] * m[j] - q @ q)
            if disc < 0:
                return rect
            k0, k1 = (b - math.sqrt(disc)) / a, (b + math.sqrt(disc)) / a
            lo, hi = max(int(math.floor(f * k0 + cc)) - 1, 0), min(int(math.ceil(f * k1 + cc)) + 1, n)
            bounds.append((lo, hi))
        (u0, u1), (v0, v1) = bounds
        v0, v1 = max(v0, rect[0].start), min(v1, rect[0].stop)
        u0, u1 = max(u0, rect[1].start), min(u1, rect[1].stop)
        if u0 >= u1 or v0 >= v1:
            return None
        return (slice(v0, v1), slice(u0, u1))

    def _crown_colour(self, ti: int, unit) -> np.ndarray:
        """Crown colour (N x 3 uint8) at unit-sphere points of tree ``ti``'s ellipsoid, looked up in a texture
        over (azimuth, polar angle) built once from the ray caster's leaf shading, instead of per pixel."""
        tex = self._crowns.get(ti)
        if tex is None:
            tr = self.scene.trees[ti]
            c = np.array(tr.centre)
            rad = np.array([tr.radius, tr.radius, tr.radius * tr.squash])
            nphi, nth = 512, 256
            phi = (np.arange(nphi + 1) + 0.5) / nphi * 2 * math.pi  # one wrapped column for interpolation
            th = (np.arange(nth) + 0.5) / nth * math.pi
            PH, TH = np.meshgrid(phi, th)
            P = c + rad * np.stack([np.sin(TH) * np.cos(PH), np.sin(TH) * np.sin(PH), np.cos(TH)], -1).reshape(-1, 3)
            col = self._tree(P, np.full(len(P), ti), np.zeros(len(P)))
            tex = cv2.convertScaleAbs(col.reshape(nth, nphi + 1, 3), alpha=255.0)
            self._crowns[ti] = tex
        nth, nphi = tex.shape[0], tex.shape[1] - 1
        phi = np.mod(np.arctan2(unit[1], unit[0]), 2 * math.pi)
        th = np.arccos(np.clip(unit[2], -1.0, 1.0))
        n = len(phi)
        cols = 1024
        rows = -(-n // cols)
        mx = np.zeros(rows * cols, np.float32)
        my = np.zeros(rows * cols, np.float32)
        mx[:n] = phi / (2 * math.pi) * nphi - 0.5
        my[:n] = th / math.pi * nth - 0.5
        out = cv2.remap(tex, mx.reshape(rows, cols), my.reshape(rows, cols), cv2.INTER_LINEAR,
                        borderMode=cv2.BORDER_REPLICATE)
        return out.reshape(-1, 3)[:n]

    def _draw_sky(self, A, img, zb):
        empty = cv2.compare(zb, 0.0, cv2.CMP_EQ)  # uint8 mask: nothing drawn (non-zero)
        bx, by, bw, bh = cv2.boundingRect(empty)
        if bw == 0 or bh == 0:
            return
        axes = [_vec(1, 0, 0), _vec(0, 1, 0), _vec(0, 0, 1)]
        # the rays of the frame's corner pixels (facade axes): every pixel's ray is a positive combination of them,
        # so a cube face none of them points into (ray . normal <= 0) holds no pixel and is not even projected
        rays = np.array([[self._rx_row[i], self._ry_col[j], 1.0] for i in (0, -1) for j in (0, -1)]) @ A.T
        for k in range(6):
            n = axes[k // 2] * (1 if k % 2 == 0 else -1)
            if (rays @ n <= 0.0).all():
                continue
            e1, e2 = axes[(k // 2 + 1) % 3], axes[(k // 2 + 2) % 3]
            corners = np.array([n - e1 - e2, n + e1 - e2, n + e1 + e2, n - e1 + e2])
            uv = self._polygon(corners @ A)
            if uv is None:
                continue
            got = self._rect_mask(uv)
            if got is None:
                continue
            (x0, y0, x1, y1), mask = got
            x0, y0, x1, y1 = max(x0, bx), max(y0, by), min(x1, bx + bw), min(y1, by + bh)
            if x0 >= x1 or y0 >= y1:
                continue
            sel = empty[y0:y1, x0:x1]
            if mask is not None:
                sel = cv2.bitwise_and(sel, mask[y0 - got[0][1]:y1 - got[0][1], x0 - got[0][0]:x1 - got[0][0]])
            if not cv2.countNonZero(sel):
                continue
            tex = self._cube_face(k, n, e1, e2)
            N = tex.shape[0]
            T1 = np.array([[2.0 / N, 0.0, -1.0 + 1.0 / N], [0.0, 2.0 / N, -1.0 + 1.0 / N], [0.0, 0.0, 1.0]])
            Hm = self._kidx(x0, y0) @ np.column_stack([A.T @ e1, A.T @ e2, A.T @ n]) @ T1
            col = self._warp(tex, Hm, (x1 - x0, y1 - y0))
            cv2.copyTo(col, sel, dst=img[y0:y1, x0:x1])

    # ---- camera effects ----------------------------------------------------------------------------------
    def render(self, pose: TruePose, *, index: int = 0, time_s: float = 0.0,
               exposure: AutoExposure | None = None) -> RenderedFrame:
        img, zb, sid = self._radiance(pose)
        mean = float(np.mean(cv2.mean(img)[:3])) / 255.0
        if exposure is not None:
            gain = exposure.update(mean, time_s)
        else:
            gain = float(np.clip(0.42 / max(mean, 1e-3), 0.6, 1.7))
        frame = WarpFrame(img, zb, sid, pose, self.K.copy(), gain, pending=self._zb_pending)
        self._zb_pending = None
        if self.blur and self.exposure_s > 0:
            img = self._blurred(img, frame)
        frame.image = self._expose(img, gain, index, mean)
        return frame

    def _blurred(self, img: np.ndarray, frame: WarpFrame) -> np.ndarray:
        """The ray caster's motion blur (``Renderer._motion_blur``), its blur vectors from a 1-in-16 sample of the
        depth (the same values): the full z-depth is converted only if the far layer needs a blur of its own."""
        pose = frame.pose
        # a bound first: the median depth is at least 1 / the largest inverse depth, so the translation's blur is at
        # most |v| f t_exp x that; below half a pixel with the rotation's, neither layer is blurred (most frames)
        v = pose.R_world_from_cam.T @ np.asarray(pose.velocity_enu_m_s, dtype=float)
        w = np.asarray(pose.angular_rate_cam_rad_s, dtype=float)
        ft = float(self.K[0, 0]) * self.exposure_s
        if float(np.hypot(w[0], w[1])) * ft + float(np.hypot(v[0], v[1])) * ft * frame.largest_inverse_depth() < 0.49:
            return img
        with np.errstate(divide="ignore"):
            sub = np.float32(1.0) / frame.inverse_depth[::4, ::4]
        near, far = self.blur_vectors_sampled(sub, pose)
        if float(np.hypot(*near)) < 0.5 and float(np.hypot(*far)) < 0.5:
            return img  # nothing to blur (_line_blur returns its input below half a pixel)
        return self._motion_blur(img, frame.depth, frame.pose)

    def _expose(self, img: np.ndarray, gain: float, index: int, mean: float) -> np.ndarray:
        """Gain and sensor noise in one saturating OpenCV pass: round(v x gain + n x k), n a window of a noise
        table drawn once (unit triangular values, stored with an offset as uint8) at a per-frame random offset.

        The ray caster's model has read noise 1.5 DN and shot noise 0.06 DN per DN of signal per pixel,
        variance 2.25 + 0.06 v; here one level per frame, the root mean square of that model over the frame
        (the variance is linear in v, so its mean is the variance at the frame's mean gained signal ``mean`` x
        gain x 255): the frame's noise power is the per-pixel model's, dark pixels get a little more and bright
        ones a little less (1.5-4.2 DN per pixel there, typically 2.9 DN here). One pass instead of six (table
        lookup, two multiplies, add, subtract, gain): about 1 ms instead of 6 per 1280 px frame."""
        flat = img.reshape(img.shape[0], -1)
        if not self.noise:
            return cv2.convertScaleAbs(flat, alpha=gain).reshape(img.shape)
        signal = min(mean * gain * 255.0, 255.0)
        k = math.sqrt(1.5**2 + 0.06 * signal) / self._tri_std
        n = self._noise_window(flat.size, index).reshape(flat.shape)
        return cv2.addWeighted(flat, gain, n, k, -_NOISE_ZERO * k).reshape(img.shape)

    def _noise_window(self, n: int, index: int) -> np.ndarray:
        """Frame ``index``'s window of n unit triangular noise values (std ``_tri_std``) plus ``_NOISE_ZERO``
        (uint8 0..30)."""
        if self._noise is None or len(self._noise) < 2 * n:
            rng = np.random.default_rng([self.seed, 17])
            b = np.frombuffer(rng.bytes(2 * n), dtype=np.uint8)
            self._noise = cv2.LUT(b, self._tri).ravel()
        offset = int(np.random.default_rng([self.seed, index, 17]).integers(len(self._noise) - n + 1))
        return self._noise[offset:offset + n]


def make_renderer(kind: str, scene: Scene, frame: FacadeFrame, camera: CameraModel, **kw) -> Renderer:
    """The renderer by name: 'warp' (real time, the default of the live camera and recordings) or 'raycast'
    (the per-pixel reference)."""
    if kind == "warp":
        return WarpRenderer(scene, frame, camera, **kw)
    if kind == "raycast":
        return Renderer(scene, frame, camera, **kw)
    raise CompanionError(f"unknown renderer {kind!r}", f"use one of {', '.join(RENDERERS)}")

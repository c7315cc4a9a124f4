"""Vectorised ray casting of the facade scene: image, z-depth, ROI mask and surface ids for one true pose.

Every pixel's ray is intersected analytically with the target building (box), the ground plane, the far
buildings and tree trunks (boxes, tested only inside their projected image rectangles), tree crowns (ellipsoids)
and the sky at infinity. Then camera effects that matter to the pipeline: auto exposure, motion blur from the
true velocity over the exposure time, sensor noise (JPEG is applied by whoever stores or streams the frame).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from companion.errors import CompanionError
from companion.geo import FacadeFrame
from sim.camera.model import CameraModel, TruePose
from sim.camera.noise import fbm, value_noise
from sim.camera.scene import Scene
from sim.camera.textures import FacadeTexture

SKY, TARGET, SIDE, ROOF, GROUND, FAR, TREE, TRUNK = range(8)
SURFACE_NAMES = ("sky", "target_wall", "side_wall", "roof", "ground", "far_building", "tree", "trunk")
_EPS = 1e-3


@dataclass
class RenderedFrame:
    image: np.ndarray  # BGR uint8, before any JPEG compression
    depth: np.ndarray  # float32 z-depth in metres, inf for sky
    roi_mask: np.ndarray  # uint8, 255 where the pixel sees the target facade
    surface: np.ndarray  # uint8 surface id per pixel (SURFACE_NAMES)
    pose: TruePose
    K: np.ndarray
    gain: float  # exposure gain used


class AutoExposure:
    """A camera's auto exposure: gain follows the scene brightness with a lag, so frames with a lot of bright
    sky near the building's edge come out darker on the facade, as real footage does."""

    def __init__(self, target: float = 0.42, time_constant_s: float = 0.4, seed: int = 0):
        self.target = target
        self.tau = time_constant_s
        self.gain: float | None = None
        self.t: float | None = None
        self.seed = seed

    def update(self, mean_radiance: float, t_s: float) -> float:
        want = float(np.clip(self.target / max(mean_radiance, 1e-3), 0.6, 1.7))
        if self.gain is None or self.t is None:
            self.gain = want
        else:
            k = 1.0 - math.exp(-max(t_s - self.t, 0.0) / self.tau)
            self.gain += k * (want - self.gain)
        self.t = t_s
        flicker = 1.0 + 0.02 * (float(value_noise(np.array([t_s]), np.array([0.0]), 0.7, self.seed)[0]) * 2 - 1)
        return self.gain * flicker


class Renderer:
    """Renders a :class:`Scene` seen through a :class:`CameraModel` placed at true poses."""

    def __init__(self, scene: Scene, frame: FacadeFrame, camera: CameraModel, *, exposure_s: float = 1 / 240,
                 noise: bool = True, blur: bool = True, seed: int = 0):
        if exposure_s < 0:
            raise CompanionError(f"exposure_s={exposure_s} is negative", "give the exposure time in seconds")
        self.scene = scene
        self.frame = frame
        self.camera = camera
        self.K = camera.K
        self.exposure_s = exposure_s
        self.noise = noise
        self.blur = blur
        self.seed = seed
        de, dn = frame.along_enu
        oe, on = frame.out_enu
        self.M = np.array([[de, dn, 0.0], [oe, on, 0.0], [0.0, 0.0, 1.0]])  # facade <- ENU
        w, h = camera.width, camera.height
        u, v = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
        # float32 rays: twice the speed of float64, and 1e-7 relative precision is micrometres at 30 m
        self._rx = ((u - self.K[0, 2]) / self.K[0, 0]).astype(np.float32)
        self._ry = ((v - self.K[1, 2]) / self.K[1, 1]).astype(np.float32)
        self._dnorm = np.sqrt(self._rx**2 + self._ry**2 + 1.0)
        self._pano: np.ndarray | None = None
        # background objects: far buildings and trunks (boxes), then tree crowns (their bounding boxes)
        los = [b.lo for b in scene.boxes]
        his = [b.hi for b in scene.boxes]
        for tr in scene.trees:
            rad = np.array([tr.radius, tr.radius, tr.radius * tr.squash])
            los.append(tuple(np.array(tr.centre) - rad))
            his.append(tuple(np.array(tr.centre) + rad))
        self._n_boxes = len(scene.boxes)
        self._obj_lo = np.array(los, float).reshape(-1, 3)
        self._obj_hi = np.array(his, float).reshape(-1, 3)
        self._obj_corners = np.array([_box_corners(a, b) for a, b in zip(los, his, strict=True)]).reshape(-1, 8, 3)

    # ---- geometry ----------------------------------------------------------------------------------------
    def cast(self, pose: TruePose):
        """Ray cast: t z-depth (H,W), surface id (H,W), hit points in facade coords (H,W,3), ray directions
        (H,W,3, camera z = 1) and the index of the box or tree hit (H,W; -1 for none)."""
        sc = self.scene
        A = self.M @ pose.R_world_from_cam  # facade <- camera
        # float32 origin: a float64 scalar would silently promote every float32 ray array to float64
        orig = (self.M @ pose.position_enu).astype(np.float32)
        rx, ry = self._rx, self._ry
        A32 = A.astype(np.float32)
        Dc = tuple(A32[k, 0] * rx + A32[k, 1] * ry + A32[k, 2] for k in range(3))
        H, W = rx.shape
        t = np.full((H, W), np.inf, np.float32)
        sid = np.zeros((H, W), np.uint8)
        # target building
        tb, face = _box_hit(orig, Dc, (0.0, -sc.depth_m, 0.0), (sc.length_m, 0.0, sc.height_m))
        hit = np.isfinite(tb)
        t[hit] = tb[hit]
        front = (face == 1) & (Dc[1] < 0)
        fid = np.where(front, TARGET, np.where(face == 2, ROOF, SIDE))
        sid[hit] = fid[hit]
        # ground
        with np.errstate(divide="ignore", invalid="ignore"):
            tg = -orig[2] / Dc[2]
        g = (Dc[2] < 0) & (tg > _EPS) & (tg < t) & (orig[2] > 0)
        t[g] = tg[g]
        sid[g] = GROUND
        # far buildings, trunks and crowns: only inside their projected rectangles, and only where nothing
        # nearer than the object's closest point was hit already
        rng_t = t * self._dnorm
        obj = np.full((H, W), -1, np.int16)
        rects, dist = self._object_rects(orig, A)
        for j, (sl, near) in enumerate(zip(rects, dist, strict=True)):
            if sl is None:
                continue
            cand = rng_t[sl] > near
            if not cand.any():
                continue
            dsel = tuple(x[sl][cand] for x in Dc)
            if j < self._n_boxes:
                b = sc.boxes[j]
                th, _ = _box_hit(orig, dsel, b.lo, b.hi)
                surf, idx = (FAR if b.kind == "building" else TRUNK), j
            else:
                idx = j - self._n_boxes
                tr = sc.trees[idx]
                rad = np.array([tr.radius, tr.radius, tr.radius * tr.squash])
                th = _ellipsoid_hit(orig, dsel, np.array(tr.centre), rad)
                surf = TREE
            sub_t, sub_s, sub_o, sub_r = t[sl], sid[sl], obj[sl], rng_t[sl]
            ct = sub_t[cand]
            m = th < ct
            if not m.any():
                continue
            ct[m] = th[m]
            sub_t[cand] = ct
            cs = sub_s[cand]
            cs[m] = surf
            sub_s[cand] = cs
            co = sub_o[cand]
            co[m] = idx
            sub_o[cand] = co
            sub_r[cand] = ct * self._dnorm[sl][cand]
        tf = np.where(np.isfinite(t), t, 0.0)
        P = tuple(orig[k] + Dc[k] * tf for k in range(3))
        return t, sid, P, Dc, obj

    def _object_rects(self, orig, A):
        """Image rectangles of all background objects (boxes, then tree crowns) and their nearest distances,
        projected in one go; objects straddling the camera's near plane fall back to exact clipping."""
        corners = self._obj_corners  # (N, 8, 3)
        lo, hi = self._obj_lo, self._obj_hi
        dist = np.linalg.norm(np.maximum(np.maximum(lo - orig, 0.0), orig - hi), axis=1)
        cam = (corners - orig) @ A
        z = cam[..., 2]
        H, W = self.camera.height, self.camera.width
        front = z > 0.05
        all_front = front.all(axis=1)
        with np.errstate(divide="ignore", invalid="ignore"):
            u = cam[..., 0] / z * self.K[0, 0] + self.K[0, 2]
            v = cam[..., 1] / z * self.K[1, 1] + self.K[1, 2]
        u0 = np.floor(u.min(axis=1)) - 1
        u1 = np.ceil(u.max(axis=1)) + 1
        v0 = np.floor(v.min(axis=1)) - 1
        v1 = np.ceil(v.max(axis=1)) + 1
        rects: list = []
        for j in range(len(corners)):
            if not front[j].any():
                rects.append(None)
            elif not all_front[j]:
                rects.append(self._rect(orig, A, corners[j]))
            else:
                a0, a1 = max(int(u0[j]), 0), min(int(u1[j]), W)
                b0, b1 = max(int(v0[j]), 0), min(int(v1[j]), H)
                rects.append((slice(b0, b1), slice(a0, a1)) if a0 < a1 and b0 < b1 else None)
        return rects, dist

    def _rect(self, orig, A, corners):
        """Image rectangle (slices) covering the box with these 8 corners (facade coords), or None if unseen.
        Edges crossing the near plane are clipped there, so boxes beside the camera get a tight rectangle."""
        cam = (corners - orig) @ A  # A is orthogonal: its inverse is its transpose
        z = cam[:, 2]
        H, W = self.camera.height, self.camera.width
        near = 0.05
        front = z > near
        if not front.any():
            return None
        pts = [cam[front]]
        if not front.all():
            for i, j in _BOX_EDGES:
                if front[i] != front[j]:
                    s = (near - z[i]) / (z[j] - z[i])
                    pts.append((cam[i] + s * (cam[j] - cam[i]))[None])
        p = np.concatenate(pts)
        u = p[:, 0] / p[:, 2] * self.K[0, 0] + self.K[0, 2]
        v = p[:, 1] / p[:, 2] * self.K[1, 1] + self.K[1, 2]
        u0, u1 = max(int(math.floor(u.min())) - 1, 0), min(int(math.ceil(u.max())) + 1, W)
        v0, v1 = max(int(math.floor(v.min())) - 1, 0), min(int(math.ceil(v.max())) + 1, H)
        if u0 >= u1 or v0 >= v1:
            return None
        return (slice(v0, v1), slice(u0, u1))

    # ---- shading -----------------------------------------------------------------------------------------
    def radiance(self, pose: TruePose):
        """Scene colour (BGR float32 0..1, before exposure), z-depth and surface ids."""
        sc = self.scene
        t, sid, P, D, obj = self.cast(pose)
        H, W = t.shape
        img = np.zeros((H, W, 3), np.float32)
        dnorm = self._dnorm
        sun = sc.sun_dir

        def lambert(n):
            return np.float32(sc.light * (0.55 + 0.5 * max(0.0, float(np.dot(n, sun)))))

        m = sid == TARGET
        if m.any():
            gsd = self._gsd(m, t, D[1], 0.15)
            if m.mean() > 0.3:  # mostly wall: sample the full grid and copy, cheaper than gather + scatter
                col = self._plane(sc.texture, P[0], P[2], gsd, sc.length_m, m)
                np.copyto(img, col * lambert((0, 1, 0)), where=m[..., None])
            else:
                img[m] = self._plane(sc.texture, P[0][m], P[2][m], gsd, sc.length_m) * lambert((0, 1, 0))
        m = sid == SIDE
        if m.any():
            right_side = P[0][m] > sc.length_m / 2
            s = np.where(right_side, -P[1][m], P[1][m] + sc.depth_m)
            gsd = self._gsd(m, t, D[0], 0.15)
            col = self._plane(sc.side_texture, s, P[2][m], gsd, sc.depth_m)
            shade = np.where(right_side, lambert((1, 0, 0)), lambert((-1, 0, 0))).astype(np.float32)
            img[m] = col * shade[:, None]
        m = sid == ROOF
        if m.any():
            pa, po = P[0][m], P[1][m]
            n = fbm(pa, po, 0.5, sc.seed + 61, octaves=3)
            img[m] = (np.float32(0.45) + 0.06 * n)[:, None] * np.array([1.0, 1.0, 1.02], np.float32) * lambert(
                (0, 0, 1))
        m = sid == GROUND
        if m.any():
            pa, po = P[0][m], P[1][m]
            gsd = self._gsd(m, t, D[2], 0.05)
            paved = (po > -sc.depth_m - 4) & (po < 8) & (pa > -6) & (pa < sc.length_m + 6)
            n1 = fbm(pa, po, 3.0, sc.seed + 71, octaves=5, min_cell=gsd * 2)
            grass = np.array([0.16, 0.36, 0.26], np.float32) * (1 + 0.35 * n1)[:, None]
            slab = np.array([0.55, 0.56, 0.57], np.float32) * (1 + 0.12 * n1)[:, None]
            fa, fo = np.mod(pa, 0.6), np.mod(po, 0.6)
            joint = (np.minimum(np.minimum(fa, 0.6 - fa), np.minimum(fo, 0.6 - fo)) < max(0.004, gsd / 2))
            slab[joint] *= np.float32(0.75 if gsd < 0.05 else 0.95)
            col = np.where(paved[:, None], slab, grass)
            img[m] = col * lambert((0, 0, 1)) * self._haze_keep(t[m] * dnorm[m])[:, None] + self._haze(t[m] * dnorm[m])
        m = sid == FAR
        if m.any():
            img[m] = self._far_building(_rows(P, m), obj[m], t[m] * dnorm[m], lambert)
        m = sid == TRUNK
        if m.any():
            img[m] = np.array([0.1, 0.15, 0.2], np.float32) * lambert((0, 1, 0))
        m = sid == TREE
        if m.any():
            img[m] = self._tree(_rows(P, m), obj[m], t[m] * dnorm[m])
        m = sid == SKY
        if m.any():
            img[m] = self._sky(_rows(D, m) / dnorm[m][:, None])
        depth = t.astype(np.float32)
        return img, depth, sid

    def _gsd(self, m, t, d_normal, min_cos) -> float:
        """Median size (m) of a pixel's footprint on a plane, from a 1-in-16 subsample of the mask."""
        sub = m[::4, ::4]
        if not sub.any():
            sub, sl = m, (slice(None), slice(None))
        else:
            sl = (slice(None, None, 4), slice(None, None, 4))
        dn = self._dnorm[sl][sub]
        cos = np.maximum(np.abs(d_normal[sl][sub]) / dn, min_cos)
        return float(np.median(t[sl][sub] * dn / self.K[0, 0] / cos))

    def _plane(self, tex: FacadeTexture, s, u, gsd: float, extent, mask=None):
        """Sample a tiled texture at plane coordinates via one patch + bilinear remap. ``s``, ``u`` are the
        selected pixels' coordinates (1-D), or full (H, W) grids with ``mask`` marking the pixels on the plane."""
        texel_mm = gsd * 1000.0 * 1.5
        level = int(np.clip(math.floor(math.log2(max(texel_mm, 1.0))), 0, 10))
        if mask is None:
            s0, s1, u0, u1 = float(s.min()), float(s.max()), float(u.min()), float(u.max())
        else:
            s0, s1 = float(np.min(s, where=mask, initial=np.inf)), float(np.max(s, where=mask, initial=-np.inf))
            u0, u1 = float(np.min(u, where=mask, initial=np.inf)), float(np.max(u, where=mask, initial=-np.inf))
        s0, s1 = max(s0, 0.0), min(s1, extent)
        u0, u1 = max(u0, 0.0), min(u1, tex.style.height_m)
        while ((s1 - s0) * 1000 / 2**level) * ((u1 - u0) * 1000 / 2**level) > 12e6 and level < 10:
            level += 1
        patch, so, uo, px = tex.patch(s0, u0, max(s1, s0 + 1e-3), max(u1, u0 + 1e-3), level)
        if mask is not None and s.shape[1] < 32000:
            mx = ((s - so) / px - 0.5).astype(np.float32)
            my = ((u - uo) / px - 0.5).astype(np.float32)
            out = cv2.remap(patch, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
            return out.astype(np.float32) * np.float32(1 / 255)
        if mask is not None:
            s, u = s[mask], u[mask]
        n = len(s)
        cols = 1024
        rows = -(-n // cols)
        mx = np.zeros(rows * cols, np.float32)
        my = np.zeros(rows * cols, np.float32)
        mx[:n] = (s - so) / px - 0.5
        my[:n] = (u - uo) / px - 0.5
        out = cv2.remap(patch, mx.reshape(rows, cols), my.reshape(rows, cols), cv2.INTER_LINEAR,
                        borderMode=cv2.BORDER_REPLICATE)
        return out.reshape(-1, 3)[:n].astype(np.float32) * np.float32(1 / 255)

    def _haze(self, r):
        f = (1.0 - np.exp(-r / 900.0)).astype(np.float32)
        return f[:, None] * np.array(self.scene.sky_horizon, np.float32)

    def _haze_keep(self, r):
        return np.exp(-r / 900.0).astype(np.float32)

    def _far_building(self, P, bi, r, lambert):
        sc = self.scene
        out = np.zeros((len(P), 3), np.float32)
        lo = np.array([b.lo for b in sc.boxes])
        hi = np.array([b.hi for b in sc.boxes])
        blo, bhi = lo[bi], hi[bi]
        col = np.array([b.bgr for b in sc.boxes], np.float32)[bi]
        dlo, dhi = np.abs(P - blo), np.abs(P - bhi)
        axis_lo, axis_hi = np.argmin(dlo, axis=1), np.argmin(dhi, axis=1)
        use_hi = dhi.min(axis=1) < dlo.min(axis=1)
        axis = np.where(use_hi, axis_hi, axis_lo)
        sign = np.where(use_hi, 1.0, -1.0)
        shade = np.ones(len(P), np.float32)
        for ax in range(3):
            for sg in (-1.0, 1.0):
                n = np.zeros(3)
                n[ax] = sg
                sel = (axis == ax) & (sign == sg)
                shade[sel] = lambert(n)
        horiz = np.where(axis == 0, P[:, 1], P[:, 0])
        fu = np.mod(P[:, 2], 3.2) / 3.2
        fh = np.mod(horiz, 2.8) / 2.8
        win = (axis != 2) & (fu > 0.35) & (fu < 0.75) & (fh > 0.2) & (fh < 0.75) & (P[:, 2] > 1.0)
        col = col * shade[:, None]
        col[win] = col[win] * 0.45 + np.array([0.35, 0.3, 0.25], np.float32) * 0.4
        out[:] = col * self._haze_keep(r)[:, None] + self._haze(r)
        return out

    def _tree(self, P, ti, r):
        sc = self.scene
        out = np.zeros((len(P), 3), np.float32)
        cs = np.array([t.centre for t in sc.trees])
        c = cs[ti]
        rad = np.array([[t.radius, t.radius, t.radius * t.squash] for t in sc.trees])[ti]
        n = (P - c) / rad**2
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        lam = sc.light * (0.35 + 0.65 * np.clip(n @ sc.sun_dir, 0, 1))
        leaf = 0.55 + 0.45 * value_noise(P[:, 0] + 0.7 * P[:, 1], P[:, 2] - 0.3 * P[:, 1], 0.22, sc.seed + 81)
        leaf *= 0.8 + 0.2 * value_noise(P[:, 0] - P[:, 1], P[:, 2], 0.9, sc.seed + 83)
        green = np.array([t.bgr for t in sc.trees], np.float32)[ti]
        out[:] = green * (lam * leaf)[:, None].astype(np.float32)
        return out * self._haze_keep(r)[:, None] + self._haze(r)

    def _sky_colour(self, d):
        """Sky radiance for unit directions d (N, 3) in facade axes: gradient plus clouds on a layer 1 km up."""
        sc = self.scene
        el = np.clip(d[:, 2], 0.0, 1.0)
        zen = np.array(sc.sky_zenith, np.float32)
        hor = np.array(sc.sky_horizon, np.float32)
        col = hor + (zen - hor) * np.sqrt(el).astype(np.float32)[:, None]
        up = np.maximum(d[:, 2], 0.02)
        x, y = d[:, 0] / up * 1000.0, d[:, 1] / up * 1000.0
        c = fbm(x, y, 900.0, sc.seed + 91, octaves=5)
        cover = np.clip((c + 0.55 - (1 - sc.cloud_cover)) * 2.5, 0, 1) * np.clip(el * 8, 0, 1)
        cloud = np.float32(0.97) - 0.12 * np.clip(c, 0, 1)[:, None]
        return col * (1 - cover)[:, None] + cloud * cover[:, None]

    def _sky_panorama(self):
        """The sky is a function of direction only, so it is rendered once into an azimuth x elevation image
        at about the camera's angular resolution and then looked up per pixel."""
        if self._pano is None:
            deg_px = 2.0 * math.degrees(1.0 / self.K[0, 0])  # clouds are soft: half the camera's resolution
            w = int(np.clip(360.0 / deg_px, 1024, 4096))
            h = w // 4 + 2  # elevation -1 .. 90 degrees
            az = (np.arange(w) + 0.5) / w * 2 * math.pi
            el = np.radians(-1.0 + (np.arange(h) + 0.5) / h * 91.0)
            AZ, EL = np.meshgrid(az, el)
            d = np.stack([np.cos(EL) * np.sin(AZ), np.cos(EL) * np.cos(AZ), np.sin(EL)], -1).reshape(-1, 3)
            pano = self._sky_colour(d).reshape(h, w, 3).astype(np.float32)
            self._pano = np.concatenate([pano, pano[:, :1]], axis=1)  # wrap column for interpolation
        return self._pano

    def _sky(self, d):
        pano = self._sky_panorama()
        h, w = pano.shape[0], pano.shape[1] - 1
        az = np.mod(np.arctan2(d[:, 0], d[:, 1]), 2 * math.pi)
        el = np.degrees(np.arcsin(np.clip(d[:, 2], -1, 1)))
        mx = (az / (2 * math.pi) * w - 0.5).astype(np.float32)
        my = ((el + 1.0) / 91.0 * h - 0.5).astype(np.float32)
        n = len(d)
        cols = 1024
        rows = -(-n // cols)
        bx = np.zeros(rows * cols, np.float32)
        by = np.zeros(rows * cols, np.float32)
        bx[:n], by[:n] = mx, my
        out = cv2.remap(pano, bx.reshape(rows, cols), by.reshape(rows, cols), cv2.INTER_LINEAR,
                        borderMode=cv2.BORDER_REPLICATE)
        return out.reshape(-1, 3)[:n]

    # ---- camera effects ----------------------------------------------------------------------------------
    def render(self, pose: TruePose, *, index: int = 0, time_s: float = 0.0,
               exposure: AutoExposure | None = None) -> RenderedFrame:
        img, depth, sid = self.radiance(pose)
        if exposure is not None:
            gain = exposure.update(float(img.mean()), time_s)
        else:
            gain = float(np.clip(0.42 / max(float(img.mean()), 1e-3), 0.6, 1.7))
        img *= np.float32(gain)
        if self.blur and self.exposure_s > 0:
            img = self._motion_blur(img, depth, pose)
        if self.noise:
            rng = np.random.default_rng([self.seed, index, 17])
            # read noise 1.5 DN plus shot noise (variance 0.06 DN per DN of signal), in 0..1 units
            sigma = np.sqrt(np.float32(1.5**2) + np.float32(0.06 * 255) * np.clip(img, 0, 1)) / np.float32(255)
            # unit-variance triangular noise from random bytes: 5x faster than Gaussian draws, same spectrum
            b = np.frombuffer(rng.bytes(2 * img.size), dtype=np.uint8).reshape((2,) + img.shape)
            img += (b[0].astype(np.float32) + b[1] - np.float32(255)) * np.float32(1 / 104.5) * sigma
        image = cv2.convertScaleAbs(img, alpha=255.0)  # rounds and saturates to uint8
        roi = np.where(sid == TARGET, 255, 0).astype(np.uint8)
        return RenderedFrame(image, depth, roi, sid, pose, self.K.copy(), gain)

    def blur_vectors(self, depth: np.ndarray, pose: TruePose) -> tuple[np.ndarray, np.ndarray]:
        """Image motion (pixels) during the exposure at the centre: (near layer, far layer)."""
        return self.blur_vectors_sampled(depth[::4, ::4], pose)

    def blur_vectors_sampled(self, sub: np.ndarray, pose: TruePose) -> tuple[np.ndarray, np.ndarray]:
        """``blur_vectors`` from its 1-in-16 sample of the z-depth, ``depth[::4, ::4]`` (a renderer that keeps
        inverse depth converts only these)."""
        v = pose.R_world_from_cam.T @ np.asarray(pose.velocity_enu_m_s, dtype=float)
        w = np.asarray(pose.angular_rate_cam_rad_s, dtype=float)
        f = self.K[0, 0]
        finite = sub[np.isfinite(sub) & (sub < 50)]
        z = float(np.median(finite)) if finite.size else math.inf
        rot = np.array([-w[1], w[0]]) * f * self.exposure_s
        trans = np.array([-v[0], -v[1]]) * f * self.exposure_s / z if math.isfinite(z) else np.zeros(2)
        return rot + trans, rot

    def _motion_blur(self, img, depth, pose):
        near, far = self.blur_vectors(depth, pose)
        out = _line_blur(img, near)
        if np.linalg.norm(near - far) > 0.5 and np.isfinite(depth).any():
            far_img = _line_blur(img, far)
            farm = ~(depth < 50)
            out[farm] = far_img[farm]
        return out


def _line_blur(img, vec):
    n = float(np.hypot(*vec))
    if n < 0.5:
        return img
    size = int(math.ceil(n)) * 2 + 1
    k = np.zeros((size, size), np.float32)
    c = size // 2
    steps = max(int(math.ceil(n * 2)), 2)
    for s in np.linspace(-0.5, 0.5, steps):
        x, y = c + s * vec[0], c + s * vec[1]
        k[int(round(y)), int(round(x))] += 1
    k /= k.sum()
    return cv2.filter2D(img, -1, k, borderType=cv2.BORDER_REPLICATE)


def _rows(comps, m) -> np.ndarray:
    """(N, 3) array of the masked entries of three component arrays."""
    return np.stack([c[m] for c in comps], axis=-1)


# corner indices of _box_corners joined by the 12 box edges (corner index = 4 x_hi + 2 y_hi + z_hi)
_BOX_EDGES = [(i, i | b) for i in range(8) for b in (1, 2, 4) if not i & b]


def _box_corners(lo, hi) -> np.ndarray:
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    return np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])


def _box_hit(orig, D, lo, hi):
    """First hit of rays D = (d_along, d_out, d_up) from outside a box: entry distance (inf where missed) and
    entry axis (0 along, 1 out, 2 up). Only the (at most three) faces turned towards the camera can be entered
    first, so each is a single plane intersection plus a bounds check on the other two coordinates."""
    shape = D[0].shape
    t = np.full(shape, np.inf, np.float32)
    axis = np.zeros(shape, np.uint8)
    for k in range(3):
        if lo[k] < orig[k] < hi[k]:
            continue
        plane = lo[k] if orig[k] <= lo[k] else hi[k]
        d = D[k]
        with np.errstate(divide="ignore", invalid="ignore"):
            tk = (plane - orig[k]) / d
        ok = tk > _EPS
        for j in range(3):
            if j != k:
                c = orig[j] + D[j] * tk
                ok &= (c >= lo[j]) & (c <= hi[j])
        # a ray enters a convex box through exactly one face: no need to compare with the other faces
        t[ok] = tk[ok]
        axis[ok] = k
    return t, axis


def _ellipsoid_hit(orig, D, c, rad):
    o = [float((orig[k] - c[k]) / rad[k]) for k in range(3)]  # Python floats keep the float32 arrays float32
    d = [D[k] * np.float32(1.0 / rad[k]) for k in range(3)]
    a = d[0] * d[0] + d[1] * d[1] + d[2] * d[2]
    b = 2 * (d[0] * o[0] + d[1] * o[1] + d[2] * o[2])
    cc = float(o[0] ** 2 + o[1] ** 2 + o[2] ** 2) - 1.0
    disc = b * b - 4 * a * cc
    with np.errstate(invalid="ignore"):
        t = (-b - np.sqrt(disc)) / (2 * a)
    return np.where((disc >= 0) & (t > _EPS), t, np.inf)

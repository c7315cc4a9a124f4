"""Real photographs as the simulator's textures: a facade photo on the wall plane, an outdoor photo far behind.

The procedural scene (``scene.py``) only ever shows walls and backgrounds we drew ourselves, so a model that
fits it can still fail on real facades. Here the wall is a real facade photo mapped onto the plane out = 0 and
the background a real outdoor photo on a plane ``background_distance_m`` behind it; a camera at the standoff,
facing the wall, flies along it and off its end. Both surfaces are planes facing the camera, so every frame is
two exact affine warps (OpenCV) and its truth is exact: the ROI mask, the z-depth of every pixel, and the texture
coordinates of the wall (``PhotoFrame.wall_from_image``), from which the true overlap of any two frames follows.

Where the photo's labels say a pixel is not facade (CMP's class 1: sky, neighbours, rectification padding), the
wall has a hole there and the background shows through, so a photo's own sky is never counted as wall.
Which photos make a pass is decided by the caller (``bench/depth_real_passes.py`` names held-out photos only).
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass

import cv2
import numpy as np

from companion.errors import CompanionError
from sim.camera.model import CameraModel


@dataclass(frozen=True)
class PhotoTexture:
    """A photo mapped onto a plane ``width_m`` wide; ``alpha`` (uint8, 255 = part of the surface) or None."""

    name: str
    image: np.ndarray  # BGR uint8
    width_m: float
    alpha: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.image is None or self.image.ndim != 3 or self.image.dtype != np.uint8:
            raise CompanionError(f"texture {self.name} is not a BGR uint8 image", "load it with cv2.imread")
        if self.alpha is not None and self.alpha.shape != self.image.shape[:2]:
            raise CompanionError(f"texture {self.name}: alpha {self.alpha.shape} does not match the image "
                                 f"{self.image.shape[:2]}", "pass the photo's label mask at the photo's size")
        if not self.width_m > 0:
            raise CompanionError(f"texture {self.name}: width {self.width_m} m", "give a positive width in metres")

    @property
    def height_m(self) -> float:
        return self.width_m * self.image.shape[0] / self.image.shape[1]


@dataclass(frozen=True)
class PhotoPass:
    """One evaluation pass: a photo wall, a photo background behind it, and the flight along the wall.

    Each strip is a horizontal line at ``up_m`` flown left to right at the standoff; the camera starts with the
    left image edge on the wall's left end and ends after ``background_frames / len(strips)`` frames that see no
    wall at all (past the wall's right end).
    """

    name: str
    wall: PhotoTexture
    background: PhotoTexture  # its width is ignored: it is scaled to cover every view of the pass
    background_distance_m: float = 120.0
    standoff_m: float = 4.0
    strips_up_m: tuple[float, ...] | None = None  # None: one strip at the wall's mid-height
    frames: int = 250
    background_frames: int = 22
    camera: CameraModel = CameraModel(width=1920, height=1080, hfov_deg=69.0)
    jpeg_quality: int = 90

    def __post_init__(self) -> None:
        if not self.standoff_m > 0:
            raise CompanionError(f"pass {self.name}: standoff {self.standoff_m} m", "use a positive standoff")
        if self.background_distance_m <= 0:
            raise CompanionError(f"pass {self.name}: background at {self.background_distance_m} m",
                                 "put the background behind the wall (a positive distance, e.g. 120 m)")
        if not 0 <= self.background_frames < self.frames:
            raise CompanionError(f"pass {self.name}: {self.background_frames} background frames of {self.frames}",
                                 "keep background_frames below frames")


@dataclass(frozen=True)
class PhotoFrame:
    """One rendered frame and its exact truth."""

    index: int
    image: np.ndarray  # BGR uint8, JPEG-compressed as a camera stores it
    roi_mask: np.ndarray  # uint8, 255 where the pixel sees the wall
    depth: np.ndarray  # float32 z-depth in metres
    along_m: float  # camera position along the wall
    up_m: float  # camera height
    wall_from_image: np.ndarray  # 3x3: image pixel (x, y, 1) -> wall metres (along, up, 1)

    @property
    def wall_fraction(self) -> float:
        return float(np.count_nonzero(self.roi_mask)) / self.roi_mask.size


def _image_from_plane(cam: CameraModel, z_m: float, along_m: float, up_m: float) -> np.ndarray:
    """2x3 affine: plane metres (along, up) -> image pixel (x, y) for a frontal plane at z-depth ``z_m``."""
    K = cam.K
    fx, fy = K[0, 0] / z_m, K[1, 1] / z_m
    # pixel centres at +0.5 (as in render.py): continuous x = fx (a - a_c) + cx; index = continuous - 0.5
    return np.array([[fx, 0.0, -fx * along_m + K[0, 2] - 0.5],
                     [0.0, -fy, fy * up_m + K[1, 2] - 0.5]])


def _plane_from_texture(tex_w_px: int, tex_h_px: int, width_m: float, height_m: float,
                        origin: tuple[float, float]) -> np.ndarray:
    """3x3: texture pixel index (i, j) -> plane metres (along, up); row 0 is the top of the photo."""
    sa, su = width_m / tex_w_px, height_m / tex_h_px
    a0, u0 = origin
    return np.array([[sa, 0.0, a0 + 0.5 * sa], [0.0, -su, u0 + height_m - 0.5 * su], [0.0, 0.0, 1.0]])


class PhotoPassRenderer:
    """Renders a :class:`PhotoPass` frame by frame (deterministic: the same pass gives the same frames)."""

    def __init__(self, spec: PhotoPass):
        self.spec = spec
        cam = spec.camera
        s = spec.standoff_m
        self.half_view_m = s * math.tan(math.radians(cam.hfov_deg) / 2)  # half footprint width on the wall
        self.positions = self._positions()
        # wall texture prefiltered to about one texel per image pixel (warpAffine's bilinear lookup would alias)
        self._wall_img, self._wall_alpha = self._prefilter(spec.wall.image, spec.wall.alpha, spec.wall.width_m, s)
        self._wall_tex_to_plane = _plane_from_texture(self._wall_img.shape[1], self._wall_img.shape[0],
                                                      spec.wall.width_m, spec.wall.height_m, (0.0, 0.0))
        # background plane: large enough to fill every view of the pass, photo scaled uniformly to cover it
        zb = s + spec.background_distance_m
        half_w = zb * math.tan(math.radians(cam.hfov_deg) / 2) * 1.02
        half_h = zb * math.tan(math.radians(cam.vfov_deg) / 2) * 1.02
        alongs = [p[0] for p in self.positions]
        ups = [p[1] for p in self.positions]
        need_w = max(alongs) - min(alongs) + 2 * half_w
        need_h = max(ups) - min(ups) + 2 * half_h
        bh, bw = spec.background.image.shape[:2]
        scale = max(need_w / bw, need_h / bh)  # metres per photo pixel
        bg_w, bg_h = bw * scale, bh * scale
        centre_a, centre_u = (max(alongs) + min(alongs)) / 2, (max(ups) + min(ups)) / 2
        self._bg_img, _ = self._prefilter(spec.background.image, None, bg_w, zb)
        self._bg_tex_to_plane = _plane_from_texture(self._bg_img.shape[1], self._bg_img.shape[0], bg_w, bg_h,
                                                    (centre_a - bg_w / 2, centre_u - bg_h / 2))

    def _positions(self) -> list[tuple[float, float]]:
        sp = self.spec
        strips = sp.strips_up_m or (sp.wall.height_m / 2,)
        per = [sp.frames // len(strips) + (1 if k < sp.frames % len(strips) else 0) for k in range(len(strips))]
        out: list[tuple[float, float]] = []
        for k, (up, n) in enumerate(zip(strips, per, strict=True)):
            n_bg = sp.background_frames // len(strips) + (1 if k < sp.background_frames % len(strips) else 0)
            start = self.half_view_m  # left image edge on the wall's left end
            first_bg = sp.wall.width_m + self.half_view_m + 0.05  # first position that sees no wall
            n_wall = max(n - n_bg, 1)
            step = (first_bg - start) / n_wall
            out += [(start + i * step if i < n_wall else first_bg + (i - n_wall) * step, float(up)) for i in range(n)]
        return out

    def _prefilter(self, image, alpha, width_m: float, z_m: float):
        """Shrink a texture whose texels are smaller than the image pixels it lands on (INTER_AREA)."""
        px_per_texel = self.spec.camera.K[0, 0] / z_m * width_m / image.shape[1]
        if px_per_texel >= 1.0:
            return image, alpha
        size = (max(2, round(image.shape[1] * px_per_texel)), max(2, round(image.shape[0] * px_per_texel)))
        small = cv2.resize(image, size, interpolation=cv2.INTER_AREA)
        a = None if alpha is None else cv2.resize(alpha, size, interpolation=cv2.INTER_AREA)
        return small, a

    def __len__(self) -> int:
        return len(self.positions)

    def render(self, index: int) -> PhotoFrame:
        sp, cam = self.spec, self.spec.camera
        along, up = self.positions[index]
        size = (cam.width, cam.height)
        wall_aff = _image_from_plane(cam, sp.standoff_m, along, up) @ self._wall_tex_to_plane
        wall = cv2.warpAffine(self._wall_img, wall_aff, size, flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        alpha = self._wall_alpha if self._wall_alpha is not None else np.full(self._wall_img.shape[:2], 255, np.uint8)
        cover = cv2.warpAffine(alpha, wall_aff, size, flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                               borderValue=0)
        _, roi = cv2.threshold(cover, 127, 255, cv2.THRESH_BINARY)
        zb = sp.standoff_m + sp.background_distance_m
        bg_aff = _image_from_plane(cam, zb, along, up) @ self._bg_tex_to_plane
        bg = cv2.warpAffine(self._bg_img, bg_aff, size, flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        image = cv2.copyTo(wall, roi, bg)  # wall where the truth says wall, background elsewhere
        ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, sp.jpeg_quality])
        image = cv2.imdecode(buf, cv2.IMREAD_COLOR)
        depth = np.full(roi.shape, zb, np.float32)
        depth[roi > 0] = sp.standoff_m
        to_image = np.vstack([_image_from_plane(cam, sp.standoff_m, along, up), [0.0, 0.0, 1.0]])
        return PhotoFrame(index, image, roi, depth, along, up, np.linalg.inv(to_image))

    def frames(self) -> Iterator[PhotoFrame]:
        for i in range(len(self)):
            yield self.render(i)


def true_overlap(a: PhotoFrame, b: PhotoFrame, shape: tuple[int, int]) -> float:
    """Share of frame ``a``'s wall pixels that frame ``b`` also sees (from the wall texture coordinates)."""
    h, w = shape
    b_from_a = np.linalg.inv(b.wall_from_image) @ a.wall_from_image
    seen = cv2.warpPerspective(b.roi_mask, np.linalg.inv(b_from_a), (w, h), flags=cv2.INTER_NEAREST,
                               borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    wall_a = a.roi_mask > 0
    n = int(np.count_nonzero(wall_a))
    return float(np.count_nonzero(seen[wall_a])) / n if n else 0.0

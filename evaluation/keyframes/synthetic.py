"""Synthetic wall views with exactly known overlap, for the gate's tests, benchmarks and a no-simulator eval.

A large procedurally textured "wall" image is viewed by a virtual camera that translates, rotates and zooms
(a similarity transform, i.e. a fronto-parallel camera at a varying standoff). The true overlap of two views is
the area of view A's footprint on the wall covered by view B's footprint, divided by A's footprint area: the
same definition as the simulator's ``true_overlap``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from companion.attitude import camera_rotation_enu
from companion.geo import FacadeFrame, GeoPoint
from companion.keyframes.overlap import convex_intersection_area
from companion.records import Frame, MaskedFrame, Pose, TaggedFrame
from companion.wall_footprint import corner_footprint


def textured_wall(width: int, height: int, seed: int = 0) -> np.ndarray:
    """A BGR wall texture: multi-octave noise (stains, render), a block pattern (panels) and fine grain."""
    rng = np.random.default_rng(seed)
    acc = np.zeros((height, width), np.float32)
    for octave, weight in ((256, 0.35), (64, 0.25), (16, 0.25), (4, 0.15)):
        small = rng.random((max(2, height // octave), max(2, width // octave))).astype(np.float32)
        acc += weight * cv2.resize(small, (width, height), interpolation=cv2.INTER_CUBIC)
    # Panels with slightly different shades and dark joints, like cladding or brickwork at a coarse scale.
    pw, ph = 97, 61
    shade = rng.normal(0.0, 0.06, size=(height // ph + 2, width // pw + 2)).astype(np.float32)
    yy = np.arange(height, dtype=np.int32)[:, None]  # broadcast, not full-size index grids: big walls fit
    xx = np.arange(width, dtype=np.int32)[None, :]
    offset = ((yy // ph) % 2) * (pw // 2)
    acc += shade[yy // ph, (xx + offset) // pw]
    acc -= 0.25 * (((yy % ph) < 3) | (((xx + offset) % pw) < 3))
    acc += rng.normal(0.0, 0.03, size=acc.shape).astype(np.float32)
    del yy, xx, offset
    gray = cv2.normalize(acc, None, 20, 235, cv2.NORM_MINMAX).astype(np.uint8)
    tint = np.array([0.92, 0.97, 1.0], np.float32)  # warm grey
    return np.clip(gray[:, :, None].astype(np.float32) * tint, 0, 255).astype(np.uint8)


@dataclass(frozen=True)
class View:
    """A camera footprint on the wall texture: centre (texture px), rotation (deg) and zoom (texture px per px)."""

    cx: float
    cy: float
    width: int
    height: int
    angle_deg: float = 0.0
    zoom: float = 1.0

    def image_to_texture(self) -> np.ndarray:
        """2x3 affine matrix mapping image pixel coordinates to texture coordinates."""
        c, s = math.cos(math.radians(self.angle_deg)), math.sin(math.radians(self.angle_deg))
        a = self.zoom * np.array([[c, -s], [s, c]])
        t = np.array([self.cx, self.cy]) - a @ np.array([self.width / 2.0, self.height / 2.0])
        return np.hstack([a, t[:, None]])

    def corners(self) -> np.ndarray:
        m = self.image_to_texture()
        rect = np.array([[0, 0, 1], [self.width, 0, 1], [self.width, self.height, 1], [0, self.height, 1]], float)
        return (rect @ m.T).astype(np.float32)


def render(texture: np.ndarray, view: View, blur_sigma: float = 0.0) -> np.ndarray:
    img = cv2.warpAffine(
        texture,
        view.image_to_texture(),
        (view.width, view.height),
        flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
        borderMode=cv2.BORDER_REFLECT,
    )
    if blur_sigma > 0:
        img = cv2.GaussianBlur(img, (0, 0), blur_sigma)
    return img


def true_overlap(a: View, b: View) -> float:
    """Share (0..1) of A's wall footprint that B also shows."""
    area = convex_intersection_area(b.corners(), a.corners())
    return area / float(cv2.contourArea(a.corners()))


def masked_frame(index: int, image: np.ndarray, mask: np.ndarray | None = None, t_s: float | None = None):
    """Wrap an image as the gate's input record (mask all-facade when None)."""
    if mask is None:
        mask = np.full(image.shape[:2], 255, np.uint8)
    frame = Frame(index=index, capture_time_s=float(index) / 30.0 if t_s is None else t_s, image=image)
    return MaskedFrame(tagged=TaggedFrame(frame=frame, pose=None), mask=mask)


def sweep(
    texture: np.ndarray, n: int, step_px: float, width: int, height: int, *, start_x: float | None = None,
    y: float | None = None, jitter_px: float = 0.0, seed: int = 0,
) -> list[View]:
    """Views moving right by ``step_px`` texture px per frame (a horizontal scan leg), optional hand jitter."""
    rng = np.random.default_rng(seed)
    x0 = width / 2.0 + 8 if start_x is None else start_x
    y0 = texture.shape[0] / 2.0 if y is None else y
    return [
        View(x0 + i * step_px + rng.normal(0, jitter_px), y0 + rng.normal(0, jitter_px), width, height)
        for i in range(n)
    ]


def lawnmower(
    n: int, step_px: float, width: int, height: int, texture_shape: tuple[int, ...], *, zoom: float = 1.0,
    margin_px: float = 8.0,
) -> list[View]:
    """``n`` views in horizontal passes joined by vertical moves, each ``step_px`` texture px from the last.

    A continuous serpentine path (no jumps), so a long pass fits a texture a few frames wide.
    """
    th, tw = texture_shape[:2]
    half_w, half_h = zoom * width / 2 + margin_px, zoom * height / 2 + margin_px
    x, y, direction = half_w, half_h, 1.0
    row_target = None
    views = []
    for _ in range(n):
        views.append(View(x, y, width, height, zoom=zoom))
        if row_target is not None:  # moving down to the next pass
            y = min(row_target, y + step_px)
            if y >= row_target:
                row_target, direction = None, -direction
            continue
        nx = x + direction * step_px
        if half_w <= nx <= tw - half_w:
            x = nx
        else:
            row_target = y + zoom * height * 0.5
            if row_target > th - half_h:
                raise ValueError("texture too small for this many views")
            y = min(row_target, y + step_px)
    return views


# -- a wall in front of a far background, seen from telemetry-tagged poses ----------------------------------------
# The views above are one plane: a static far background cannot be told from the wall by how it moves. The scene
# below has both, with exact truth: a wall plane (along_m 0..length_m, up_m 0..height_m at out_m = 0) textured
# with ``wall``, and a background plane ``background_distance_m`` behind it that fills the rest of the view.
# Cameras are given in facade coordinates (companion.geo) and tagged with geodetic poses of a real-looking site,
# so the gate's telemetry path sees exactly what the onboard chain would give it.

SITE = FacadeFrame.from_wall(GeoPoint(37.5665, 126.978, 30.0), GeoPoint(37.5665, 126.9786, 30.0))  # 53 m wall, W->E


@dataclass(frozen=True)
class WallCamera:
    """A camera in facade coordinates: centre (along, out, up) in metres, turned right by ``yaw_deg`` from facing
    the wall and up by ``pitch_deg`` (a stabilised gimbal: no roll)."""

    along_m: float
    out_m: float
    up_m: float
    yaw_deg: float = 0.0
    pitch_deg: float = 0.0

    def rotation(self) -> np.ndarray:
        """Columns: the camera's right, down and forward axes in facade coordinates (along, out, up).

        (along, -out, up) is a right-handed frame in which facing the wall is heading 0, so the camera's attitude
        there is ``camera_rotation_enu``'s; flipping the out row gives the (left-handed) facade axes."""
        return np.diag([1.0, -1.0, 1.0]) @ camera_rotation_enu(yaw_deg=self.yaw_deg, pitch_deg=self.pitch_deg)

    @property
    def centre(self) -> np.ndarray:
        return np.array([self.along_m, self.out_m, self.up_m])


@dataclass(frozen=True)
class WallScene:
    """Wall texture over ``length_m`` x ``height_m`` (row 0 = top of the wall) and a background texture spread
    over ``background_size_m`` (width, height; centred on the wall, bottom at ground level) at the distance."""

    wall: np.ndarray
    background: np.ndarray
    length_m: float
    height_m: float
    background_distance_m: float = 120.0
    background_size_m: tuple[float, float] = (600.0, 200.0)
    width_px: int = 480
    height_px: int = 270
    hfov_deg: float = 69.0
    frame: FacadeFrame = SITE

    @property
    def K(self) -> np.ndarray:
        f = (self.width_px / 2.0) / math.tan(math.radians(self.hfov_deg) / 2.0)
        return np.array([[f, 0.0, self.width_px / 2.0], [0.0, f, self.height_px / 2.0], [0.0, 0.0, 1.0]])

    def _plane_to_image(self, cam: WallCamera, texture: np.ndarray, origin, size_m, out_m: float) -> np.ndarray:
        """Homography from a texture's pixels (row 0 = top) to image pixels, the texture spanning ``size_m`` from
        the facade point ``origin`` (along, up of its bottom-left corner) on the plane ``out_m``."""
        th, tw = texture.shape[:2]
        sx, sy = size_m[0] / tw, size_m[1] / th
        c = cam.centre
        top = origin[1] + size_m[1]
        to_rel = np.array([[sx, 0.0, origin[0] - c[0]], [0.0, 0.0, out_m - c[1]], [0.0, -sy, top - c[2]]])
        return self.K @ cam.rotation().T @ to_rel

    def render(self, cam: WallCamera) -> tuple[np.ndarray, np.ndarray]:
        """(BGR image, truth ROI mask 0/255 = wall) of the scene from ``cam``."""
        size = (self.width_px, self.height_px)
        bw, bh = self.background_size_m
        Hb = self._plane_to_image(cam, self.background, (self.length_m / 2 - bw / 2, 0.0), (bw, bh),
                                  -self.background_distance_m)
        image = cv2.warpPerspective(self.background, Hb, size, flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
        Hw = self._plane_to_image(cam, self.wall, (0.0, 0.0), (self.length_m, self.height_m), 0.0)
        wall = cv2.warpPerspective(self.wall, Hw, size, flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        ones = np.full(self.wall.shape[:2], 255, np.uint8)
        mask = cv2.warpPerspective(ones, Hw, size, flags=cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT)
        image[mask > 0] = wall[mask > 0]
        return image, mask

    def footprint(self, cam: WallCamera) -> np.ndarray:
        """The image rectangle on the wall PLANE (along_m, up_m), 4 x 2: what true overlap is measured on."""
        fp = corner_footprint(self.K, self.width_px, self.height_px, cam.centre, cam.rotation())
        if fp is None:
            raise ValueError(f"{cam} does not see the whole image on the wall plane")
        return fp

    def true_overlap(self, a: WallCamera, b: WallCamera) -> float:
        """Share (0..1) of a's footprint on the wall plane that b's covers (the simulator's definition)."""
        fa, fb = self.footprint(a), self.footprint(b)
        return convex_intersection_area(fb, fa) / abs(float(cv2.contourArea(fa.astype(np.float32))))

    def wall_share(self, cam: WallCamera) -> float:
        """Share of the image that shows the wall."""
        return float((self.render(cam)[1] > 0).mean())

    def pose(self, cam: WallCamera, t_s: float = 0.0, *, offset_m: tuple[float, float, float] = (0.0, 0.0, 0.0),
             yaw_error_deg: float = 0.0) -> Pose:
        """The telemetry a GNSS/IMU would give for ``cam`` (optionally off by ``offset_m`` in facade axes)."""
        along, out, up = cam.centre + np.asarray(offset_m, dtype=float)
        lat, lon, alt = (float(v) for v in self.frame.facade_to_geodetic(along, out, up))
        yaw = (self.frame.yaw_facing_wall_deg + cam.yaw_deg + yaw_error_deg) % 360.0
        return Pose(t_s, lat, lon, alt, float(up), 0.0, 0.0, yaw, gimbal_pitch_deg=cam.pitch_deg)

    def masked_frame(self, index: int, cam: WallCamera, *, t_s: float | None = None, mask: str = "truth",
                     pose: Pose | None = None, with_pose: bool = True) -> MaskedFrame:
        """The gate's input for ``cam``: ``mask`` 'truth' (the wall only) or 'none' (whole frame as ROI)."""
        image, roi = self.render(cam)
        t = float(index) / 30.0 if t_s is None else t_s
        if mask == "none":
            roi = np.full(image.shape[:2], 255, np.uint8)
        elif mask != "truth":
            raise ValueError(f"mask must be 'truth' or 'none', not {mask!r}")
        p = (pose or self.pose(cam, t)) if with_pose else None
        return MaskedFrame(tagged=TaggedFrame(frame=Frame(index=index, capture_time_s=t, image=image), pose=p),
                           mask=roi)

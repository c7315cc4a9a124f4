"""Training frames built from real photos with exactly known depth: a real facade on a wall plane before a far photo.

The simulator's procedural walls taught the model that windows, arches and balconies are far (its windows are
flat paint) and that anything plain and bright at the top of a frame is sky. Real labelled facades fix the
textures, but a photo has no depth. So we build the depth: the facade part of a labelled photo (CMP: classes
2-12; LabelMeFacade: building, window, door) is perspective-warped onto a plane 3-8 m in front of the camera,
turned by a small random yaw and pitch, so every wall pixel's z-depth is the plane's depth along that pixel's ray.
Behind it, a real outdoor photo (LabelMeFacade backgrounds: sky, trees, streets, distant buildings) is a plane
at 20-500 m (clipped to the model's depth range), its labelled sky at the clip depth. The label of each photo
decides what is wall: a photo's own sky or neighbours never count as wall, and windows and balconies always do.

Views: mid-wall (the scan's common frame), views that run off the wall's end or over its top (part wall, part
background: the roof line and the wall end of a real building), and background-only views (no wall at all,
the frames the masker must drop). Plain walls come from the shared domain randomisation (``data.plain_wall``).
Two named options (``CompositeOptions``, off by default): windows that reflect the background, and bright grey
cladding.

Only photos of ``realdata``'s ``train`` split are ever loaded here.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from companion.attitude import camera_rotation_enu
from companion.depth.training.realdata import (
    RealPhoto,
    Split,
    facade_mask,
    list_real_photos,
    load_image,
    window_mask,
)
from companion.errors import CompanionError

log = logging.getLogger(__name__)

STANDOFF_M = (3.0, 8.0)
BACKGROUND_M = (20.0, 500.0)
WALL_WIDTH_M = (8.0, 30.0)  # physical width of the photo's facade
MAX_YAW_DEG = 20.0
MAX_PITCH_DEG = 12.0
BACKGROUND_ONLY = 0.12
OFF_WALL_EDGE = 0.40  # views that show a wall end or the top of the wall
_SKY_RGB = (0, 128, 128)  # LabelMeFacade sky
REFLECTION_STRENGTH = (0.35, 1.0)  # share of a reflecting window's colour that is the reflection
REFLECTION_ZOOM = (1.0, 2.5)  # the reflected crop is 1/2.5 to all of the background frame


@dataclass(frozen=True)
class CompositeOptions:
    """Named changes of the real-photo composites, all off by default (off: the samples of before, bit for bit).

    ``reflect_windows``: share of wall composites whose window glass (CMP class 3, LabelMe window) shows a
    mirrored, zoomed crop of the sample's own background photo (trees, sky, buildings), blended in at a random
    strength, while the depth truth stays the wall plane's. Real windows reflect what is behind and around the
    camera, and every real-photo model so far cuts a window reflecting trees and sky (the DJI photo); the labelled
    photos' glass rarely shows them, so the composites never taught that such pixels can be near.

    ``bright_walls``: share of composites whose facade becomes bright, grey, low-texture cladding
    (``data.bright_cladding``), mostly under an overcast sky: the labelled facades are mostly darker brick, stone
    and render, so such walls were rare in the composites.

    Tried once with the mask loss (docs/DEPTH.md, "Reflecting windows and bright cladding"): not enough on their own
    to make a model pass the real-photo checks.
    """

    reflect_windows: float = 0.0
    bright_walls: float = 0.0


@dataclass(frozen=True)
class WallPhoto:
    """A real facade photo (BGR uint8), its facade mask and its window-glass mask (bool), downscaled for
    training (``windows`` None: no window labels, such a wall never reflects)."""

    image: np.ndarray
    facade: np.ndarray
    name: str
    windows: np.ndarray | None = None


@dataclass(frozen=True)
class BackgroundPhoto:
    """A real outdoor photo (BGR uint8) and its sky mask (bool)."""

    image: np.ndarray
    sky: np.ndarray
    name: str


@dataclass(frozen=True)
class PhotoBank:
    walls: tuple[WallPhoto, ...]
    backgrounds: tuple[BackgroundPhoto, ...]


@dataclass(frozen=True)
class Composite:
    """One training frame at model input size: image (BGR uint8), z-depth (float32 m), facade (uint8 255) and sky
    (bool), plus the plane that made the wall (None for a background-only frame)."""

    image: np.ndarray
    depth: np.ndarray
    facade: np.ndarray
    sky: np.ndarray
    K: np.ndarray
    plane_normal: np.ndarray | None  # unit normal n (away from the camera), plane n.X = plane_offset > 0 (metres)
    plane_offset: float
    background_depth_m: float


def _downscale(image: np.ndarray, mask: np.ndarray, max_side: int) -> tuple[np.ndarray, np.ndarray]:
    scale = max_side / max(image.shape[:2])
    if scale >= 1.0:
        return image, mask
    size = (max(1, round(image.shape[1] * scale)), max(1, round(image.shape[0] * scale)))
    return (cv2.resize(image, size, interpolation=cv2.INTER_AREA),
            cv2.resize(mask.astype(np.uint8), size, interpolation=cv2.INTER_NEAREST) > 0)


def _sky_mask(photo: RealPhoto) -> np.ndarray:
    bgr = cv2.imread(str(photo.label), cv2.IMREAD_COLOR)
    if bgr is None:
        raise CompanionError(f"cannot decode label {photo.label}", "restore the file from the shared data set")
    return np.all(bgr[..., ::-1] == np.array(_SKY_RGB, np.uint8), axis=-1)


def load_photo_bank(root: Path | None = None, max_side: int = 768, split: Split = "train") -> PhotoBank:
    """One split's labelled facades (CMP, LabelMeFacade) and backgrounds, downscaled to ``max_side``.

    Training uses the ``train`` split (the default) only; ``heldout`` is for the figures (bench/depth_real_photos.py).
    """
    walls, backgrounds = [], []
    for photo in list_real_photos(root, split=split):
        if photo.split != split or photo.label is None:  # never the other split, never an unlabelled photo
            continue
        image = load_image(photo)
        if photo.kind == "facade":
            facade = facade_mask(photo) > 0
            if facade.mean() < 0.2:
                continue
            _, windows = _downscale(image, window_mask(photo) > 0, max_side)
            image, facade = _downscale(image, facade, max_side)
            walls.append(WallPhoto(image, facade, photo.image.name, windows))
        else:
            image, sky = _downscale(image, _sky_mask(photo), max_side)
            backgrounds.append(BackgroundPhoto(image, sky, photo.image.name))
    if not walls or not backgrounds:
        raise CompanionError(f"no labelled {split} facades or backgrounds in the real photo folder",
                             "put the project's shared data beside the checkout (../shared/data/real-facades)")
    log.info("real photo bank: %d facades, %d backgrounds (train split)", len(walls), len(backgrounds))
    return PhotoBank(tuple(walls), tuple(backgrounds))


def camera_matrix(rng: np.random.Generator, height: int, width: int, aspect: float | None = None) -> np.ndarray:
    """Intrinsics at the model input size of a 16:9 or 4:3 camera (or ``aspect`` = frame height / width) with a
    55-80 deg horizontal field of view, squashed to height x width as the runtime squashes every frame."""
    hfov = np.radians(rng.uniform(55.0, 80.0))
    if aspect is None:
        aspect = 9 / 16 if rng.random() < 0.5 else 3 / 4
    tan_h = np.tan(hfov / 2)
    fx = (width / 2) / tan_h
    fy = (height / 2) / (tan_h * aspect)
    return np.array([[fx, 0, width / 2 - 0.5], [0, fy, height / 2 - 0.5], [0, 0, 1]], np.float64)


def _rotation(yaw_deg: float, pitch_deg: float) -> np.ndarray:
    """A camera turned by ``yaw_deg`` / ``pitch_deg``, in the axes of the level camera it was turned from."""
    level = camera_rotation_enu(yaw_deg=0.0, pitch_deg=0.0)
    return level.T @ camera_rotation_enu(yaw_deg=yaw_deg, pitch_deg=pitch_deg)


def plane_depth(K: np.ndarray, normal: np.ndarray, offset: float, height: int, width: int) -> np.ndarray:
    """z-depth of the plane n.X = offset seen through every pixel centre (inf where the ray misses it)."""
    u, v = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
    rays = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], -1)  # z component 1
    denom = rays @ normal
    with np.errstate(divide="ignore"):
        z = np.where(denom > 1e-9, offset / denom, np.inf)
    return z


def _background(bank: PhotoBank, rng: np.random.Generator, height: int, width: int, aspect: float):
    bg = bank.backgrounds[int(rng.integers(len(bank.backgrounds)))]
    h, w = bg.image.shape[:2]
    # a crop of the photo with the camera's aspect, 50-100 % of the photo's size
    cw = w * rng.uniform(0.5, 1.0)
    ch = min(h, cw * aspect)
    cw = ch / aspect
    x0, y0 = rng.uniform(0, w - cw), rng.uniform(0, h - ch)
    src = np.float32([[x0, y0], [x0 + cw, y0], [x0, y0 + ch]])
    dst = np.float32([[0, 0], [width, 0], [0, height]])
    A = cv2.getAffineTransform(src, dst)
    image = cv2.warpAffine(bg.image, A, (width, height), flags=cv2.INTER_AREA, borderMode=cv2.BORDER_REFLECT)
    sky = cv2.warpAffine(bg.sky.astype(np.uint8), A, (width, height), flags=cv2.INTER_NEAREST,
                         borderMode=cv2.BORDER_REFLECT) > 0
    if rng.random() < 0.5:
        image, sky = image[:, ::-1], sky[:, ::-1]
    return np.ascontiguousarray(image), np.ascontiguousarray(sky)


def reflection(background: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """What a window pane shows of the scene: the background frame mirrored left-right, a crop of it (biased to its
    upper part: trees and sky) zoomed 1-2.5x, dimmed or tinted and a little soft, as float32 BGR 0-255."""
    h, w = background.shape[:2]
    zoom = rng.uniform(*REFLECTION_ZOOM)
    cw, ch = w / zoom, h / zoom
    x0, y0 = rng.uniform(0, w - cw), rng.uniform(0, 0.5 * (h - ch))
    src = np.float32([[x0 + cw, y0], [x0, y0], [x0 + cw, y0 + ch]])  # right edge -> left: mirrored
    dst = np.float32([[0, 0], [w, 0], [0, h]])
    A = cv2.getAffineTransform(src, dst)
    out = cv2.warpAffine(background, A, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    out = out.astype(np.float32) * rng.uniform(0.6, 1.1) * rng.uniform(0.9, 1.1, size=3).astype(np.float32)
    sigma = rng.uniform(0.0, 1.5)
    return cv2.GaussianBlur(out, (0, 0), sigma) if sigma > 0.3 else out


def reflect_in_windows(
    image: np.ndarray, background: np.ndarray, glass: np.ndarray, rng: np.random.Generator
) -> np.ndarray:
    """Blend ``reflection(background)`` into the float image where ``glass`` (0-1 coverage) is, at a random
    strength: the pixels change, their depth (the wall plane's) does not."""
    strength = rng.uniform(*REFLECTION_STRENGTH)
    a = (glass * strength)[..., None]
    return image * (1.0 - a) + reflection(background, rng) * a


def compose(
    bank: PhotoBank, rng: np.random.Generator, height: int = 192, width: int = 640, max_depth: float = 100.0,
    *, background_only: bool | None = None, square_pixels: bool = False,
    options: CompositeOptions = CompositeOptions(),
) -> Composite:
    """One random composite frame (see the module docstring). ``square_pixels``: a camera frame of height x width
    (for evaluation) instead of a 16:9 or 4:3 frame squashed to the model input (for training). ``options``: see
    ``CompositeOptions`` (their random draws come after all others, so they change nothing else of a sample)."""
    K = camera_matrix(rng, height, width, aspect=height / width if square_pixels else None)
    aspect = (K[0, 0] / K[1, 1]) * height / width  # source-frame height / width
    bg_image, sky = _background(bank, rng, height, width, aspect)
    bg_depth = float(np.exp(rng.uniform(np.log(BACKGROUND_M[0]), np.log(BACKGROUND_M[1]))))
    depth = np.where(sky, max_depth, min(bg_depth, max_depth)).astype(np.float32)
    facade = np.zeros((height, width), np.uint8)
    if background_only is None:
        background_only = rng.random() < BACKGROUND_ONLY
    if background_only:
        return Composite(bg_image, depth, facade, sky, K, None, float("nan"), bg_depth)

    wall = bank.walls[int(rng.integers(len(bank.walls)))]
    tex, tex_mask = wall.image, wall.facade
    flipped = rng.random() < 0.5
    if flipped:
        tex, tex_mask = tex[:, ::-1], tex_mask[:, ::-1]
    th, tw = tex.shape[:2]
    ys, xs = np.nonzero(tex_mask)
    mpp = rng.uniform(*WALL_WIDTH_M) / max(1, xs.max() - xs.min() + 1)  # metres per texture pixel
    standoff = rng.uniform(*STANDOFF_M)
    R = _rotation(rng.uniform(-MAX_YAW_DEG, MAX_YAW_DEG), rng.uniform(-MAX_PITCH_DEG, MAX_PITCH_DEG))
    axis_s, axis_t, normal = R[:, 0], R[:, 1], R[:, 2]  # wall right, wall down, away from the camera
    centre = np.array([0.0, 0.0, standoff])  # the wall point on the optical axis
    # which texture point the optical axis hits: inside the facade, or beyond its end / top (half a view width)
    half_view_px = standoff * (width / 2) / K[0, 0] / mpp
    if rng.random() < OFF_WALL_EDGE:
        s0 = rng.uniform(xs.min() - half_view_px, xs.max() + half_view_px)
        t0 = rng.uniform(ys.min() - half_view_px * aspect, ys.max() + half_view_px * aspect)
    else:
        k = int(rng.integers(len(xs)))
        s0, t0 = float(xs[k]), float(ys[k])
    origin = centre - mpp * (s0 * axis_s + t0 * axis_t)
    H = K @ np.column_stack([mpp * axis_s, mpp * axis_t, origin])  # texture (s, t, 1) -> image
    ss = 2  # supersample the texture warp (a texture pixel is often smaller than an output pixel)
    H2 = np.diag([ss, ss, 1.0]) @ H
    big = (width * ss, height * ss)
    warped = cv2.warpPerspective(tex, H2, big, flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
    alpha = cv2.warpPerspective(tex_mask.astype(np.float32), H2, big, flags=cv2.INTER_LINEAR,
                                borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    warped = cv2.resize(warped, (width, height), interpolation=cv2.INTER_AREA).astype(np.float32)
    alpha = cv2.resize(alpha, (width, height), interpolation=cv2.INTER_AREA)
    image = warped * alpha[..., None] + bg_image.astype(np.float32) * (1.0 - alpha[..., None])
    reflect = (options.reflect_windows > 0 and wall.windows is not None and wall.windows.any()
               and rng.random() < options.reflect_windows)
    if reflect:
        glass = wall.windows[:, ::-1] if flipped else wall.windows
        glass_alpha = cv2.warpPerspective(glass.astype(np.float32), H2, big, flags=cv2.INTER_LINEAR,
                                          borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        glass_alpha = np.minimum(cv2.resize(glass_alpha, (width, height), interpolation=cv2.INTER_AREA), alpha)
        image = reflect_in_windows(image, bg_image, glass_alpha, rng)
    image = np.clip(image + 0.5, 0, 255).astype(np.uint8)
    on_wall = alpha >= 0.5
    offset = float(normal @ centre)
    z = plane_depth(K, normal, offset, height, width)
    depth = np.where(on_wall, np.clip(z, 0.1, max_depth), depth).astype(np.float32)
    facade[on_wall] = 255
    return Composite(image, depth, facade, sky & ~on_wall, K, normal, offset, bg_depth)

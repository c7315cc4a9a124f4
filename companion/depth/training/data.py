"""Training samples from simulator recordings, with the domain randomisation that carries the model to real photos.

Each sample is the frame resized to the model input (as the runtime does: whole frame, squashed to H x W), its
true depth (metres, inf sky clipped to the model's max depth), and a random crop of both for cheaper CPU steps.
Randomisation: colour/brightness/contrast/gamma, greyscale, light gradients, blur, sensor noise, JPEG, flips, and
two scene-level ones that the simulator's textured walls and blue skies lack and real photos have: plain walls
(texture suppressed on all or part of the facade, with uneven low-frequency light) and overcast or over-exposed
sky (flat grey or white). Without them a small model learns "plain and bright = sky" and cuts plain cladding.
Needs numpy + OpenCV only (torch is imported by the training loop).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from companion.errors import CompanionError
from companion.plugins import provided

SKY_DEPTH_FRACTION = 0.99  # true depth at or beyond this fraction of the clip depth is sky


@dataclass
class FrameSet:
    """Frames (N x H x W x 3 uint8 BGR) and true depth (N x H x W float32 metres) at model input size."""

    images: np.ndarray
    depths: np.ndarray
    roi_masks: np.ndarray  # N x H x W uint8, 255 = facade (for evaluation)

    def __len__(self) -> int:
        return len(self.images)


def load_frames(recordings: list[Path], height: int, width: int, max_depth: float, stride: int = 1) -> FrameSet:
    """Read simulator recordings and resize every ``stride``-th frame to the model input."""
    open_recording = provided("open_recording", "training on simulator recordings")
    images, depths, masks = [], [], []
    for path in recordings:
        rec = open_recording(path)
        for i in range(0, len(rec), stride):
            images.append(cv2.resize(rec.image(i), (width, height), interpolation=cv2.INTER_AREA))
            d = np.asarray(rec.depth(i), dtype=np.float32)
            d = np.where(np.isfinite(d), d, max_depth)
            # nearest keeps depth edges sharp (no averaged near/far pixels that exist nowhere)
            depths.append(np.clip(cv2.resize(d, (width, height), interpolation=cv2.INTER_NEAREST), 0.1, max_depth))
            masks.append(cv2.resize(rec.roi_mask(i), (width, height), interpolation=cv2.INTER_NEAREST))
    if not images:
        raise CompanionError("no frames in the training recordings", "check the recording folders (frames/*.jpg)")
    return FrameSet(np.stack(images), np.stack(depths), np.stack(masks))


def _smooth_field(shape: tuple[int, int], rng: np.random.Generator, amplitude: float) -> np.ndarray:
    """Low-frequency random field in [-amplitude, amplitude]: uneven light over a wall or a cloud deck."""
    h, w = shape
    coarse = rng.uniform(-1.0, 1.0, size=(int(rng.integers(2, 5)), int(rng.integers(2, 7)))).astype(np.float32)
    return cv2.resize(coarse, (w, h), interpolation=cv2.INTER_CUBIC).clip(-1, 1) * amplitude


def _region_patch(region: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """A random ellipse (10-60 % of the frame height) intersected with ``region``."""
    h, w = region.shape
    patch = np.zeros((h, w), np.uint8)
    centre = (int(rng.integers(0, w)), int(rng.integers(0, h)))
    axes = (int(rng.uniform(0.1, 0.6) * h * rng.uniform(1.0, 2.5)), int(rng.uniform(0.1, 0.6) * h))
    cv2.ellipse(patch, centre, axes, float(rng.uniform(0, 180)), 0, 360, 1, -1)
    return region & (patch > 0)


def _chosen_region(facade: np.ndarray, rng: np.random.Generator, whole_share: float) -> np.ndarray | None:
    """The facade whole (``whole_share`` of the samples) or a patch of it (:func:`_region_patch`); None when too
    few pixels are left to paint. One helper for :func:`plain_wall` and :func:`bright_cladding` so both draw it the
    same way (the draws and their order decide every training sample)."""
    region = facade if rng.random() < whole_share else _region_patch(facade, rng)
    return None if region.sum() < 50 else region


def _lit_flat(base: np.ndarray, img: np.ndarray, region: np.ndarray, rng: np.random.Generator, *,
              light_max: float, detail_max: float, lift: tuple[float, float] | None = None) -> np.ndarray:
    """``base`` colour under a smooth random light field (0-``light_max``, plus a brightness lift drawn from
    ``lift`` when given), with 0-``detail_max`` of the photo's local detail kept: the plain surface both
    :func:`plain_wall` and :func:`bright_cladding` paint. The draws keep their order (field amplitude, field, lift,
    detail share) so the samples stay the ones before this helper existed."""
    detail = img - cv2.GaussianBlur(img, (0, 0), 3.0)
    light = 1.0 + _smooth_field(region.shape, rng, rng.uniform(0.0, light_max))
    if lift is not None:
        light = light + rng.uniform(*lift)
    return base[None, None, :] * light[..., None] + detail * rng.uniform(0.0, detail_max)


def _painted(img: np.ndarray, region: np.ndarray, flat: np.ndarray, rng: np.random.Generator,
             noise_max: float) -> np.ndarray:
    """``flat`` with sensor noise (sigma 0.002-``noise_max``) in ``region``, ``img`` elsewhere: the outline stays
    sharp, as a real roof line or wall end is."""
    flat = flat + rng.normal(0, rng.uniform(0.002, noise_max), img.shape).astype(np.float32)
    return np.where(region[..., None], flat, img).astype(np.float32)


def plain_wall(img: np.ndarray, facade: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Suppress the texture of the facade pixels (float BGR in [0, 1], ``facade`` bool), whole or a patch.

    Keeps 0-40 % of the local detail (seams, window outlines stay faintly) around the region's mean colour, lit by a
    smooth random field and a brightness lift: what plain cladding or render looks like under soft light. The
    region's outline is left sharp, as a real roof line or wall end is.
    """
    region = _chosen_region(facade, rng, 0.6)
    if region is None:
        return img
    base = img[region].mean(axis=0)
    flat = _lit_flat(base, img, region, rng, light_max=0.3, detail_max=0.4, lift=(-0.1, 0.35))
    return _painted(img, region, flat, rng, 0.015)


def bright_cladding(img: np.ndarray, facade: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Turn the facade pixels (float BGR in [0, 1], ``facade`` bool) into bright, grey, nearly textureless cladding.

    ``plain_wall`` keeps the photo's own mean colour, and most labelled facades are mid-dark brick, stone or
    render, so a bright grey clad wall under an overcast sky (a common case for an inspection drone) was rare in the
    composites. Here the level is 0.55-0.92 (before the global brightness
    jitter), the colour grey with at most a faint tint of the photo's own, 0-25 % of the detail kept, soft light
    (overcast: +-0-12 %), and in half the samples faint panel seams.
    """
    region = _chosen_region(facade, rng, 0.75)
    if region is None:
        return img
    own = img[region].mean(axis=0)
    own = own / max(float(own.mean()), 1e-3)  # the photo's hue at unit level
    hue = 1.0 + (own - 1.0) * rng.uniform(0.0, 0.4) + rng.uniform(-0.03, 0.03, size=3)
    base = (rng.uniform(0.55, 0.92) * hue).astype(np.float32)
    flat = _lit_flat(base, img, region, rng, light_max=0.12, detail_max=0.25)
    if rng.random() < 0.5:  # panel seams: thin darker lines on a regular grid
        flat = _with_seams(flat, region.shape, rng)
    return _painted(img, region, flat, rng, 0.012)


def _with_seams(flat: np.ndarray, shape: tuple[int, int], rng: np.random.Generator) -> np.ndarray:
    """``flat`` darkened 2-10 % along thin lines on a regular grid (15-80 px apart, random offset): the panel
    seams of clad walls."""
    h, w = shape
    seams = np.zeros((h, w), np.float32)
    step_x, step_y = int(rng.integers(15, 80)), int(rng.integers(15, 80))
    seams[:, int(rng.integers(0, step_x))::step_x] = 1.0
    seams[int(rng.integers(0, step_y))::step_y, :] = 1.0
    return flat * (1.0 - seams[..., None] * rng.uniform(0.02, 0.1))


def overcast_sky(img: np.ndarray, sky: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Replace the sky pixels (float BGR, ``sky`` bool) with a flat grey-white cloud deck, never the wall's exact
    shade (a roof line against a sky of the same colour has no visible edge for any model to find)."""
    if sky.sum() < 50:
        return img
    wall_level = float(img[~sky].mean()) if (~sky).any() else 0.5
    level = wall_level * (rng.uniform(1.15, 1.8) if rng.random() < 0.7 else rng.uniform(0.55, 0.85))
    tint = np.array([1.0, 1.0, 1.0], np.float32) * rng.uniform(0.96, 1.04, size=3).astype(np.float32)
    deck = level * tint[None, None, :] * (1.0 + _smooth_field(sky.shape, rng, rng.uniform(0.0, 0.12))[..., None])
    return np.where(sky[..., None], np.clip(deck, 0, 1), img).astype(np.float32)


def randomise(
    image: np.ndarray, rng: np.random.Generator, *, facade: np.ndarray | None = None, sky: np.ndarray | None = None,
    bright_walls: float = 0.0,
) -> np.ndarray:
    """Domain randomisation of one BGR uint8 image (geometry untouched).

    ``facade`` and ``sky`` (bool masks from the simulator's truth) enable the plain-wall and overcast-sky changes.
    ``bright_walls``: share of samples whose facade becomes bright grey cladding (``bright_cladding``), then under
    an overcast sky 70 % of the time instead of 30 %; 0 (the default) draws nothing extra, so the samples are the
    ones before the option existed.
    """
    img = image.astype(np.float32) / 255.0
    clad = facade is not None and bright_walls > 0 and rng.random() < bright_walls
    if clad:
        img = bright_cladding(img, facade, rng)
    elif facade is not None and rng.random() < 0.4:
        img = plain_wall(img, facade, rng)
    if sky is not None and rng.random() < (0.7 if clad else 0.3):
        img = overcast_sky(img, sky, rng)
    if rng.random() < 0.2:  # greyscale: real facades are often colourless concrete / cladding
        g = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
        img = np.repeat(g[..., None], 3, axis=2)
    img = img * rng.uniform(0.7, 1.3, size=3).astype(np.float32)  # white balance / colour cast
    mean = img.mean()
    img = (img - mean) * rng.uniform(0.5, 1.4) + mean * rng.uniform(0.6, 1.4)  # contrast, brightness
    if rng.random() < 0.5:  # uneven light: a linear ramp in a random direction
        h, w = img.shape[:2]
        ang = rng.uniform(0, 2 * np.pi)
        yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
        ramp = (np.cos(ang) * (xx / w - 0.5) + np.sin(ang) * (yy / h - 0.5)) * rng.uniform(0, 0.6)
        img = img * (1.0 + ramp[..., None])
    img = np.clip(img, 0, 1) ** rng.uniform(0.7, 1.4)  # gamma
    if rng.random() < 0.4:
        k = int(rng.choice([3, 5, 7]))
        img = cv2.GaussianBlur(img, (k, k), 0)
    if rng.random() < 0.5:
        img = img + rng.normal(0, rng.uniform(0.005, 0.04), img.shape).astype(np.float32)
    out = np.clip(img * 255.0, 0, 255).astype(np.uint8)
    if rng.random() < 0.5:
        ok, buf = cv2.imencode(".jpg", out, [cv2.IMWRITE_JPEG_QUALITY, int(rng.integers(25, 90))])
        if ok:
            out = cv2.imdecode(buf, cv2.IMREAD_COLOR)
    return out


def to_input(image_bgr: np.ndarray) -> np.ndarray:
    """BGR uint8 H x W x 3 -> RGB float32 3 x H x W in [0, 1], the model's input convention."""
    return cv2.cvtColor(image_bgr, cv2.COLOR_BGR2RGB).astype(np.float32).transpose(2, 0, 1) / 255.0


def augment_crop(
    image: np.ndarray, depth: np.ndarray, facade: np.ndarray, sky: np.ndarray, rng: np.random.Generator,
    crop: tuple[int, int] | None, augment: bool = True, bright_walls: float = 0.0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One training sample from a frame at model input size: a random crop, randomised and maybe flipped.

    Returns (3 x h x w RGB float input, 1 x h x w float32 depth, 1 x h x w bool facade) (the facade crop feeds the
    near/far mask loss). ``bright_walls``: see ``randomise``."""
    h, w = depth.shape
    ch, cw = crop or (h, w)
    y0 = int(rng.integers(0, h - ch + 1))
    x0 = int(rng.integers(0, w - cw + 1))
    img = image[y0 : y0 + ch, x0 : x0 + cw]
    dep = depth[y0 : y0 + ch, x0 : x0 + cw]
    fac = facade[y0 : y0 + ch, x0 : x0 + cw] > 0
    if augment:
        img = randomise(img, rng, facade=fac, sky=sky[y0 : y0 + ch, x0 : x0 + cw], bright_walls=bright_walls)
        if rng.random() < 0.5:
            img, dep, fac = img[:, ::-1], dep[:, ::-1], fac[:, ::-1]
    return (to_input(np.ascontiguousarray(img)), np.ascontiguousarray(dep, dtype=np.float32)[None],
            np.ascontiguousarray(fac)[None])


def sample_batch(
    frames: FrameSet, batch: int, crop: tuple[int, int] | None, rng: np.random.Generator, augment: bool = True,
    max_depth: float = 100.0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A random batch: (B x 3 x h x w inputs, B x 1 x h x w true depth, B x 1 x h x w bool facade from the truth
    masks), cropped and randomised.

    ``max_depth`` is the clip depth of ``frames`` (sky is stored at it)."""
    xs, ds, fs = [], [], []
    for idx in rng.integers(0, len(frames), batch):
        dep = np.asarray(frames.depths[idx], dtype=np.float32)
        x, d, f = augment_crop(frames.images[idx], dep, frames.roi_masks[idx], dep >= SKY_DEPTH_FRACTION * max_depth,
                               rng, crop, augment)
        xs.append(x)
        ds.append(d)
        fs.append(f)
    return np.stack(xs), np.stack(ds).astype(np.float32), np.stack(fs)

"""SIFT features inside the ROI mask only, so sky, trees and far buildings never steer the alignment.

The extraction itself is the keyframe gate's (one function for both); this module adds the stitcher's needs:
full-resolution keypoints, the grey level at each (gain compensation) and an on-disk cache.
"""

from __future__ import annotations

import hashlib
import json
import logging
import threading
from collections import OrderedDict
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import cv2
import numpy as np
from PIL import Image

from companion.errors import CompanionError
from companion.files import atomic_path
from companion.image_files import TRUNCATED, UNDECODABLE, ZERO_BYTES, read_image_file
from companion.keyframes.features import FeatureConfig, FeatureExtractor
from companion.progress import progress_bar
from companion.stitch.config import STITCH_FEATURES, StitchConfig, worker_count
from companion.stitch.inputs import KeyframeInput, SkippedKeyframe, StitchInput

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Features:
    keypoints: np.ndarray  # (N, 2) float32 full-resolution pixel coordinates
    descriptors: np.ndarray  # (N, 128) float32
    image_size: tuple[int, int]  # (width, height)
    luminance: np.ndarray | None = None  # (N,) local mean grey level at each keypoint, for gain compensation


def read_image(path: Path, flags: int, what: str) -> np.ndarray:
    """Decodes an image file, refusing a damaged one (a JPEG cut short decodes in OpenCV with grey below the cut):
    the shared decode path of companion/image_files.py, its reason raised in the stitcher's words."""
    read = read_image_file(path, flags)
    if read.ok:
        return read.image
    if read.problem == TRUNCATED:
        raise CompanionError(f"{what} {path} is {TRUNCATED}",
                             "the file was cut short while it was written; the map is made without it")
    if read.problem == UNDECODABLE:
        raise CompanionError(f"cannot decode {what} {path}", "the spool must write complete JPEG or PNG files")
    raise CompanionError(f"{what} {path} {read.problem}", "check that the file is there")


_REDUCED_GREY = {1: cv2.IMREAD_GRAYSCALE, 2: cv2.IMREAD_REDUCED_GRAYSCALE_2, 4: cv2.IMREAD_REDUCED_GRAYSCALE_4}


def load_working_copy(kf: KeyframeInput, work_width: int) -> tuple[np.ndarray, np.ndarray, tuple[int, int]]:
    """(grey image, 0/255 ROI mask of its size, the keyframe's full (width, height)) for feature extraction.

    A JPEG is decoded straight at 1/2 or 1/4 of its size where that is still at least ``work_width`` wide
    (libjpeg scales in the DCT: at 4K half the decode time of a full colour decode and no full-size copy);
    the features are then found on the same working copy as before and scaled back to full resolution."""
    width, height = image_size(kf.image_path)
    factor = max((f for f in _REDUCED_GREY if work_width <= 0 or width / f >= work_width), default=1)
    grey = read_image(kf.image_path, _REDUCED_GREY[factor], "keyframe image")
    if factor > 1 and grey.shape != (-(-height // factor), -(-width // factor)):  # not a JPEG: resized otherwise
        factor, grey = 1, read_image(kf.image_path, cv2.IMREAD_GRAYSCALE, "keyframe image")
    mask = load_mask(kf, (width, height))
    if factor > 1:
        mask = cv2.resize(mask, (grey.shape[1], grey.shape[0]), interpolation=cv2.INTER_NEAREST)
    return grey, mask, (width, height)


def image_size(path: Path) -> tuple[int, int]:
    """(width, height) from the file's header, without decoding it."""
    try:
        with Image.open(path) as im:
            return im.size
    except FileNotFoundError as exc:
        raise CompanionError(
            f"cannot read keyframe image {path} ({exc.strerror})", "check that the file is there"
        ) from exc
    except (OSError, ValueError) as exc:
        empty = path.is_file() and path.stat().st_size == 0
        raise CompanionError(
            f"keyframe image {path} is {ZERO_BYTES}" if empty else f"cannot decode keyframe image {path}",
            "the spool must write complete JPEG or PNG files"
        ) from exc


def load_image_and_mask(kf: KeyframeInput) -> tuple[np.ndarray, np.ndarray]:
    """BGR image and a 0/255 ROI mask of the same size (all 255 when the keyframe has no mask)."""
    img = read_image(kf.image_path, cv2.IMREAD_COLOR, "keyframe image")
    return img, load_mask(kf, (img.shape[1], img.shape[0]))


class DecodedMasks:
    """ROI masks this process has decoded, kept as bits (1 MB for a 4K mask), the least recently used dropped past
    ``max_bytes``. Why: every keyframe's mask is read by four stages (features, the wall check, the render plan
    and the render's decodes: 151 reads of 35 masks on the 4K bench), and OpenCV's PNG decoder takes 40 ms of CPU
    for a 4K mask whose file is 16 KB; unpacking the bits takes 2.5 ms. Keyed by the file's path, inode, size and
    modification time, so a mask rewritten (or replaced) is decoded again; thread-safe."""

    def __init__(self, max_bytes: int = 128 << 20):
        self.max_bytes = max_bytes
        self._bits: OrderedDict[tuple, tuple[np.ndarray, tuple[int, int]]] = OrderedDict()
        self._bytes = 0
        self._lock = threading.Lock()

    @staticmethod
    def key(path: Path) -> tuple | None:
        try:
            st = Path(path).stat()
        except OSError:
            return None  # read_image names the problem
        return (str(path), st.st_ino, st.st_size, st.st_mtime_ns)

    def get(self, key: tuple | None, shape: tuple[int, int]) -> np.ndarray | None:
        with self._lock:
            found = self._bits.get(key) if key is not None else None
            if found is None or found[1] != shape:
                return None
            self._bits.move_to_end(key)
        bits = np.unpackbits(found[0], count=shape[0] * shape[1]).reshape(shape)
        return np.negative(bits, out=bits)  # 1 -> 255 (uint8), 0 -> 0

    def put(self, key: tuple | None, mask: np.ndarray) -> None:
        if key is None:
            return
        bits = np.packbits(mask > 0)
        with self._lock:
            if key in self._bits:
                return
            self._bits[key] = (bits, mask.shape)
            self._bytes += bits.nbytes
            while self._bytes > self.max_bytes and self._bits:
                self._bytes -= self._bits.popitem(last=False)[1][0].nbytes


DECODED_MASKS = DecodedMasks()


def load_mask(kf: KeyframeInput, size: tuple[int, int]) -> np.ndarray:
    """The keyframe's 0/255 ROI mask, checked to be ``size`` (width, height); all 255 when it has none. A mask
    read before in this process comes from :data:`DECODED_MASKS` (the same pixels, no PNG decode)."""
    width, height = size
    if kf.mask_path is None:
        return np.full((height, width), 255, np.uint8)
    key = DECODED_MASKS.key(kf.mask_path)
    known = DECODED_MASKS.get(key, (height, width))
    if known is not None:
        return known
    mask = read_image(kf.mask_path, cv2.IMREAD_GRAYSCALE, "mask")
    if mask.shape != (height, width):
        raise CompanionError(
            f"mask {kf.mask_path} is {mask.shape[1]}x{mask.shape[0]} but its image is {width}x{height}",
            "write the mask at the full frame resolution",
        )
    mask = cv2.threshold(mask, 127, 255, cv2.THRESH_BINARY)[1]  # 0/255, as fast as a copy
    DECODED_MASKS.put(key, mask)
    return mask


def detect(
    image: np.ndarray,
    mask: np.ndarray,
    features: FeatureConfig = STITCH_FEATURES,
    *,
    full_size: tuple[int, int] | None = None,
) -> Features:
    """SIFT on a working-resolution copy (``features.long_side_px``); keypoints are returned in full-resolution
    pixels. ``full_size``: ``image`` is itself a reduced copy (``load_working_copy``) of a keyframe of this
    (width, height).

    Extraction is the keyframe gate's (:class:`companion.keyframes.FeatureExtractor`) with the stitcher's
    :data:`~companion.stitch.config.STITCH_FEATURES`: the gate's plain-wall settings (CLAHE, contrast threshold
    0.01) on a larger copy. ``replace(STITCH_FEATURES, equalize=False, contrast_threshold=0.04)`` is plain SIFT."""
    fs = FeatureExtractor(features).extract(image, mask)
    w, h = full_size or fs.full_size
    to_work = fs.scale * fs.full_size[0] / w  # working px per full-resolution px
    if fs.descriptors is None or len(fs) == 0:
        return Features(np.zeros((0, 2), np.float32), np.zeros((0, 128), np.float32), (w, h), np.zeros(0, np.float32))
    pts = fs.points
    # the local grey level for gain compensation, from the working copy before CLAHE (CLAHE changes levels)
    smooth = cv2.GaussianBlur(fs.work_gray, (0, 0), 4.0)
    xi = np.clip(np.round(pts[:, 0]).astype(int), 0, smooth.shape[1] - 1)
    yi = np.clip(np.round(pts[:, 1]).astype(int), 0, smooth.shape[0] - 1)
    lum = smooth[yi, xi].astype(np.float32)
    return Features(pts / to_work, fs.descriptors.astype(np.float32), (w, h), lum)


FEATURE_SETTINGS = {"v": 4}  # bump "v" when detect() changes, so cached features are recomputed


def feature_key(kf: KeyframeInput, settings: dict) -> str:
    parts = [str(kf.image_path), str(kf.mask_path), json.dumps(settings, sort_keys=True)]
    for p in (kf.image_path, kf.mask_path):
        if p is not None:
            st = Path(p).stat()
            parts.append(f"{st.st_size}:{st.st_mtime_ns}")
    return hashlib.sha1("|".join(parts).encode()).hexdigest()[:16]


def detect_settings(features: FeatureConfig) -> dict:
    """What the features depend on besides the files (the cache key): every extraction setting."""
    return FEATURE_SETTINGS | asdict(features)


def cached_features(kf: KeyframeInput, cache_dir: Path, features: FeatureConfig = STITCH_FEATURES) -> Features:
    """Features from the on-disk cache when the image, mask and settings are unchanged (resumable runs)."""
    key = feature_key(kf, detect_settings(features))
    path = cache_dir / f"kf{kf.index:06d}-{key}.npz"
    if path.exists():
        try:
            z = np.load(path)
            return Features(z["kp"], z["desc"], (int(z["size"][0]), int(z["size"][1])), z["lum"])
        except (OSError, ValueError, KeyError):
            path.unlink(missing_ok=True)  # torn write from an interrupted run: recompute
    grey, mask, full_size = load_working_copy(kf, features.long_side_px)
    feats = detect(grey, mask, features, full_size=full_size)
    cache_dir.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        np.savez(tmp, kp=feats.keypoints, desc=feats.descriptors, size=np.array(feats.image_size), lum=feats.luminance)
    return feats


@dataclass(frozen=True)
class KeyframeFeatures:
    """The features stage's output: the usable keyframes (``input.keyframes``; damaged ones moved to
    ``input.skipped``), their features and cache keys, position for position."""

    input: StitchInput
    features: tuple[Features, ...]
    keys: tuple[str, ...]


def find_features(inp: StitchInput, cfg: StitchConfig, cache_dir: Path, *, progress: bool) -> KeyframeFeatures:
    """Features inside the ROI of every keyframe; a keyframe whose files are damaged, or whose size is not the
    camera's, is left out and named (not fatal). No usable keyframe at all is an error naming the first reasons."""
    settings = detect_settings(cfg.features)
    feats, keys, usable, skipped = [], [], [], list(inp.skipped)

    def extract(kf: KeyframeInput) -> Features | str:
        try:
            return cached_features(kf, cache_dir, cfg.features)
        except CompanionError as exc:
            return exc.problem
        except OSError as exc:
            return f"cannot read its files ({exc})"

    # one keyframe per thread: decoding and SIFT run in OpenCV without the GIL, so the cores work side by side
    with ThreadPoolExecutor(worker_count(cfg)) as pool:
        found = pool.map(extract, inp.keyframes)
        for kf, f in progress_bar(
            zip(inp.keyframes, found, strict=True),
            total=len(inp.keyframes),
            desc="features",
            disable=not progress,
            leave=False,
            unit="it",
        ):
            if isinstance(f, str):
                skipped.append(SkippedKeyframe(kf.index, f))
                continue
            size_problem = _size_problem(f, inp)
            if size_problem:
                skipped.append(SkippedKeyframe(kf.index, size_problem))
                continue
            feats.append(f)
            keys.append(feature_key(kf, settings))
            usable.append(kf)
    for sk in skipped:
        log.warning("%s", sk.warning())
    if not usable:
        reasons = "; ".join(sk.warning() for sk in skipped[:3]) + ("; ..." if len(skipped) > 3 else "")
        raise CompanionError(
            f"no usable keyframe is left: {reasons}",
            "check the spool's frames/ directory (complete JPEG/PNG files, masks of the image size)",
        )
    return KeyframeFeatures(replace(inp, keyframes=usable, skipped=tuple(skipped)), tuple(feats), tuple(keys))


def _size_problem(f: Features, inp: StitchInput) -> str:
    W, H = inp.camera.width, inp.camera.height
    if f.image_size == (W, H):
        return ""
    return (
        f"image is {f.image_size[0]}x{f.image_size[1]}, the camera's are {W}x{H} "
        "(all keyframes of one stitch come from one camera mode)"
    )

"""Masks for anyone's photos: ``<image stem>_mask.png`` beside nothing else, in OpenDroneMap's naming.

OpenDroneMap (and Metashape's mask import with the ``{filename}_mask`` template) read an 8-bit single-channel
PNG per photo: 255 where the photo may be used, 0 where it must be ignored. Ours is the depth mask: 255 = the
near facade, 0 = background; a photo with no near surface gets an all-zero mask (nothing of it is used) rather
than no file, so the tools never fall back to using the whole photo.

Without ``--sequence`` each photo has only the network and itself: its mask gets the single-photo rule
(companion/depth/single_photo.py; default: far patches that do not reach the frame's top are wall).

Images are read with OpenCV's default EXIF orientation handling, as OpenSfM reads them, so each mask lines up
with the photo as those tools see it. One unreadable photo does not stop the others: every readable photo gets
its mask, then the unreadable ones are reported together.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from companion.errors import CompanionError
from companion.files import NewOutput, write_atomic
from companion.image_files import read_image_file

_Masks = Iterator[tuple[int, np.ndarray | None, bool, bool]]  # (index, mask or None, no near surface, parallax)
# (photo path, decoded image shape) -> where the photo can show the wall (uint8 0/255), or None: no bound
Bound = Callable[[Path, tuple[int, ...]], "np.ndarray | None"]
IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".tif", ".tiff")


@dataclass(frozen=True)
class PhotoMask:
    """What was written for one photo."""

    image: Path
    mask_path: Path
    roi_fraction: float  # share of the photo kept as facade (0 for a photo with no near surface)
    no_near_surface: bool  # the masker found only far background: the mask is all zero
    by_parallax: bool = False  # --sequence: parallax confirmed or corrected the network's mask
    bounded: bool = False  # --mission: the wall's projection from the photo's pose cut what cannot be wall


def mask_name(image: Path) -> str:
    """OpenDroneMap's mask file name for a photo: ``DJI_0001.JPG`` -> ``DJI_0001_mask.png``."""
    return f"{Path(image).stem}_mask.png"


def expand_images(paths: Iterable[str | Path]) -> list[Path]:
    """Files as given, folders expanded to their image files (sorted); a path that does not exist is an error."""
    out: list[Path] = []
    for p in map(Path, paths):
        if p.is_dir():
            out += sorted(f for f in p.iterdir() if f.is_file() and f.suffix.lower() in IMAGE_SUFFIXES)
        elif p.exists():
            out.append(p)
        else:
            raise CompanionError(f"{p} does not exist", "pass existing photo files or folders of photos")
    if not out:
        raise CompanionError("no photos to mask", f"pass image files ({', '.join(IMAGE_SUFFIXES)}) or folders of them")
    return out


def _write_png(path: Path, mask: np.ndarray) -> None:
    """Write via a temporary name and rename, so a mask file is either complete or absent."""
    ok, buf = cv2.imencode(".png", mask)
    if not ok:  # pragma: no cover - PNG encoding of a uint8 image does not fail
        raise CompanionError(f"could not encode {path}", "report this as a bug")
    write_atomic(path, buf.tobytes())


class _PhotoReader:
    """Reads photos through the shared decode path (companion/image_files.py), so a JPEG cut short is refused
    (not masked, never a --sequence parallax neighbour) and remembers why each unreadable one was."""

    def __init__(self) -> None:
        self.problems: dict[Path, str] = {}

    def __call__(self, path: Path) -> np.ndarray | None:
        read = read_image_file(path, cv2.IMREAD_COLOR)
        if not read.ok:
            self.problems[path] = read.problem or "unreadable"
        return read.image


def _checked_out_dir(out_dir: str | Path, paths: list[Path]) -> Path:
    """``out_dir``, refused when it is a file or when two photos would get the same mask name."""
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise CompanionError(f"--out {out} is a file", "give a folder for the masks (it is created if missing)")
    seen: dict[str, Path] = {}
    for p in paths:
        other = seen.setdefault(mask_name(p), p)
        if other != p:
            raise CompanionError(f"{other} and {p} would both get the mask {mask_name(p)}",
                                 "mask photos with the same name into separate --out folders")
    return out


def _single_photo_masks(paths: list[Path], masker, read: _PhotoReader) -> _Masks:
    """(index, mask or None when unreadable, no near surface, judged by parallax) from the network alone."""
    from companion.records import Frame, TaggedFrame

    for n, path in enumerate(paths):
        image = read(path)
        if image is None:
            yield n, None, False, False
            continue
        _, roi = masker.mask(TaggedFrame(Frame(index=n, capture_time_s=0.0, image=image), pose=None))
        yield n, (roi.mask if not roi.empty else np.zeros(image.shape[:2], np.uint8)), roi.empty, False


def _with_single_rule(masker, rule):
    """The masker with the single-photo rule (companion/depth/single_photo.py); a stand-in masker without a depth
    session (tests) is used as it is."""
    from companion.depth.single_photo import SinglePhotoMasker, single_photo_rule

    if getattr(masker, "session", None) is None:
        return masker
    chosen = single_photo_rule(rule)
    return masker if chosen.name == "network" else SinglePhotoMasker(masker, chosen)


def _sequence_masks(paths: list[Path], masker, read: _PhotoReader, params=None) -> _Masks:
    """The same from the network and the pass's parallax (companion/depth/sequence.py)."""
    from companion.depth.sequence import mask_sequence

    for n, m in mask_sequence(paths, masker, read, params):
        yield (n, None, False, False) if m is None else (n, m.mask, m.no_near_surface, m.parallax)


def _bounded(mask: np.ndarray, no_near_surface: bool, path: Path, bound: Bound | None) -> tuple[np.ndarray, bool, bool]:
    """The mask cut to the photo's wall bound (companion/depth/wall_bound.py); (mask, no near surface, bounded)."""
    from companion.depth.wall_bound import apply_bound

    cut = bound(path, mask.shape) if bound is not None else None
    if cut is None:
        return mask, no_near_surface, False
    mask = apply_bound(mask, cut)
    return mask, no_near_surface or not mask.any(), True


def mask_photos(images: Iterable[str | Path], out_dir: str | Path, masker=None,
                on_mask: Callable[[PhotoMask], None] | None = None, *, sequence: bool = False,
                bound: Bound | None = None, sequence_params=None, single_rule=None) -> list[PhotoMask]:
    """Mask each photo with the depth masker (default: the shipped model) and write ``<stem>_mask.png``.

    ``sequence``: the photos are one pass along the wall in capture order; the motion parallax between
    neighbouring photos confirms or corrects each network mask and drops photos of only far background
    (companion/depth/sequence.py; docs/DEPTH.md says what it changes).

    ``bound``: where each photo can show the wall (``companion.depth.photo_pose.photo_bound`` with a mission):
    everything outside it is cut from the mask; a photo it gives no bound keeps its mask. ``sequence_params``: the
    parallax rules of ``sequence`` (``companion.depth.parallax.ParallaxParams``; default: the shipped ones).

    ``single_rule``: without ``sequence``, how each photo's network mask is post-processed
    (``companion.depth.single_photo.SINGLE_PHOTO_RULES`` name or rule; None: its ``DEFAULT_RULE``;
    "network": the network's mask as the onboard chain makes it).

    Raises CompanionError before writing anything when two photos would get the same mask name or ``out_dir``
    is a file, and after writing every readable photo's mask when some photos could not be read.
    """
    from companion.depth.masker import Masker

    paths = expand_images(images)
    out = _checked_out_dir(out_dir, paths)
    output = NewOutput(out)
    out.mkdir(parents=True, exist_ok=True)
    masker = masker or Masker()
    if not sequence:
        masker = _with_single_rule(masker, single_rule)
    reader = _PhotoReader()
    masks = _sequence_masks(paths, masker, reader, sequence_params) if sequence else \
        _single_photo_masks(paths, masker, reader)
    results: list[PhotoMask] = []
    unreadable: list[Path] = []
    for n, mask, no_near_surface, by_parallax in masks:
        if mask is None:
            unreadable.append(paths[n])
            continue
        mask, no_near_surface, bounded = _bounded(mask, no_near_surface, paths[n], bound)
        target = out / mask_name(paths[n])
        _write_png(target, mask)
        share = 0.0 if no_near_surface else float(np.count_nonzero(mask)) / mask.size
        result = PhotoMask(paths[n], target, share, no_near_surface, by_parallax, bounded)
        results.append(result)
        if on_mask is not None:
            on_mask(result)
    if unreadable:
        names = "; ".join(f"{p}: {reader.problems.get(p, 'unreadable')}" for p in unreadable)
        written = f"the masks of the other {len(results)} photos were written to {out}"
        if not results:  # nothing written: no empty folder left behind to be taken for a result
            output.remove_created()
            written = "no mask was written"
        raise CompanionError(
            f"{len(unreadable)} of {len(paths)} photos could not be read as images: {names}",
            f"check that they are complete JPEG/PNG/TIFF files and rerun on them; {written}",
        )
    return results

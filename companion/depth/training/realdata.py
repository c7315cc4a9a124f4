"""The real photographs of the project's shared data folder: where they are in it, their facade/background truth,
and the fixed split. The folder is always given by the caller (``companion depth train --real-photos``, or
``evaluation.shared_data`` for the benches and tests): a checkout keeps it in ../shared/data, an install has no
such place.

One module owns the split so that training and every figure agree on it: a photo that training may see is never
one a figure is reported on. The split is a pure function of the file name (SHA-1 of the stem), so it does not
move when photos are added or when the folder is read in another order.

* ``train``: labelled CMP and LabelMeFacade facades and LabelMeFacade backgrounds whose hash falls outside the
  held-out fifth.
* ``heldout``: the other fifth, plus every photo without labels that is only fit for testing: the Strecha
  fountain-P11 / entry-P10 views and the two DJI drone photos (``real-uav-facade``).

Licences: CMP, LabelMeFacade and Strecha are research / non-commercial (``real-facades/ATTRIBUTION.md``); the
DJI photos are BSD-3-Clause. ``RealPhoto.permissive`` says which is which, so a model trained only on permissive
data can be built and named as such.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import cv2
import numpy as np

from companion.errors import CompanionError

Split = Literal["train", "heldout"]
Kind = Literal["facade", "background"]

HELDOUT_MODULUS = 5  # one photo in five is held out

# LabelMeFacade RGB label colours that belong to the facade (building, window, door); everything else is background.
_LABELME_FACADE_RGB = ((128, 0, 0), (0, 0, 128), (128, 128, 0))
_CMP_BACKGROUND_INDEX = 1  # CMP class 1 = background; 2..12 are facade parts (wall, window, door, balcony, ...)
_CMP_WINDOW_INDEX = 3  # cmp/label_names.txt: "3 window"
_LABELME_WINDOW_RGB = (0, 0, 128)


@dataclass(frozen=True)
class RealPhoto:
    """One real photograph and, where the data set has one, its per-pixel label file."""

    image: Path
    label: Path | None
    source: str  # 'cmp', 'labelmefacade', 'labelmefacade-bg', 'strecha', 'dji'
    kind: Kind
    permissive: bool

    @property
    def split(self) -> Split:
        return split_of(self.image)


def split_of(path: Path) -> Split:
    """'heldout' for unlabelled test-only sets and for one stem in ``HELDOUT_MODULUS`` by hash, else 'train'."""
    parts = set(Path(path).parts)
    if "real-uav-facade" in parts or any(p.startswith("strecha_") for p in parts):
        return "heldout"
    digest = hashlib.sha1(Path(path).stem.encode()).digest()
    return "heldout" if digest[0] % HELDOUT_MODULUS == 0 else "train"


def list_real_photos(root: Path, split: Split | None = None) -> list[RealPhoto]:
    """Every real photo under the shared data folder ``root``, optionally only one split, in a stable order."""
    root = Path(root)
    facades = root / "real-facades"
    if not facades.is_dir():
        raise CompanionError(f"real photo folder {facades} not found",
                             "give the shared data folder that holds real-facades/ (../shared/data beside a checkout)")
    photos: list[RealPhoto] = []
    for img in sorted((facades / "facades" / "cmp" / "images").glob("*.jpg")):
        photos.append(RealPhoto(img, facades / "facades" / "cmp" / "labels" / f"{img.stem}.png", "cmp", "facade",
                                False))
    for sub, source, kind in (("facades", "labelmefacade", "facade"),
                              ("backgrounds", "labelmefacade-bg", "background")):
        folder = facades / sub / "labelmefacade"
        for img in sorted((folder / "images").glob("*.jpg")):
            photos.append(RealPhoto(img, folder / "labels" / f"{img.stem}.png", source, kind, False))
    for img in sorted((facades / "facades").glob("strecha_*/images/*.jpg")):
        photos.append(RealPhoto(img, None, "strecha", "facade", False))
    for img in sorted((root / "real-uav-facade").glob("*.JPG")):
        photos.append(RealPhoto(img, None, "dji", "facade", True))
    if split is not None:
        photos = [p for p in photos if p.split == split]
    return photos


def load_image(photo: RealPhoto) -> np.ndarray:
    """The photo as BGR uint8; a photo that does not decode is an error naming the file."""
    image = cv2.imread(str(photo.image), cv2.IMREAD_COLOR)
    if image is None:
        raise CompanionError(f"cannot decode {photo.image}", "restore the file from the shared data set")
    return image


def facade_mask(photo: RealPhoto) -> np.ndarray | None:
    """uint8 mask, 255 = facade (wall, windows, doors, balconies, ...), 0 = background; None without labels.

    CMP labels are palette PNGs whose pixel value is the class index (read with PIL: OpenCV would turn the palette
    into colours); LabelMeFacade labels are RGB colours.
    """
    if photo.label is None:
        return None
    if photo.source == "cmp":
        from PIL import Image

        with Image.open(photo.label) as im:
            index = np.array(im)
        return np.where(index != _CMP_BACKGROUND_INDEX, 255, 0).astype(np.uint8)
    bgr = cv2.imread(str(photo.label), cv2.IMREAD_COLOR)
    if bgr is None:
        raise CompanionError(f"cannot decode label {photo.label}", "restore the file from the shared data set")
    rgb = bgr[..., ::-1]
    keep = np.zeros(rgb.shape[:2], dtype=bool)
    for colour in _LABELME_FACADE_RGB:
        keep |= np.all(rgb == np.array(colour, dtype=np.uint8), axis=-1)
    return np.where(keep, 255, 0).astype(np.uint8)


def window_mask(photo: RealPhoto) -> np.ndarray | None:
    """uint8 mask, 255 = window glass (CMP class 3, LabelMeFacade window colour 0:0:128); None without labels.

    The composites use it to let a window reflect the background (``composite.CompositeOptions``): real windows
    mirror trees and sky, and a model that learned "trees and sky = far" cuts them out of the wall.
    """
    if photo.label is None:
        return None
    if photo.source == "cmp":
        from PIL import Image

        with Image.open(photo.label) as im:
            index = np.array(im)
        return np.where(index == _CMP_WINDOW_INDEX, 255, 0).astype(np.uint8)
    bgr = cv2.imread(str(photo.label), cv2.IMREAD_COLOR)
    if bgr is None:
        raise CompanionError(f"cannot decode label {photo.label}", "restore the file from the shared data set")
    keep = np.all(bgr[..., ::-1] == np.array(_LABELME_WINDOW_RGB, dtype=np.uint8), axis=-1)
    return np.where(keep, 255, 0).astype(np.uint8)

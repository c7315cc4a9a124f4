"""One way to read an image file, shared by every reader of users' and spooled images (the image-folder camera of
``companion cull``, ``companion mask``, the stitcher).

Why one path: a JPEG cut short (a torn write, a card pulled, a copy interrupted) still *decodes* in OpenCV: libjpeg
prints "Premature end of JPEG file" without a file name and fills the missing rows with grey. Such a frame (94 %
grey, say) passed ``companion cull`` as a good frame and became the parallax reference of the next ones. The
stitcher already refused it by the end-of-image marker; now every reader checks the same way, before decoding (so
libjpeg has nothing to warn about), and says which file and why.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

JPEG_SOI = b"\xff\xd8"  # start of image: the file is a JPEG
JPEG_SOS = b"\xff\xda"  # start of scan: entropy-coded data follows
JPEG_EOI = b"\xff\xd9"  # end of image: a complete JPEG has one after its last scan

TRUNCATED = "truncated (the JPEG ends before its end-of-image marker)"
UNDECODABLE = "not a readable image (OpenCV cannot decode it)"
EMPTY = "empty (every pixel is black, or the image is a few pixels in size)"
ZERO_BYTES = "an empty file (0 bytes: a write that never happened)"


@dataclass(frozen=True)
class ImageRead:
    """An image file read: ``image`` when it is usable, else None and ``problem`` says why (one of the constants
    above, or the OS's reason it could not be read)."""

    path: Path
    image: np.ndarray | None
    problem: str | None = None

    @property
    def ok(self) -> bool:
        return self.image is not None

    def describe(self) -> str:
        """``NAME: problem`` for warnings and reports (the file name only: the folder is said once around it)."""
        return f"{self.path.name}: {self.problem}"


def jpeg_truncated(data: bytes) -> bool:
    """True for JPEG bytes without an end-of-image marker after their last scan (False for anything not a JPEG)."""
    if data[:2] != JPEG_SOI:
        return False
    last_scan = data.rfind(JPEG_SOS)
    return last_scan < 0 or data.find(JPEG_EOI, last_scan) < 0


def read_image_file(path: str | Path, flags: int = cv2.IMREAD_COLOR, *, reject_blank: bool = False) -> ImageRead:
    """Read and decode ``path`` (OpenCV ``flags``), checking a JPEG's end-of-image marker first.

    ``reject_blank``: an all-black or tiny image counts as unusable too (a camera's dropped frame); the stitcher's
    masks are legitimately all zero, so it is off by default."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        return ImageRead(path, None, f"cannot be read ({exc.strerror or exc})")
    if not data:  # OpenCV asserts on an empty buffer rather than returning None
        return ImageRead(path, None, ZERO_BYTES)
    if jpeg_truncated(data):
        return ImageRead(path, None, TRUNCATED)
    try:
        image = cv2.imdecode(np.frombuffer(data, np.uint8), flags)
    except cv2.error:
        image = None
    if image is None:
        return ImageRead(path, None, UNDECODABLE)
    if reject_blank and (min(image.shape[:2]) <= 8 or not image.any()):
        return ImageRead(path, None, EMPTY)
    return ImageRead(path, image)

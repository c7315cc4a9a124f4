"""Look at what the mask does on image files (e.g. real photos): one picture per image, frame | disparity | masked
frame, and the ROI's figures. The network runs once per image; the ROI is cut from that same disparity."""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from companion.depth.masker import Masker
from companion.depth.roi import RoiResult
from companion.depth.visual import save_visual
from companion.errors import CompanionError


@dataclass(frozen=True)
class InspectedImage:
    image: Path
    picture: Path  # frame | disparity | masked frame
    roi: RoiResult
    disparity_p5_p50_p95: tuple[float, float, float]


def inspect_images(images: Iterable[str | Path], out_dir: Path, masker: Masker) -> Iterator[InspectedImage]:
    """Mask each image file and write its picture to ``out_dir/<stem>.jpg``; yields as each one is done."""
    for name in images:
        image = cv2.imread(str(name), cv2.IMREAD_COLOR)
        if image is None:
            raise CompanionError(f"cannot read image {name}", "pass JPEG/PNG files")
        disparity = masker.session.disparity(image)
        roi = masker.roi_from_disparity(disparity, image.shape[:2])
        picture = Path(out_dir) / f"{Path(name).stem}.jpg"
        save_visual(picture, image, disparity, roi.mask, None)
        p5, p50, p95 = (float(v) for v in np.percentile(disparity, [5, 50, 95]))
        yield InspectedImage(Path(name), picture, roi, (p5, p50, p95))

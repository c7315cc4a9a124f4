"""The chain decides on a working copy of each frame; only the keyframes it spools get their full-resolution pixels.

Why: tracker, depth mask and SIFT each shrank the frame on their own (a 320 px grey copy, the network's input, a
960 px SIFT copy that OpenCV doubles inside), so their cost grew with the camera: at 1280x720 a SIFT extraction
took 224 ms of CPU against 121 ms on a 640 px copy (docs/BENCHMARKS.md, issue 17), and the judged 30 fps demo
skipped nine frames in ten. The overlap the gate decides on (paper Eq. 2) is a ratio of the image size, so it is
the same on a copy: the frame is resized once, to ``long_side_px`` (640 by default: on 480 pairs of a synthetic
1280x720 wall with 70-90 % true overlap, R on a 640 px copy and on the old 960 px SIFT copy differ by at most 0.01
points and put every pair on the same side of Rth as truth, at half the CPU, bench/chain_working_size.py; on
simulator frames even a 480 px copy kept the same keyframes, docs/BENCHMARKS.md), and tracker, masker and gate all
work on that copy. The full-resolution frame is kept only while it may still become a keyframe (held for a
decision, or the gate's candidate); a keyframe goes to the spool with its full-resolution image, its ROI mask
scaled up to it, and its displacements in full-resolution pixels.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace

import cv2
import numpy as np

from companion.errors import CompanionError
from companion.records import EncodedFrame, Frame, Keyframe

log = logging.getLogger(__name__)
# libjpeg's DCT scaling: the decoder itself delivers 1/2, 1/4 or 1/8 of the size, skipping most of the inverse DCT
_REDUCED_COLOR = {2: cv2.IMREAD_REDUCED_COLOR_2, 4: cv2.IMREAD_REDUCED_COLOR_4, 8: cv2.IMREAD_REDUCED_COLOR_8}


def decode_full(frame: EncodedFrame) -> Frame | None:
    """The frame at the camera's resolution (None: the data is not an image)."""
    image = cv2.imdecode(np.frombuffer(frame.data, np.uint8), cv2.IMREAD_COLOR)
    if image is None or image.ndim != 3:
        return None
    return Frame(frame.index, frame.capture_time_s, image)


@dataclass(frozen=True)
class WorkingCopy:
    """``long_side_px``: the working copy's long side; frames not larger are used as they are. <= 0: no copy."""

    long_side_px: int = 640

    def __post_init__(self) -> None:
        if 0 < self.long_side_px < 160:
            raise CompanionError(f"working copy long side {self.long_side_px} px is too small to measure overlap",
                                 "use 480-960 px (default 640), or 0 to decide on full-resolution frames")

    def scale_for(self, width: int, height: int) -> float:
        """Working px per full-resolution px (<= 1)."""
        long_side = max(width, height)
        if self.long_side_px <= 0 or long_side <= self.long_side_px:
            return 1.0
        return self.long_side_px / long_side

    def of(self, frame: Frame | EncodedFrame) -> Frame | None:
        """The frame the chain decides on: the same record when no copy is needed, else a resized copy (None: an
        encoded frame whose data is not an image)."""
        if isinstance(frame, EncodedFrame):
            return self._decode(frame)
        h, w = frame.image.shape[:2]
        s = self.scale_for(w, h)
        if s == 1.0:
            return frame
        return Frame(frame.index, frame.capture_time_s, self._shrink(frame.image, self._size(w, h, s)))

    @staticmethod
    def _size(width: int, height: int, scale: float) -> tuple[int, int]:
        return max(1, round(width * scale)), max(1, round(height * scale))

    @staticmethod
    def _shrink(image: np.ndarray, size: tuple[int, int]) -> np.ndarray:
        if (image.shape[1], image.shape[0]) == size:
            return image
        return cv2.resize(image, size, interpolation=cv2.INTER_AREA)

    def _decode(self, frame: EncodedFrame) -> Frame | None:
        """Decode straight to (about) the working size: the largest DCT reduction whose output is still at least the
        working copy, then an area resize for the rest. A 1280x720 JPEG to its 640 px copy costs half of a full
        decode plus resize, and differs from it by 0.2 grey levels on average (docs/BENCHMARKS.md)."""
        s = self.scale_for(frame.width, frame.height)
        if s == 1.0:
            full = decode_full(frame)
            if full is not None and full.image.shape[:2] != (frame.height, frame.width):
                log.warning("frame %d is %dx%d, not the %dx%d the camera declared", frame.index,
                            full.image.shape[1], full.image.shape[0], frame.width, frame.height)
            return full
        size = self._size(frame.width, frame.height, s)
        factor = max((f for f in _REDUCED_COLOR if frame.width / f >= size[0] and frame.height / f >= size[1]),
                     default=1)
        flag = _REDUCED_COLOR.get(factor, cv2.IMREAD_COLOR)
        image = cv2.imdecode(np.frombuffer(frame.data, np.uint8), flag)
        if image is None or image.ndim != 3:
            return None
        return Frame(frame.index, frame.capture_time_s, self._shrink(image, size))


class FullResolution:
    """Full-resolution frames by index, kept while the chain may still spool them; ``restore`` gives a keyframe
    decided on a working copy its full-resolution image, mask and pixel displacements."""

    def __init__(self) -> None:
        self._frames: dict[int, Frame] = {}

    def __len__(self) -> int:
        return len(self._frames)

    def keep(self, full: Frame | EncodedFrame, working: Frame) -> None:
        """Hold the camera's frame as it came: an encoded frame stays encoded until it is spooled (unless its
        working copy is already the full image)."""
        if isinstance(full, EncodedFrame) and working.image.shape[:2] == (full.height, full.width):
            full = working
        if full is not working:
            self._frames[full.index] = full

    def release_below(self, index: int | None) -> None:
        """Forget every frame older than ``index`` (None: all): none of them can become a keyframe any more."""
        self._frames = {} if index is None else {i: f for i, f in self._frames.items() if i >= index}

    def restore(self, kf: Keyframe) -> Keyframe:
        full = self._frames.get(kf.index)
        if isinstance(full, EncodedFrame):
            decoded = decode_full(full)
            if decoded is None:  # its working copy decoded, so this is not expected; spool what we have
                log.warning("keyframe %d: the full-resolution image does not decode; spooled at the working size",
                            kf.index)
                return kf
            full = decoded
        if full is None or full is kf.frame:
            return kf
        fh, fw = full.image.shape[:2]
        wh, ww = kf.image.shape[:2]
        up = fw / ww
        smooth = cv2.resize(kf.mask, (fw, fh), interpolation=cv2.INTER_LINEAR)
        mask = cv2.threshold(smooth, 127, 255, cv2.THRESH_BINARY)[1]
        d = kf.decision

        def px(value: float | None) -> float | None:
            return None if value is None else value * up

        decision = replace(d, dx_px=px(d.dx_px), dy_px=px(d.dy_px), prediction_miss_px=px(d.prediction_miss_px))
        return replace(kf, frame=full, mask=mask, decision=decision)

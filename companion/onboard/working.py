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

from dataclasses import dataclass, replace

import cv2

from companion.errors import CompanionError
from companion.records import Frame, Keyframe


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

    def of(self, frame: Frame) -> Frame:
        """The frame the chain decides on: the same record when no copy is needed, else a resized copy."""
        h, w = frame.image.shape[:2]
        s = self.scale_for(w, h)
        if s == 1.0:
            return frame
        size = (max(1, round(w * s)), max(1, round(h * s)))
        return Frame(frame.index, frame.capture_time_s, cv2.resize(frame.image, size, interpolation=cv2.INTER_AREA))


class FullResolution:
    """Full-resolution frames by index, kept while the chain may still spool them; ``restore`` gives a keyframe
    decided on a working copy its full-resolution image, mask and pixel displacements."""

    def __init__(self) -> None:
        self._frames: dict[int, Frame] = {}

    def __len__(self) -> int:
        return len(self._frames)

    def keep(self, full: Frame, working: Frame) -> None:
        if full is not working:
            self._frames[full.index] = full

    def release_below(self, index: int | None) -> None:
        """Forget every frame older than ``index`` (None: all): none of them can become a keyframe any more."""
        self._frames = {} if index is None else {i: f for i, f in self._frames.items() if i >= index}

    def restore(self, kf: Keyframe) -> Keyframe:
        full = self._frames.get(kf.index)
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

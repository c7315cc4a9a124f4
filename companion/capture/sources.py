"""Frame sources behind one interface: video files, V4L2 devices, RTSP/HTTP streams, image folders.

(The simulator's live camera client lives in ``simcam.py``; it yields frames still JPEG-encoded, ``EncodedFrame``.)
Every frame carries its capture time in seconds; corrupt or missing frames are skipped and counted, never fatal.
"""

from __future__ import annotations

import abc
import logging
import math
import re
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from companion.errors import CompanionError
from companion.image_files import read_image_file
from companion.records import EncodedFrame, Frame

log = logging.getLogger(__name__)
IMAGE_SUFFIXES = {".jpg", ".jpeg", ".png", ".tif", ".tiff", ".bmp"}


@dataclass
class SourceStats:
    delivered: int = 0
    corrupt: int = 0
    corrupt_files: list[str] = field(default_factory=list)  # "NAME: why" per corrupt file (image folders name them)
    stalls: int = 0
    notes: list[str] = field(default_factory=list)  # things the user should hear about (warnings)
    ended: str | None = None  # set when a recording reached its own end (not a camera that stopped delivering)


class FrameSource(abc.ABC):
    """Iterate to get frames; ``stats`` counts what was skipped. Use as a context manager.

    ``recorded`` sources (video files, image folders) hold frames taken earlier, with capture times on the clock
    they were recorded with; live sources (devices, streams, the simulator camera) deliver frames as they are taken.
    """

    name = "source"
    recorded = False

    def __init__(self) -> None:
        self.stats = SourceStats()

    @abc.abstractmethod
    def __iter__(self) -> Iterator[Frame | EncodedFrame]: ...

    def time_span(self) -> tuple[float, float] | None:
        """First and last capture time of a recorded source (None when unknown or live)."""
        return None

    def close(self) -> None:  # noqa: B027 - optional hook
        pass

    def __enter__(self) -> FrameSource:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _usable(image: np.ndarray | None) -> bool:
    return image is not None and image.ndim == 3 and image.shape[0] > 8 and image.shape[1] > 8 and image.any()


class VideoSource(FrameSource):
    """OpenCV VideoCapture (FFmpeg / V4L2 backends) for files, devices and network streams.

    Capture time: for files, ``start_time_s`` + the container's timestamp of the frame; for live devices and
    streams, the companion's clock (``time.time()``) when the frame was grabbed. A live source that delivers
    nothing for ``stall_timeout_s`` logs a warning ("camera stopped delivering") and keeps waiting, up to
    ``give_up_s`` in total.
    """

    def __init__(
        self,
        target: str | int,
        *,
        live: bool,
        backend: int = cv2.CAP_ANY,
        start_time_s: float = 0.0,
        stall_timeout_s: float = 2.0,
        give_up_s: float = 30.0,
    ):
        super().__init__()
        self.target = target
        self.live = live
        self.start_time_s = start_time_s
        self.stall_timeout_s = stall_timeout_s
        self.give_up_s = give_up_s
        self.name = str(target)
        self.recorded = not live
        self.cap = cv2.VideoCapture(target, backend)
        if not self.cap.isOpened():
            raise CompanionError(
                f"cannot open camera/video {target!r}",
                "check the path, device (/dev/videoN) or stream URL, and that FFmpeg can read it",
            )
        self.fps = self.cap.get(cv2.CAP_PROP_FPS) or 0.0

    def time_span(self) -> tuple[float, float] | None:
        count = self.cap.get(cv2.CAP_PROP_FRAME_COUNT) if self.recorded else 0
        if count <= 0 or self.fps <= 0:
            return None
        return self.start_time_s, self.start_time_s + (count - 1) / self.fps

    def __iter__(self) -> Iterator[Frame]:
        index = 0
        last_ok = time.monotonic()
        consecutive_failures = 0
        while True:
            ok = self.cap.grab()
            grabbed_at = time.time()
            image = self.cap.retrieve()[1] if ok else None
            if not ok or not _usable(image):
                if not self.live:
                    # A file: a failed grab past the last frame is the end; one in the middle is a corrupt frame.
                    consecutive_failures += 1
                    frame_count = self.cap.get(cv2.CAP_PROP_FRAME_COUNT)
                    pos = self.cap.get(cv2.CAP_PROP_POS_FRAMES)
                    if not ok and (consecutive_failures > 25 or (frame_count > 0 and pos >= frame_count)):
                        self.stats.ended = f"video {self.name} ended after {self.stats.delivered} frames"
                        return
                    self.stats.corrupt += 1
                    index += 1
                    continue
                self.stats.corrupt += int(ok)
                stalled = time.monotonic() - last_ok
                if stalled > self.give_up_s:
                    raise CompanionError(
                        f"camera {self.name} delivered no frame for {stalled:.0f} s", "check the camera cable/stream"
                    )
                if stalled > self.stall_timeout_s * (self.stats.stalls + 1):
                    self.stats.stalls += 1
                    log.warning("camera %s stopped delivering frames (%.1f s without one)", self.name, stalled)
                time.sleep(0.01)
                continue
            consecutive_failures = 0
            last_ok = time.monotonic()
            if self.live:
                t = grabbed_at
            else:
                t = self.start_time_s + self.cap.get(cv2.CAP_PROP_POS_MSEC) / 1000.0
            self.stats.delivered += 1
            yield Frame(index=index, capture_time_s=t, image=image)
            index += 1

    def close(self) -> None:
        self.cap.release()


class ImageFolderSource(FrameSource):
    """Images in name order. Capture times from ``times.csv`` (``name,seconds`` per line, an optional header
    line), which must then list every image: a folder half on one clock and half on ``index / fps`` would tag
    frames with poses from the wrong moment. Without ``times.csv``: ``start_time_s + index / fps``."""

    recorded = True

    def __init__(self, folder: Path, fps: float = 30.0, start_time_s: float = 0.0):
        super().__init__()
        self.folder = Path(folder)
        self.name = str(folder)
        self.files = sorted(p for p in self.folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
        if not self.files:
            raise CompanionError(f"no images in {folder}", f"put {', '.join(sorted(IMAGE_SUFFIXES))} files there")
        if fps <= 0:
            raise CompanionError(f"frame rate {fps} is not positive", "give the image folder's frame rate, e.g. 30")
        self.fps = fps
        self.start_time_s = start_time_s
        csv = self.folder / "times.csv"
        self.times: dict[str, float] = _read_times_csv(csv) if csv.exists() else {}
        if self.times:
            missing = [p.name for p in self.files if p.name not in self.times]
            if missing:
                raise CompanionError(
                    f"{csv} gives no time for {len(missing)} of {len(self.files)} images (first: {missing[0]})",
                    "add a line 'name,seconds' for every image, or remove times.csv to use index / fps",
                )

    def time_of(self, index: int, path: Path) -> float:
        return self.times[path.name] if self.times else self.start_time_s + index / self.fps

    def time_span(self) -> tuple[float, float]:
        times = [self.time_of(i, p) for i, p in enumerate(self.files)]
        return min(times), max(times)

    def __iter__(self) -> Iterator[Frame]:
        for index, path in enumerate(self.files):
            # the shared decode path: a JPEG cut short is refused here, never culled (nor a parallax reference)
            read = read_image_file(path, cv2.IMREAD_COLOR, reject_blank=True)
            if not read.ok:
                self.stats.corrupt += 1
                self.stats.corrupt_files.append(read.describe())
                log.warning("skipping corrupt image %s in %s", read.describe(), self.folder)
                continue
            self.stats.delivered += 1
            yield Frame(index=index, capture_time_s=self.time_of(index, path), image=read.image)
        self.stats.ended = f"image folder {self.name} ended after {self.stats.delivered} frames"


def _read_times_csv(path: Path) -> dict[str, float]:
    """``name,seconds`` lines; a first line that is not a number is a header. Anything else unreadable is an error
    (a frame silently left without its time would be tagged from another clock)."""
    times: dict[str, float] = {}
    for number, line in enumerate(path.read_text().splitlines(), start=1):
        if not line.strip():
            continue
        name, _, value = (part.strip() for part in line.partition(","))
        try:
            t = float(value)
        except ValueError:
            if number == 1:
                continue  # header
            t = math.nan
        if not name or not math.isfinite(t):
            raise CompanionError(f"{path} line {number} is not 'name,seconds': {line.strip()!r}",
                                 "write one 'image name,capture time in seconds' per line")
        times[name] = t
    return times


def open_source(spec: str, *, start_time_s: float = 0.0, fps: float = 30.0) -> FrameSource:
    """Pick a source from a user's --capture argument.

    ``sim://HOST:PORT`` simulator camera; ``/dev/videoN`` or ``v4l2:N`` a V4L2 device; ``rtsp://``, ``http(s)://``,
    ``udp://`` a stream; a directory an image folder; any other path a video file.
    """
    if spec.startswith("sim://"):
        from companion.capture.simcam import DEFAULT_PORT, SimCameraSource

        host, _, port = spec[len("sim://") :].partition(":")
        # A camera silent for 10 s has stopped: the iteration ends (counted as a stall) and the caller warns.
        return SimCameraSource(host or "127.0.0.1", int(port or DEFAULT_PORT), idle_timeout_s=10.0)
    m = re.fullmatch(r"(?:v4l2:)?(?:/dev/video)?(\d+)", spec)
    if m and (spec.startswith(("v4l2:", "/dev/video"))):
        return VideoSource(int(m.group(1)), live=True, backend=cv2.CAP_V4L2)
    if re.match(r"^(rtsp|rtsps|http|https|udp|tcp)://", spec):
        return VideoSource(spec, live=True, backend=cv2.CAP_FFMPEG)
    path = Path(spec)
    if path.is_dir():
        return ImageFolderSource(path, fps=fps, start_time_s=start_time_s)
    if not path.exists():
        raise CompanionError(
            f"capture source {spec!r} does not exist",
            "give a video file, an image folder, /dev/videoN, rtsp://... or sim://HOST:PORT",
        )
    return VideoSource(str(path), live=False, backend=cv2.CAP_FFMPEG, start_time_s=start_time_s)

"""Frame sources behind one interface: video files, V4L2 devices, RTSP/HTTP streams, image folders.

(The simulator's live camera client lives in ``simcam.py`` and yields the same ``Frame`` records.)
Every frame carries its capture time in seconds; corrupt or missing frames are skipped and counted, never fatal.
"""

from __future__ import annotations

import abc
import logging
import re
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from companion.errors import CompanionError
from companion.records import Frame

log = logging.getLogger(__name__)
IMAGE_SUFFIXES = {".jpg", ".jpeg", ".png", ".tif", ".tiff", ".bmp"}


@dataclass
class SourceStats:
    delivered: int = 0
    corrupt: int = 0
    stalls: int = 0
    notes: list[str] = field(default_factory=list)


class FrameSource(abc.ABC):
    """Iterate to get frames; ``stats`` counts what was skipped. Use as a context manager."""

    name = "source"

    def __init__(self) -> None:
        self.stats = SourceStats()

    @abc.abstractmethod
    def __iter__(self) -> Iterator[Frame]: ...

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
        self.cap = cv2.VideoCapture(target, backend)
        if not self.cap.isOpened():
            raise CompanionError(
                f"cannot open camera/video {target!r}",
                "check the path, device (/dev/videoN) or stream URL, and that FFmpeg can read it",
            )
        self.fps = self.cap.get(cv2.CAP_PROP_FPS) or 0.0

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
    """Images in name order. Capture time from ``times.csv`` (name,seconds) if present, else index / fps."""

    def __init__(self, folder: Path, fps: float = 30.0, start_time_s: float = 0.0):
        super().__init__()
        self.folder = Path(folder)
        self.name = str(folder)
        self.files = sorted(p for p in self.folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
        if not self.files:
            raise CompanionError(f"no images in {folder}", f"put {', '.join(sorted(IMAGE_SUFFIXES))} files there")
        self.times: dict[str, float] = {}
        csv = self.folder / "times.csv"
        if csv.exists():
            for line in csv.read_text().splitlines():
                parts = line.strip().split(",")
                if len(parts) == 2 and parts[1].replace(".", "", 1).replace("-", "", 1).isdigit():
                    self.times[parts[0]] = float(parts[1])
        self.fps = fps
        self.start_time_s = start_time_s

    def __iter__(self) -> Iterator[Frame]:
        for index, path in enumerate(self.files):
            image = cv2.imread(str(path), cv2.IMREAD_COLOR)
            if not _usable(image):
                self.stats.corrupt += 1
                log.warning("skipping unreadable image %s", path.name)
                continue
            t = self.times.get(path.name, self.start_time_s + index / self.fps)
            self.stats.delivered += 1
            yield Frame(index=index, capture_time_s=t, image=image)


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

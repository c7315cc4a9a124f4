"""Client for the simulator's live camera (``python -m sim camera``): a frame source like any other camera.

Wire format (TCP, one message per frame): 4-byte big-endian length N, N bytes of UTF-8 JSON header, then
``header["size"]`` bytes of JPEG. The header carries ``index`` (camera frame number) and ``capture_time_s``
(seconds on the vehicle's clock, the clock MAVLink timestamps use), plus ``width``, ``height``, ``encoding``.
The companion gets only what a real camera gives: pixels and a capture time, never the simulator's truth.
"""

from __future__ import annotations

import json
import logging
import socket
import struct
import time
from collections.abc import Iterator

import cv2
import numpy as np

from companion.capture.sources import FrameSource
from companion.errors import CompanionError
from companion.records import EncodedFrame, Frame

log = logging.getLogger(__name__)
DEFAULT_PORT = 14670
_LEN = struct.Struct(">I")
MAX_HEADER = 64 * 1024
MAX_PAYLOAD = 64 * 1024 * 1024


def encode_message(header: dict, payload: bytes) -> bytes:
    """One frame message (used by the simulator's camera server)."""
    h = json.dumps(dict(header, size=len(payload))).encode("utf-8")
    return _LEN.pack(len(h)) + h + payload


def _recv_exact(sock: socket.socket, n: int) -> bytes | None:
    buf = bytearray()
    while len(buf) < n:
        chunk = sock.recv(n - len(buf))
        if not chunk:
            return None
        buf.extend(chunk)
    return bytes(buf)


def read_message(sock: socket.socket) -> tuple[dict, bytes] | None:
    """Next (header, payload) from the stream; None when the server closed the connection."""
    raw = _recv_exact(sock, _LEN.size)
    if raw is None:
        return None
    (n,) = _LEN.unpack(raw)
    if not 0 < n <= MAX_HEADER:
        raise CompanionError(f"simulated camera stream is corrupt (header length {n})",
                             "check that the port belongs to `python -m sim camera`")
    hb = _recv_exact(sock, n)
    if hb is None:
        return None
    try:
        header = json.loads(hb)
        size = int(header["size"])
    except (ValueError, KeyError, TypeError) as exc:
        raise CompanionError(f"simulated camera sent a bad header: {exc}",
                             "check that the port belongs to `python -m sim camera`") from exc
    if not 0 <= size <= MAX_PAYLOAD:
        raise CompanionError(f"simulated camera frame size {size} is out of range", "restart the camera")
    payload = _recv_exact(sock, size)
    if payload is None:
        return None
    return header, payload


class SimCameraSource(FrameSource):
    """Connects to the simulated camera's TCP stream and yields the frames as they arrive: :class:`EncodedFrame`
    records (JPEG as sent, decoded by the chain only when it takes them), or decoded :class:`Frame` records when a
    header does not declare the size.

    Empty frames, and undeclared ones that do not decode, are skipped and counted (``stats.corrupt``; the chain
    counts declared ones that do not decode); the iteration ends when the camera closes the stream or, with
    ``idle_timeout_s``, when no frame arrived for that long (counted in ``stats.stalls``).
    Until the first frame the wait is ``first_frame_timeout_s`` (when longer): the camera builds its scene textures
    before it renders, which takes a loaded companion computer well over the idle timeout.
    """

    name = "simcam"

    def __init__(self, host: str = "127.0.0.1", port: int = DEFAULT_PORT, *, connect_timeout_s: float = 5.0,
                 idle_timeout_s: float | None = None, first_frame_timeout_s: float = 60.0):
        super().__init__()
        self.host, self.port = host, port
        self.idle_timeout_s = idle_timeout_s
        first = None if idle_timeout_s is None else max(idle_timeout_s, first_frame_timeout_s)
        deadline = time.monotonic() + connect_timeout_s
        last: OSError | None = None
        self.sock: socket.socket | None = None
        while time.monotonic() < deadline:
            try:
                self.sock = socket.create_connection((host, port), timeout=max(0.1, connect_timeout_s))
                break
            except OSError as exc:
                last = exc
                time.sleep(0.1)
        if self.sock is None:
            raise CompanionError(
                f"cannot connect to the simulated camera at {host}:{port} ({last})",
                "start it first: python -m sim camera MISSION.yaml --stream-port PORT (and the vehicle)",
            )
        self.sock.settimeout(first)

    def __iter__(self) -> Iterator[Frame | EncodedFrame]:
        while self.sock is not None:
            try:
                msg = read_message(self.sock)
            except TimeoutError:
                self.stats.stalls += 1
                waited = self.sock.gettimeout() if self.sock is not None else self.idle_timeout_s
                self.stats.notes.append(f"no frame for {waited} s")
                return
            except OSError as exc:
                log.warning("simulated camera connection lost: %s", exc)
                return
            if msg is None:
                return
            header, payload = msg
            frame = self._frame(header, payload)
            if frame is None:
                self.stats.corrupt += 1
                continue
            if self.stats.delivered == 0 and self.sock is not None:
                self.sock.settimeout(self.idle_timeout_s)  # warmed up: from now on a silence this long is a stall
            self.stats.delivered += 1
            yield frame

    @staticmethod
    def _frame(header: dict, payload: bytes) -> Frame | EncodedFrame | None:
        """The frame as it came: still encoded when the header declares its size (the chain decodes it at its working
        size, ``companion.onboard.working``), else decoded here; None when it is not an image."""
        index, capture_time_s = int(header["index"]), float(header["capture_time_s"])
        width, height = header.get("width"), header.get("height")
        if not payload:
            return None
        if isinstance(width, int) and isinstance(height, int) and width > 0 and height > 0:
            return EncodedFrame(index, capture_time_s, payload, width, height)
        image = cv2.imdecode(np.frombuffer(payload, np.uint8), cv2.IMREAD_COLOR)
        if image is None or image.ndim != 3:
            return None
        return Frame(index=index, capture_time_s=capture_time_s, image=image)

    def close(self) -> None:
        if self.sock is not None:
            self.sock.close()
            self.sock = None

"""The companion as a MAVLink camera (camera protocol v2), so a ground station sees keyframes arrive as photos.

Sends HEARTBEAT as MAV_TYPE_CAMERA, answers CAMERA_INFORMATION requests (MAV_CMD_REQUEST_MESSAGE or the older
MAV_CMD_REQUEST_CAMERA_INFORMATION), publishes CAMERA_IMAGE_CAPTURED for every keyframe and re-sends any of them
on request (MAV_CMD_REQUEST_MESSAGE 263 with param2 = image index), and reports CAMERA_CAPTURE_STATUS.
On a vehicle it is one more endpoint behind mavlink-router; in SITL it talks UDP to the ground station port.
"""

from __future__ import annotations

import logging
import math
import os
import threading
import time
from dataclasses import dataclass

from pymavlink import mavutil

from companion.attitude import euler_to_quat
from companion.records import Pose

log = logging.getLogger(__name__)
# The camera protocol needs MAVLink 2 messages and fields (pymavlink defaults to MAVLink 1).
os.environ["MAVLINK20"] = "1"
mavutil.set_dialect("common")
mav = mavutil.mavlink

MSG_CAMERA_INFORMATION = 259
MSG_CAMERA_IMAGE_CAPTURED = 263
MSG_CAMERA_CAPTURE_STATUS = 262


@dataclass(frozen=True)
class CameraDescription:
    vendor: str = "companion"
    model: str = "facade-scan"
    width_px: int = 3840
    height_px: int = 2160
    hfov_deg: float = 69.0
    sensor_width_mm: float = 13.2


@dataclass(frozen=True)
class CapturedImage:
    index: int
    time_boot_ms: int
    time_utc_us: int
    pose: Pose | None
    file_url: str


class MavlinkCamera:
    def __init__(
        self,
        url: str,
        camera: CameraDescription,
        *,
        system_id: int = 1,
        component_id: int = mav.MAV_COMP_ID_CAMERA,
        heartbeat_s: float = 1.0,
    ):
        self.camera = camera
        self.conn = mavutil.mavlink_connection(url, source_system=system_id, source_component=component_id)
        self.conn.mav.srcSystem = system_id
        self.conn.mav.srcComponent = component_id
        self.heartbeat_s = heartbeat_s
        self.images: list[CapturedImage] = []
        self._boot = time.monotonic()
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="mavlink-camera", daemon=True)

    def start(self) -> MavlinkCamera:
        self._thread.start()
        return self

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2)
        self.conn.close()

    def _ms(self) -> int:
        return int((time.monotonic() - self._boot) * 1000)

    def _loop(self) -> None:
        next_hb = 0.0
        while not self._stop.is_set():
            now = time.monotonic()
            if now >= next_hb:
                self._send(
                    lambda m: m.heartbeat_send(
                        mav.MAV_TYPE_CAMERA, mav.MAV_AUTOPILOT_INVALID, 0, 0, mav.MAV_STATE_ACTIVE
                    )
                )
                next_hb = now + self.heartbeat_s
            try:
                msg = self.conn.recv_match(type="COMMAND_LONG", blocking=True, timeout=0.1)
            except (OSError, ConnectionError):
                msg = None
            if msg is not None and msg.target_component in (0, self.conn.mav.srcComponent):
                self._on_command(msg)

    def _send(self, fn) -> None:
        with self._lock:
            try:
                fn(self.conn.mav)
            except OSError as exc:  # no ground station listening yet: not an error for the flight
                log.debug("camera protocol send failed: %s", exc)

    def _ack(self, msg, result: int) -> None:
        self._send(lambda m: m.command_ack_send(msg.command, result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent()))

    def _on_command(self, msg) -> None:
        cmd = msg.command
        if cmd == mav.MAV_CMD_REQUEST_CAMERA_INFORMATION or (
            cmd == mav.MAV_CMD_REQUEST_MESSAGE and int(msg.param1) == MSG_CAMERA_INFORMATION
        ):
            self._ack(msg, mav.MAV_RESULT_ACCEPTED)
            self.send_information()
        elif cmd == mav.MAV_CMD_REQUEST_MESSAGE and int(msg.param1) == MSG_CAMERA_IMAGE_CAPTURED:
            index = int(msg.param2)
            with self._lock:
                found = next((im for im in self.images if im.index == index), None)
            self._ack(msg, mav.MAV_RESULT_ACCEPTED if found else mav.MAV_RESULT_FAILED)
            if found:
                self._send_captured(found)
        elif cmd == mav.MAV_CMD_REQUEST_MESSAGE and int(msg.param1) == MSG_CAMERA_CAPTURE_STATUS:
            self._ack(msg, mav.MAV_RESULT_ACCEPTED)
            self._send(lambda m: m.camera_capture_status_send(self._ms(), 0, 0, 0.0, 0, float("nan"), len(self.images)))
        elif cmd in (mav.MAV_CMD_REQUEST_MESSAGE,):
            self._ack(msg, mav.MAV_RESULT_UNSUPPORTED)

    def send_information(self) -> None:
        c = self.camera
        focal_mm = (c.sensor_width_mm / 2.0) / math.tan(math.radians(c.hfov_deg) / 2.0)
        sensor_h = c.sensor_width_mm * c.height_px / c.width_px
        flags = mav.CAMERA_CAP_FLAGS_CAPTURE_IMAGE
        self._send(
            lambda m: m.camera_information_send(
                self._ms(),
                c.vendor.encode()[:32].ljust(32, b"\0"),
                c.model.encode()[:32].ljust(32, b"\0"),
                1,
                focal_mm,
                c.sensor_width_mm,
                sensor_h,
                c.width_px,
                c.height_px,
                0,
                flags,
                0,
                b"",
            )
        )

    def publish(self, pose: Pose | None, file_url: str, time_utc_s: float | None = None) -> CapturedImage:
        """Announce a new keyframe; returns its record (index counts from 0)."""
        with self._lock:
            image = CapturedImage(
                index=len(self.images),
                time_boot_ms=self._ms(),
                time_utc_us=int((time_utc_s if time_utc_s is not None else time.time()) * 1e6),
                pose=pose,
                file_url=file_url,
            )
            self.images.append(image)
        self._send_captured(image)
        return image

    def _send_captured(self, im: CapturedImage) -> None:
        p = im.pose
        if p is not None:
            yaw, pitch, roll = p.camera_angles()
            q = [float(v) for v in euler_to_quat(yaw_deg=yaw, pitch_deg=pitch, roll_deg=roll)]
            lat, lon = int(p.lat * 1e7), int(p.lon * 1e7)
            alt, rel = int(p.alt_amsl_m * 1000), int(p.relative_alt_m * 1000)
        else:
            q, lat, lon, alt, rel = [1.0, 0.0, 0.0, 0.0], 0, 0, 0, 0
        url = im.file_url.encode()[:205]
        self._send(
            lambda m: m.camera_image_captured_send(
                im.time_boot_ms, im.time_utc_us, 1, lat, lon, alt, rel, q, im.index, 1, url
            )
        )

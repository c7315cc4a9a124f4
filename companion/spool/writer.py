"""Durable keyframe spool: the hand-off from the onboard gate to the stitching worker.

Layout (read by companion/stitch/inputs.py; format in docs/STITCH.md):
  spool.json              camera, facade and standoff (written once, atomically)
  kf_NNNNNN.jpg           full-resolution keyframe, EXIF GPS/time + XMP orientation
  kf_NNNNNN_mask.png      ROI mask (OpenDroneMap's <image>_mask.png naming)
  kf_NNNNNN.json          sidecar: telemetry, overlap, inliers, frame index, model and thresholds
  manifest.jsonl          one line per keyframe, appended + fsynced only after its files are durable
  CLOSED                  written when the flight (or offline cull) is over

A keyframe is "reported" once its manifest line is on disk; a crash at any moment loses none of those and never
leaves a half-written file under a final name (files are written to a temp name, fsynced, then renamed).
Reopening the same directory resumes: a torn last manifest line is cut off and frames already spooled are skipped.
"""

from __future__ import annotations

import datetime as dt
import errno
import json
import logging
import os
from dataclasses import dataclass, replace
from pathlib import Path

import cv2

from companion.errors import CompanionError
from companion.records import Keyframe, Pose
from companion.spool.camera import CameraTags
from companion.spool.clock import CaptureClock, UnixCaptureClock
from companion.spool.exif import encode_tagged_jpeg

log = logging.getLogger(__name__)
MANIFEST = "manifest.jsonl"
META = "spool.json"
CLOSED = "CLOSED"  # the flight is over: a following stitcher finishes (docs/STITCH.md)


class SpoolFullError(CompanionError):
    """The disk is full: keyframes can no longer be saved (flight supervision must carry on regardless)."""


@dataclass(frozen=True)
class SpoolEntry:
    index: int  # frame index in the capture stream
    image: str
    mask: str
    sidecar: str


def _fsync_dir(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _write_atomic(path: Path, data: bytes) -> None:
    tmp = path.with_name(f".{path.name}.tmp")
    try:
        with open(tmp, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def pose_dict(pose: Pose | None) -> dict | None:
    if pose is None:
        return None
    return {
        "time_s": pose.time_s,
        "lat": pose.lat,
        "lon": pose.lon,
        "alt_amsl_m": pose.alt_amsl_m,
        "relative_alt_m": pose.relative_alt_m,
        "roll_deg": pose.roll_deg,
        "pitch_deg": pose.pitch_deg,
        "yaw_deg": pose.yaw_deg,
        "velocity_ned_m_s": list(pose.velocity_ned_m_s),
        "gimbal_pitch_deg": pose.gimbal_pitch_deg,
        "gimbal_yaw_deg": 0.0,
        "mission_item": pose.mission_item,
    }


class KeyframeSpool:
    """Append-only keyframe store; safe against crashes and restarts."""

    def __init__(
        self,
        directory: Path,
        *,
        meta: dict | None = None,
        settings: dict | None = None,
        camera_tags: CameraTags | None = None,
        capture_clock: CaptureClock | None = None,
    ):
        self.dir = Path(directory)
        self.settings = dict(settings or {})
        self.camera_tags = camera_tags or CameraTags()
        # frame capture time -> Unix time of the exposure (default: capture times are Unix already)
        self.capture_clock = capture_clock or UnixCaptureClock()
        self.untimed = 0  # keyframes saved without a capture time (no wall clock known for them)
        try:
            self.dir.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise CompanionError(
                f"cannot create spool directory {self.dir}: {exc.strerror}", "choose a writable --out"
            ) from None
        # spool.json is written with the first keyframe, when the real image size is known (a camera may deliver
        # a working resolution smaller than the mission's sensor size; the lens, hfov, is the same).
        self._meta = dict(meta) if meta is not None else None
        (self.dir / CLOSED).unlink(missing_ok=True)  # reopened (a resumed flight): more keyframes may come
        self.entries: list[SpoolEntry] = self._recover()
        self._spooled = {e.index for e in self.entries}

    def _recover(self) -> list[SpoolEntry]:
        path = self.dir / MANIFEST
        if not path.exists():
            return []
        raw = path.read_bytes()
        cut = raw.rfind(b"\n") + 1
        if cut < len(raw):  # a torn line from a crash mid-append: not reported, so drop it
            log.warning("spool %s: dropping a torn last manifest line (%d bytes)", self.dir, len(raw) - cut)
            with open(path, "r+b") as fh:
                fh.truncate(cut)
                os.fsync(fh.fileno())
        entries = []
        for line in raw[:cut].decode("utf-8").splitlines():
            if line.strip():
                rec = json.loads(line)
                entries.append(SpoolEntry(int(rec["index"]), rec["image"], rec["mask"], rec["sidecar"]))
        for stale in self.dir.glob(".*.tmp"):
            stale.unlink(missing_ok=True)
        return entries

    def close(self) -> None:
        """Mark the spool complete (``CLOSED``) so a stitcher in follow mode makes its final map."""
        _write_atomic(self.dir / CLOSED, b"")
        _fsync_dir(self.dir)

    def _check_camera_size(self, width: int, height: int) -> None:
        """A camera delivering another aspect ratio than its model (a crop) keeps spooling, without a focal: the
        flight must not stop for it, and a wrong focal in the images would mislead every photogrammetry tool."""
        intr = self.camera_tags.intrinsics
        if intr is None:
            return
        try:
            intr.scaled_to(width, height)
        except CompanionError as exc:
            log.warning("spool %s: %s; %s. The keyframes are saved without a focal length.", self.dir, exc.problem,
                        exc.fix)
            self.camera_tags = replace(self.camera_tags, intrinsics=None)

    def _write_meta(self, width: int, height: int) -> None:
        if self._meta is None or (self.dir / META).exists():
            return
        meta = dict(self._meta)
        if "camera" in meta:
            camera = {**meta["camera"], "width_px": int(width), "height_px": int(height)}
            tags = self.camera_tags
            if tags.intrinsics is not None:  # the lens at the delivered size (the stitcher reads K)
                camera.update(tags.intrinsics.scaled_to(int(width), int(height)).as_dict())
            named = {"make": tags.make, "model": tags.model, "sensor_width_mm": tags.sensor_width_mm}
            camera.update({k: v for k, v in named.items() if v is not None})
            meta["camera"] = camera
        _write_atomic(self.dir / META, json.dumps(meta, indent=1).encode())

    def __len__(self) -> int:
        return len(self.entries)

    def append(self, keyframe: Keyframe) -> SpoolEntry | None:
        """Make ``keyframe`` durable; returns its entry, or None if this frame was already spooled (resume)."""
        tagged = keyframe.masked.tagged
        frame = tagged.frame
        if frame.index in self._spooled:
            return None
        stem = f"kf_{frame.index:06d}"
        entry = SpoolEntry(frame.index, f"{stem}.jpg", f"{stem}_mask.png", f"{stem}.json")
        pose = tagged.pose
        capture_unix = self.capture_clock.unix_time(frame.capture_time_s)
        capture_utc = None if capture_unix is None else dt.datetime.fromtimestamp(capture_unix, tz=dt.UTC)
        if capture_utc is None:
            self.untimed += 1
            if self.untimed == 1:
                log.warning(
                    "spool %s: keyframe %d has no wall-clock capture time (the telemetry log has no t_wall, or the "
                    "camera clock is not set); its EXIF carries no date", self.dir, frame.index,
                )
        sidecar = {
            "index": frame.index,
            "capture_time_s": frame.capture_time_s,
            "capture_utc": capture_utc.isoformat() if capture_utc is not None else None,
            "pose": pose_dict(pose),
            "pose_stale": tagged.pose_stale,
            "overlap_to_previous": keyframe.overlap_to_previous,
            "inliers": keyframe.inliers,
            "gap_before": keyframe.gap_before,
            "settings": self.settings,
            **keyframe.extra,
        }
        line = {
            "index": frame.index,
            "image": entry.image,
            "mask": entry.mask,
            "sidecar": entry.sidecar,
            "capture_time_s": frame.capture_time_s,
            "pose": pose_dict(pose),
            "overlap_to_previous": keyframe.overlap_to_previous,
            "gap_before": keyframe.gap_before,
            "overlap_suspect": bool(keyframe.extra.get("overlap_suspect", False)),
        }
        try:
            self._check_camera_size(frame.image.shape[1], frame.image.shape[0])
            self._write_meta(frame.image.shape[1], frame.image.shape[0])
            jpeg = encode_tagged_jpeg(frame.image, pose, capture_utc, self.camera_tags)
            ok, mask_png = cv2.imencode(".png", keyframe.masked.mask)
            if not ok:
                raise ValueError("mask PNG encoding failed")
            _write_atomic(self.dir / entry.image, jpeg)
            _write_atomic(self.dir / entry.mask, mask_png.tobytes())
            _write_atomic(self.dir / entry.sidecar, json.dumps(sidecar, indent=1).encode())
            _fsync_dir(self.dir)
            with open(self.dir / MANIFEST, "ab") as fh:
                fh.write((json.dumps(line) + "\n").encode())
                fh.flush()
                os.fsync(fh.fileno())
        except OSError as exc:
            if exc.errno in (errno.ENOSPC, errno.EDQUOT):
                raise SpoolFullError(
                    f"disk full while saving keyframe {frame.index} to {self.dir}",
                    "free space on the companion's disk; keyframes already in manifest.jsonl are safe",
                ) from None
            raise CompanionError(
                f"cannot save keyframe {frame.index} in {self.dir}: {exc.strerror}", "check the disk"
            ) from None
        self.entries.append(entry)
        self._spooled.add(frame.index)
        return entry

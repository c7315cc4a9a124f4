"""Durable keyframe spool: the hand-off from the onboard gate to the stitching worker.

Layout and file names: ``companion/spool/layout.py``; the reader beside this writer: ``reader.py``; the format:
docs/STITCH.md. A keyframe is "reported" once its manifest line is on disk; a crash at any moment loses none of
those and never leaves a half-written file under a final name (files are written to a temp name, fsynced, then
renamed). Reopening the same directory resumes: a torn last manifest line is cut off and frames already spooled
are skipped.
"""

from __future__ import annotations

import datetime as dt
import errno
import json
import logging
import os
from dataclasses import replace
from pathlib import Path

import cv2

from companion.errors import CompanionError
from companion.files import TEMP_GLOB, append_durable, write_atomic
from companion.records import Keyframe, standoff_json
from companion.spool.camera import CameraTags
from companion.spool.clock import CaptureClock, UnixCaptureClock
from companion.spool.exif import encode_tagged_jpeg
from companion.spool.layout import CLOSED, MANIFEST, META, SpoolEntry

log = logging.getLogger(__name__)


class SpoolFullError(CompanionError):
    """The disk is full: keyframes can no longer be saved (flight supervision must carry on regardless)."""


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
        for stale in self.dir.glob(TEMP_GLOB):
            stale.unlink(missing_ok=True)
        return entries

    def close(self) -> None:
        """Mark the spool complete (``CLOSED``) so a stitcher in follow mode makes its final map."""
        write_atomic(self.dir / CLOSED, b"", durable=True)

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
        write_atomic(self.dir / META, json.dumps(meta, indent=1), durable=True)

    def __len__(self) -> int:
        return len(self.entries)

    def append(self, keyframe: Keyframe) -> SpoolEntry | None:
        """Make ``keyframe`` durable; returns its entry, or None if this frame was already spooled (resume)."""
        frame = keyframe.frame
        if frame.index in self._spooled:
            return None
        entry = SpoolEntry.for_frame(frame.index)
        pose = keyframe.pose
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
            "pose": None if pose is None else pose.to_json(),
            "pose_stale": keyframe.pose_stale,
            "overlap_to_previous": keyframe.overlap_to_previous,
            "inliers": keyframe.inliers,
            "gap_before": keyframe.gap_before,
            "settings": self.settings,
            **keyframe.decision.as_dict(),
        }
        if keyframe.overlap_suspect:
            sidecar.update(overlap_suspect=True, overlap_telemetry=keyframe.telemetry_overlap_suspect)
        sidecar.update(standoff_json(keyframe.standoff))
        line = {
            "index": frame.index,
            "image": entry.image,
            "mask": entry.mask,
            "sidecar": entry.sidecar,
            "capture_time_s": frame.capture_time_s,
            "pose": sidecar["pose"],
            "overlap_to_previous": keyframe.overlap_to_previous,
            "gap_before": keyframe.gap_before,
            "overlap_suspect": keyframe.overlap_suspect,
            **standoff_json(keyframe.standoff),
        }
        try:
            self._check_camera_size(frame.image.shape[1], frame.image.shape[0])
            self._write_meta(frame.image.shape[1], frame.image.shape[0])
            jpeg = encode_tagged_jpeg(frame.image, pose, capture_utc, self.camera_tags)
            ok, mask_png = cv2.imencode(".png", keyframe.mask)
            if not ok:
                raise ValueError("mask PNG encoding failed")
            write_atomic(self.dir / entry.image, jpeg, durable=True)
            write_atomic(self.dir / entry.mask, mask_png.tobytes(), durable=True)
            write_atomic(self.dir / entry.sidecar, json.dumps(sidecar, indent=1), durable=True)
            append_durable(self.dir / MANIFEST, json.dumps(line))
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

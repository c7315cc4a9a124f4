"""Reads a keyframe spool: the reference reader of the format ``writer.py`` writes (docs/STITCH.md).

Everything downstream (the stitcher, follow mode, evaluations) works on :class:`StitchInput`, never on the files.
Poses are read from their one JSON form (``companion.records.Pose.to_json``) and turned into the camera's
attitude here, gimbal included. Spools the writer wrote before that form (``time_s`` for ``t_boot_s``, no
``gimbal_source``) read the same: only the position, the heading and the gimbal's angles are used.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from companion.attitude import camera_rotation_enu, gimbal_camera_angles
from companion.errors import CompanionError
from companion.geo import FacadeFrame, GeoPoint
from companion.spool.layout import MANIFEST, META


@dataclass(frozen=True)
class CameraModel:
    """Pinhole intrinsics of the full-resolution keyframe images (no distortion: images are undistorted)."""

    K: np.ndarray
    width: int
    height: int

    @classmethod
    def from_hfov(cls, width: int, height: int, hfov_deg: float) -> CameraModel:
        if not (0.0 < hfov_deg < 179.0) or width <= 0 or height <= 0:
            raise CompanionError(
                f"camera model is invalid: {width}x{height} px, hfov {hfov_deg} deg",
                "give width_px/height_px > 0 and 0 < hfov_deg < 179 in spool.json 'camera'",
            )
        f = (width / 2.0) / math.tan(math.radians(hfov_deg) / 2.0)
        K = np.array([[f, 0.0, width / 2.0], [0.0, f, height / 2.0], [0.0, 0.0, 1.0]])
        return cls(K=K, width=int(width), height=int(height))

    @property
    def focal_px(self) -> float:
        return float(self.K[0, 0])


@dataclass(frozen=True)
class FacadeGeometry:
    """The wall being mapped: its facade frame (geo.py convention) and its height."""

    frame: FacadeFrame
    height_m: float


@dataclass(frozen=True)
class CameraPose:
    """Where the camera was and how it was turned: R maps camera axes (x right, y down, z forward) to ENU."""

    lat: float
    lon: float
    alt_amsl_m: float
    R_enu_from_cam: np.ndarray


@dataclass(frozen=True)
class KeyframeInput:
    index: int
    image_path: Path
    mask_path: Path | None  # None: the whole frame is facade (no background removal happened)
    pose: CameraPose | None
    overlap_to_previous: float | None = None


@dataclass(frozen=True)
class SkippedKeyframe:
    """A keyframe left out of the map because a file of it is missing or damaged (an SD card or a crash can do
    that); the map of everything else is still made, and the report names each one."""

    index: int | None  # None when the manifest line itself was unreadable
    reason: str

    def as_dict(self) -> dict:
        return {"index": self.index, "reason": self.reason}

    def warning(self) -> str:
        who = f"keyframe {self.index}" if self.index is not None else "a keyframe"
        return f"{who} skipped: {self.reason}"


@dataclass(frozen=True)
class StitchInput:
    keyframes: list[KeyframeInput]
    camera: CameraModel | None
    facade: FacadeGeometry | None
    standoff_m: float | None
    source: str  # "spool" or "recording"
    skipped: tuple[SkippedKeyframe, ...] = ()  # damaged or missing keyframes, never drawn

    @property
    def has_poses(self) -> bool:
        """Telemetry can place keyframes on the wall only with poses, intrinsics and the wall geometry."""
        return self.camera is not None and self.facade is not None and any(kf.pose is not None for kf in self.keyframes)


# --- poses ----------------------------------------------------------------------------------------------


def camera_attitude(pose: dict) -> tuple[float, float, float]:
    """(roll, pitch, yaw) of the CAMERA from a manifest pose: the camera on its stabilised gimbal, as every pose
    the writer has written describes it (``gimbal_camera_angles``: a null or absent angle is level and forward).
    The vehicle's own roll and pitch do not tilt the camera."""
    gimbal_pitch, gimbal_yaw = (pose.get(k) for k in ("gimbal_pitch_deg", "gimbal_yaw_deg"))
    yaw, pitch, roll = gimbal_camera_angles(
        float(pose["yaw_deg"]),
        None if gimbal_pitch is None else float(gimbal_pitch),
        None if gimbal_yaw is None else float(gimbal_yaw),
    )
    return roll, pitch, yaw


def parse_pose(pose: dict | None, where: str) -> CameraPose | None:
    if pose is None:
        return None
    try:
        roll, pitch, yaw = camera_attitude(pose)
        vals = (float(pose["lat"]), float(pose["lon"]), float(pose["alt_amsl_m"]), roll, pitch, yaw)
    except (KeyError, TypeError, ValueError) as exc:
        raise CompanionError(
            f"{where}: pose is incomplete or not numeric ({exc!r})",
            "a pose needs lat, lon, alt_amsl_m and yaw_deg (and the gimbal's angles, or null), or null",
        ) from exc
    if not all(math.isfinite(v) for v in vals):
        return None  # telemetry was stale / NaN: treat as no pose rather than a wrong prior
    R = camera_rotation_enu(yaw_deg=vals[5], pitch_deg=vals[4], roll_deg=vals[3])
    return CameraPose(vals[0], vals[1], vals[2], R)


# --- spool ------------------------------------------------------------------------------------------------


def read_spool_meta(spool: Path) -> tuple[CameraModel | None, FacadeGeometry | None, float | None]:
    path = spool / META
    if not path.exists():
        return None, None, None
    try:
        meta = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise CompanionError(f"{path} is not valid JSON ({exc})", "rewrite spool.json (see docs/STITCH.md)") from exc
    camera = None
    if meta.get("camera"):
        c = meta["camera"]
        try:
            if c.get("K") is not None:
                camera = CameraModel(
                    np.asarray(c["K"], dtype=float).reshape(3, 3), int(c["width_px"]), int(c["height_px"])
                )
            else:
                camera = CameraModel.from_hfov(int(c["width_px"]), int(c["height_px"]), float(c["hfov_deg"]))
        except (KeyError, TypeError, ValueError) as exc:
            raise CompanionError(
                f"{path}: camera needs width_px, height_px and hfov_deg or K ({exc!r})", "fix spool.json 'camera'"
            ) from exc
    facade = None
    if meta.get("facade"):
        f = meta["facade"]
        try:
            ground = float(f["ground_alt_amsl_m"])
            start = GeoPoint(float(f["start"]["lat"]), float(f["start"]["lon"]), ground)
            end = GeoPoint(float(f["end"]["lat"]), float(f["end"]["lon"]), ground)
            frame = FacadeFrame.from_wall(start, end)
            facade = FacadeGeometry(frame=frame, height_m=float(f["height_m"]))
        except (KeyError, TypeError, ValueError) as exc:
            raise CompanionError(
                f"{path}: facade needs start/end {{lat, lon}}, ground_alt_amsl_m and height_m ({exc!r})",
                "fix spool.json 'facade' (copy it from the mission file)",
            ) from exc
    standoff = meta.get("standoff_m")
    return camera, facade, (float(standoff) if standoff is not None else None)


def load_spool(spool: Path) -> StitchInput:
    manifest = spool / MANIFEST
    if not manifest.exists():
        raise CompanionError(
            f"{spool} has no {MANIFEST}", "point at a keyframe spool directory or a simulator recording"
        )
    camera, facade, standoff = read_spool_meta(spool)
    keyframes: list[KeyframeInput] = []
    skipped: list[SkippedKeyframe] = []
    seen: set[int] = set()
    lines = manifest.read_text(errors="replace").splitlines()
    for lineno, line in enumerate(lines, 1):
        if not line.strip():
            continue
        where = f"{manifest}:{lineno}"
        try:
            rec = json.loads(line)
        except json.JSONDecodeError:
            # a torn last line is what a crash mid-append leaves: stop there, the next run picks it up
            if lineno == len(lines):
                break
            # a damaged line further up (a bad sector): that keyframe is lost, the others are not
            skipped.append(SkippedKeyframe(None, f"{where} is not valid JSON"))
            continue
        try:
            index = int(rec["index"])
            image = spool / rec["image"]
        except (KeyError, TypeError, ValueError) as exc:
            raise CompanionError(f"{where}: needs 'index' and 'image' ({exc!r})", "see docs/STITCH.md") from exc
        if index in seen:
            raise CompanionError(f"{where}: keyframe index {index} appears twice", "give each keyframe a new index")
        seen.add(index)
        mask = spool / rec["mask"] if rec.get("mask") else None
        if not image.is_file():
            skipped.append(SkippedKeyframe(index, f"image {image} is missing"))
            continue
        if mask is not None and not mask.is_file():
            # without its mask the keyframe could draw background: leave it out rather than guess
            skipped.append(SkippedKeyframe(index, f"mask {mask} is missing"))
            continue
        overlap = rec.get("overlap_to_previous")
        keyframes.append(
            KeyframeInput(
                index, image, mask, parse_pose(rec.get("pose"), where), None if overlap is None else float(overlap)
            )
        )
    if camera is None and keyframes:
        if facade is not None:
            raise CompanionError(f"{spool}/{META} has a facade but no camera", f"add 'camera' to {META}")
        # no intrinsics: the sizes still tell the principal point; focal from a nominal 70 degree lens. The size
        # is the most common one of the first few readable images (one damaged keyframe must not decide it).
        sizes = [s for s in (_image_size(kf.image_path) for kf in keyframes[:5]) if s is not None]
        if not sizes:
            raise CompanionError(
                f"none of the first keyframe images of {spool} can be decoded", "write JPEG/PNG keyframes"
            )
        width, height = max(set(sizes), key=sizes.count)
        camera = CameraModel.from_hfov(width, height, 70.0)
    return StitchInput(keyframes, camera, facade, standoff, "spool", tuple(skipped))


def _image_size(path: Path) -> tuple[int, int] | None:
    """(width, height) from the image header only, or None when it cannot be read."""
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as im:
            return im.size
    except (OSError, UnidentifiedImageError):
        return None

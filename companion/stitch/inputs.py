"""Reads the worker's input: a keyframe spool directory (manifest.jsonl) or a simulator recording.

The spool format is written down in docs/STITCH.md; this module is its reference reader. Everything downstream
works on :class:`StitchInput`, never on files.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pymap3d

from companion.errors import CompanionError
from companion.geo import FacadeFrame, GeoPoint
from companion.plugins import provided


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


# --- attitude -> rotation ---------------------------------------------------------------------------------

_R_ENU_FROM_NED = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
# columns: camera x (right) = body y, camera y (down) = body z, camera z (forward) = body x
_R_BODY_FROM_CAM = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])


def rotation_enu_from_cam(roll_deg: float, pitch_deg: float, yaw_deg: float) -> np.ndarray:
    """Camera attitude (aerospace ZYX Euler angles, yaw clockwise from north, pitch up +) -> R_enu_from_cam."""
    r, p, y = (math.radians(v) for v in (roll_deg, pitch_deg, yaw_deg))
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    rz = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    rx = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
    return _R_ENU_FROM_NED @ (rz @ ry @ rx) @ _R_BODY_FROM_CAM


def camera_attitude(pose: dict) -> tuple[float, float, float]:
    """(roll, pitch, yaw) of the CAMERA from a manifest pose.

    Priority: explicit ``camera_roll/pitch/yaw_deg``; else a stabilised gimbal (``gimbal_pitch_deg`` present:
    camera yaw = body yaw + ``gimbal_yaw_deg``, pitch = gimbal pitch, no roll); else a camera fixed to the body.
    """
    if "camera_yaw_deg" in pose:
        return (
            float(pose.get("camera_roll_deg", 0.0)),
            float(pose.get("camera_pitch_deg", 0.0)),
            float(pose["camera_yaw_deg"]),
        )
    if pose.get("gimbal_pitch_deg") is not None:
        return 0.0, float(pose["gimbal_pitch_deg"]), float(pose["yaw_deg"]) + float(pose.get("gimbal_yaw_deg") or 0.0)
    return float(pose.get("roll_deg", 0.0)), float(pose.get("pitch_deg", 0.0)), float(pose["yaw_deg"])


def parse_pose(pose: dict | None, where: str) -> CameraPose | None:
    if pose is None:
        return None
    try:
        roll, pitch, yaw = camera_attitude(pose)
        vals = (float(pose["lat"]), float(pose["lon"]), float(pose["alt_amsl_m"]), roll, pitch, yaw)
    except (KeyError, TypeError, ValueError) as exc:
        raise CompanionError(
            f"{where}: pose is incomplete or not numeric ({exc!r})",
            "a pose needs lat, lon, alt_amsl_m and yaw_deg (plus roll/pitch or gimbal_pitch_deg), or null",
        ) from exc
    if not all(math.isfinite(v) for v in vals):
        return None  # telemetry was stale / NaN: treat as no pose rather than a wrong prior
    return CameraPose(vals[0], vals[1], vals[2], rotation_enu_from_cam(vals[3], vals[4], vals[5]))


# --- spool ------------------------------------------------------------------------------------------------


def _read_spool_meta(spool: Path) -> tuple[CameraModel | None, FacadeGeometry | None, float | None]:
    path = spool / "spool.json"
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
    manifest = spool / "manifest.jsonl"
    if not manifest.exists():
        raise CompanionError(
            f"{spool} has no manifest.jsonl", "point at a keyframe spool directory or a simulator recording"
        )
    camera, facade, standoff = _read_spool_meta(spool)
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
            raise CompanionError(f"{spool}/spool.json has a facade but no camera", "add 'camera' to spool.json")
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


# --- simulator recording ----------------------------------------------------------------------------------


def load_recording_input(
    path: Path,
    *,
    stride: int = 1,
    frames: list[int] | None = None,
    use_poses: bool = True,
    pose_noise_m: float = 0.0,
    attitude_noise_deg: float = 0.0,
    seed: int = 0,
) -> StitchInput:
    """Keyframes straight from a simulator recording (sim.camera.recording), for evaluation.

    ``frames`` picks frame indices (e.g. the gate's choice); otherwise every ``stride``-th frame. The recording's
    poses are exact; ``pose_noise_m``/``attitude_noise_deg`` (Gaussian, seeded) make them telemetry-like.
    """
    rec = provided("open_recording", "stitching a simulator recording")(path)
    if len(rec) == 0:
        raise CompanionError(f"recording {path} has no frames", "record a flight first")
    meta = rec.meta
    camera = CameraModel(np.asarray(rec.K, dtype=float), int(rec.width), int(rec.height))
    frame = rec.frame
    facade = FacadeGeometry(frame, float(meta["facade"]["height_m"]))
    indices = frames if frames is not None else list(range(0, len(rec), max(1, int(stride))))
    rng = np.random.default_rng(seed)
    o = frame.origin
    keyframes = []
    for i in indices:
        pose = None
        if use_poses:
            tp = rec.camera_pose(i)
            enu = np.asarray(tp.position_enu, dtype=float) + rng.normal(0.0, pose_noise_m, 3) * (pose_noise_m > 0)
            lat, lon, alt = pymap3d.enu2geodetic(enu[0], enu[1], enu[2], o.lat, o.lon, o.alt_amsl_m)
            R = np.asarray(tp.R_world_from_cam, dtype=float)
            if attitude_noise_deg > 0:
                ypr = rng.normal(0.0, attitude_noise_deg, 3)
                R = rotation_enu_from_cam(ypr[2], ypr[1], ypr[0]) @ _R_BODY_FROM_CAM.T @ _R_ENU_FROM_NED.T @ R
            pose = CameraPose(float(lat), float(lon), float(alt), R)
        keyframes.append(
            KeyframeInput(i, Path(path) / "frames" / f"{i:06d}.jpg", Path(path) / "masks" / f"{i:06d}.png", pose)
        )
    standoff = meta.get("standoff_m")
    return StitchInput(keyframes, camera, facade, float(standoff) if standoff else None, "recording")


def load_input(path: str | Path, **recording_options) -> StitchInput:
    """A spool (has manifest.jsonl) or a simulator recording (has truth.jsonl + frames/)."""
    p = Path(path)
    if not p.is_dir():
        raise CompanionError(f"{p} is not a directory", "give the keyframe spool directory")
    if (p / "manifest.jsonl").exists():
        return load_spool(p)
    if (p / "truth.jsonl").exists() and (p / "frames").is_dir():
        return load_recording_input(p, **recording_options)
    raise CompanionError(
        f"{p} is neither a keyframe spool (manifest.jsonl) nor a simulator recording (truth.jsonl)",
        "point at the spool directory the keyframe gate writes",
    )

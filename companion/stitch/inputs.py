"""The stitcher's input: a keyframe spool (read by ``companion/spool/reader.py``, the spool's own reader) or a
simulator recording. Everything downstream works on :class:`StitchInput`, never on files.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pymap3d

from companion.attitude import camera_rotation_enu
from companion.errors import CompanionError
from companion.plugins import provided
from companion.spool.layout import MANIFEST
from companion.spool.reader import (
    CameraModel,
    CameraPose,
    FacadeGeometry,
    KeyframeInput,
    SkippedKeyframe,
    StitchInput,
    camera_attitude,
    load_spool,
    parse_pose,
)

__all__ = [
    "CameraModel",
    "CameraPose",
    "FacadeGeometry",
    "KeyframeInput",
    "SkippedKeyframe",
    "StitchInput",
    "camera_attitude",
    "load_input",
    "load_recording_input",
    "load_spool",
    "parse_pose",
]


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
                ypr = rng.normal(0.0, attitude_noise_deg, 3)  # a small rotation about the NED axes, applied in ENU
                noise = camera_rotation_enu(yaw_deg=ypr[0], pitch_deg=ypr[1], roll_deg=ypr[2])
                R = noise @ camera_rotation_enu(yaw_deg=0.0, pitch_deg=0.0, roll_deg=0.0).T @ R
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
    if (p / MANIFEST).exists():
        return load_spool(p)
    if (p / "truth.jsonl").exists() and (p / "frames").is_dir():
        return load_recording_input(p, **recording_options)
    raise CompanionError(
        f"{p} is neither a keyframe spool ({MANIFEST}) nor a simulator recording (truth.jsonl)",
        "point at the spool directory the keyframe gate writes",
    )

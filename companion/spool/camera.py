"""The camera model written into keyframe EXIF and spool.json: pinhole intrinsics, sensor size, make/model.

The intrinsics come from the mission's ``camera`` block (focal from ``hfov_deg``, principal point at the centre,
no distortion) or, when the user has one, from a calibration file (OpenCV camera matrix and distortion). They are
given for one image size and scaled to the size the camera actually delivers (a working resolution smaller than
the sensor's keeps the lens: the focal in pixels scales with the width).

Calibration file (YAML or JSON), either our plain form::

    width_px: 3840
    height_px: 2160
    fx: 2795.1            # pixels
    fy: 2794.6
    cx: 1921.3
    cy: 1079.2
    distortion: [k1, k2, p1, p2, k3]   # OpenCV order; optional

or the file OpenCV's calibration tools write (``image_width``, ``image_height``, ``camera_matrix``,
``distortion_coefficients``, as cv2.FileStorage YAML).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, replace
from pathlib import Path

import cv2
import numpy as np
import yaml

from companion.errors import CompanionError

# Camera makes whose XMP gimbal pitch follows DJI's convention (0 = horizontal, -90 = nadir) in the readers we
# checked: OpenDroneMap adds 90 to drone-dji:GimbalPitchDegree for these makes only (docs/OUTPUTS.md).
DJI_CONVENTION_MAKES = ("dji", "hasselblad")


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics (pixels) for images of ``width_px`` x ``height_px``; distortion in OpenCV order."""

    width_px: int
    height_px: int
    fx: float
    fy: float
    cx: float
    cy: float
    distortion: tuple[float, ...] = ()
    source: str = "hfov"  # "hfov" (from the mission's field of view) or the calibration file's path

    @classmethod
    def from_hfov(cls, width_px: int, height_px: int, hfov_deg: float) -> Intrinsics:
        f = (width_px / 2.0) / math.tan(math.radians(hfov_deg) / 2.0)
        return cls(int(width_px), int(height_px), f, f, width_px / 2.0, height_px / 2.0)

    @property
    def hfov_deg(self) -> float:
        return math.degrees(2.0 * math.atan(self.width_px / 2.0 / self.fx))

    def scaled_to(self, width_px: int, height_px: int) -> Intrinsics:
        """The same lens on an image of another size (same aspect: a scaled sensor readout)."""
        if (width_px, height_px) == (self.width_px, self.height_px):
            return self
        sx, sy = width_px / self.width_px, height_px / self.height_px
        if abs(sx - sy) > 0.01 * sx:
            raise CompanionError(
                f"camera delivers {width_px}x{height_px} px but the camera model is for "
                f"{self.width_px}x{self.height_px} px (another aspect ratio: a crop, not a scaled readout)",
                "calibrate the camera at the resolution it streams, or set the camera's resolution to match",
            )
        return replace(
            self, width_px=int(width_px), height_px=int(height_px), fx=self.fx * sx, fy=self.fy * sy,
            cx=self.cx * sx, cy=self.cy * sy,
        )

    def as_dict(self) -> dict:
        """spool.json form: ``K`` (the stitcher reads it) plus the distortion and where the numbers came from."""
        return {
            "K": [[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]],
            "distortion_opencv": list(self.distortion),
            "intrinsics_source": self.source,
        }


@dataclass(frozen=True)
class CameraTags:
    """What the keyframe JPEGs say about the camera (EXIF Make/Model/focal, XMP orientation convention).

    ``sensor_width_mm`` is the width of the image area on the sensor; None writes the focal as its 35 mm-film
    equivalent (a 36 mm wide image area), which keeps the focal in pixels exact in every reader (docs/OUTPUTS.md).
    """

    make: str | None = None
    model: str | None = None
    intrinsics: Intrinsics | None = None
    sensor_width_mm: float | None = None

    @property
    def dji_gimbal_convention(self) -> bool:
        return (self.make or "").strip().lower() in DJI_CONVENTION_MAKES

    def focal_for(self, width_px: int, height_px: int) -> tuple[float, float, float] | None:
        """(focal length mm, focal-plane pixels per mm along x, along y) for an image of this size."""
        if self.intrinsics is None:
            return None
        k = self.intrinsics.scaled_to(width_px, height_px)
        sensor_w = self.sensor_width_mm or 36.0
        px_per_mm = width_px / sensor_w
        return k.fx / px_per_mm, px_per_mm, px_per_mm * k.fy / k.fx


def load_calibration(path: Path) -> Intrinsics:
    """Intrinsics and distortion from a calibration file (format in the module docstring)."""
    path = Path(path)
    fix = "give width_px, height_px, fx, fy, cx, cy (pixels) and optionally distortion [k1, k2, p1, p2, k3]"
    if not path.is_file():
        raise CompanionError(f"camera calibration file {path} does not exist", "fix camera.calibration in the mission")
    text = path.read_text(encoding="utf-8", errors="replace")
    if "camera_matrix" in text and text.lstrip().startswith("%YAML"):
        return _load_opencv_storage(path)
    try:
        data = json.loads(text) if path.suffix.lower() == ".json" else yaml.safe_load(text)
    except (json.JSONDecodeError, yaml.YAMLError) as exc:
        raise CompanionError(f"camera calibration file {path} cannot be parsed: {exc}", fix) from None
    if not isinstance(data, dict):
        raise CompanionError(f"camera calibration file {path} is not a mapping", fix)
    if "camera_matrix" in data:  # OpenCV's layout written as plain YAML/JSON
        m = data["camera_matrix"]
        k = np.asarray(m["data"] if isinstance(m, dict) else m, dtype=float).reshape(3, 3)
        d = data.get("distortion_coefficients") or []
        d = d["data"] if isinstance(d, dict) else d
        data = {
            "width_px": data.get("image_width"), "height_px": data.get("image_height"),
            "fx": k[0, 0], "fy": k[1, 1], "cx": k[0, 2], "cy": k[1, 2], "distortion": list(np.ravel(d)),
        }
    try:
        intr = Intrinsics(
            width_px=int(data["width_px"]), height_px=int(data["height_px"]),
            fx=float(data["fx"]), fy=float(data["fy"]), cx=float(data["cx"]), cy=float(data["cy"]),
            distortion=tuple(float(v) for v in (data.get("distortion") or ())),
            source=str(path),
        )
    except (KeyError, TypeError, ValueError) as exc:
        raise CompanionError(f"camera calibration file {path}: missing or bad value ({exc!r})", fix) from None
    return _checked(intr, path, fix)


def _load_opencv_storage(path: Path) -> Intrinsics:
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    try:
        k = fs.getNode("camera_matrix").mat()
        d = fs.getNode("distortion_coefficients").mat()
        w, h = fs.getNode("image_width").real(), fs.getNode("image_height").real()
    finally:
        fs.release()
    fix = "write image_width, image_height, camera_matrix and distortion_coefficients (OpenCV calibration output)"
    if k is None or k.shape != (3, 3) or not w or not h:
        raise CompanionError(f"camera calibration file {path} lacks camera_matrix or image size", fix)
    intr = Intrinsics(
        int(w), int(h), float(k[0, 0]), float(k[1, 1]), float(k[0, 2]), float(k[1, 2]),
        tuple(float(v) for v in np.ravel(d)) if d is not None else (), str(path),
    )
    return _checked(intr, path, fix)


def _checked(intr: Intrinsics, path: Path, fix: str) -> Intrinsics:
    ok = (
        intr.width_px > 0 and intr.height_px > 0 and intr.fx > 0 and intr.fy > 0
        and 0 < intr.cx < intr.width_px and 0 < intr.cy < intr.height_px and len(intr.distortion) in (0, 4, 5, 8)
        and all(math.isfinite(v) for v in (intr.fx, intr.fy, intr.cx, intr.cy, *intr.distortion))
    )
    if not ok:
        raise CompanionError(
            f"camera calibration file {path} holds impossible values: {intr.width_px}x{intr.height_px} px, "
            f"f=({intr.fx}, {intr.fy}), c=({intr.cx}, {intr.cy}), {len(intr.distortion)} distortion terms",
            fix,
        )
    return intr


def camera_tags_for_mission(camera) -> CameraTags:
    """CameraTags from a mission's ``camera`` block (``companion.mission.spec.Camera``; calibration path resolved)."""
    calibration = getattr(camera, "calibration", None)
    if calibration:
        intr = load_calibration(Path(calibration))
        intr = intr.scaled_to(camera.width_px, camera.height_px)  # also refuses a calibration of another aspect
    else:
        intr = Intrinsics.from_hfov(camera.width_px, camera.height_px, camera.hfov_deg)
    # Always a make and model: COLMAP shares one camera among images of the same Make, Model, focal and size (a
    # per-image camera lets the focal drift on a flat wall), and ODM groups its cameras by them too.
    make = getattr(camera, "make", None) or "companion"
    model = getattr(camera, "model", None) or (
        f"mission camera {camera.width_px}x{camera.height_px} hfov {camera.hfov_deg:g} deg"
    )
    return CameraTags(
        make=make,
        model=model,
        intrinsics=intr,
        sensor_width_mm=getattr(camera, "sensor_width_mm", None),
    )

"""Synthetic keyframe spools with exact ground truth, for tests and benchmarks without the simulator.

A textured wall (random multi-scale blobs and edges, optionally a repetitive window grid) is viewed by a
pinhole camera at a constant standoff; what lies beyond the wall edges is a far, differently textured plane
(the "background" the masks must remove). Camera poses are reported as telemetry would (optionally noisy), and
the spool is written by the product's spool writer (``companion.spool.writer``), so the worker reads exactly what
a flight leaves: the same file names, sidecars, EXIF and pose form. The camera sits on a stabilised gimbal, as the
product's poses describe it (``companion.records.Pose``): it has no roll, its pitch is the gimbal's.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import pymap3d

from companion.attitude import camera_rotation_enu
from companion.geo import FacadeFrame, GeoPoint
from companion.records import Frame, GateDecision, GateReason, GimbalSource, Keyframe, Pose
from companion.spool.writer import KeyframeSpool
from companion.stitch.inputs import CameraModel

# capture times of synthetic keyframes: Unix seconds (a fixed day), one keyframe per second
CAPTURE_EPOCH_S = 1_780_000_000.0


@dataclass(frozen=True)
class SyntheticWall:
    length_m: float = 8.0
    height_m: float = 4.0
    texture_mm_per_px: float = 4.0
    windows: bool = False  # a repetitive grid of identical dark windows (the matcher's trap)
    seed: int = 0


@dataclass(frozen=True)
class TelemetryErrors:
    """How a GNSS/IMU misreports each keyframe's pose: Gaussian noise on every keyframe (position per axis, and yaw,
    pitch and roll; the gimbal levels the camera, so the roll error does not reach the camera), plus a jump that moves
    the reported position of a run of keyframes by ``jump_m`` (along, up): GNSS multipath next to a building gives
    metre-level steps that last several seconds."""

    noise_m: float = 0.0
    noise_deg: float = 0.0
    jump_m: tuple[float, float] = (0.0, 0.0)
    jump_keyframes: tuple[int, int] = (0, 0)  # [first, stop): keyframe positions the jump applies to
    # a non-RTK receiver's slowly varying error, constant over a pass: (along, out, up) metres added to every
    # reported position (out negative: the telemetry puts the camera nearer the wall than it was)
    bias_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    # ... which is not constant over a flight: it wanders by a metre over minutes. Added to the bias per keyframe
    # position, so keyframe k is reported with bias_m + k * drift_m_per_keyframe
    drift_m_per_keyframe: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def jump_at(self, k: int) -> tuple[float, float]:
        first, stop = self.jump_keyframes
        return self.jump_m if first <= k < stop else (0.0, 0.0)

    def bias_at(self, k: int) -> tuple[float, float, float]:
        return tuple(b + k * d for b, d in zip(self.bias_m, self.drift_m_per_keyframe, strict=True))


def wall_for_texture(texture: np.ndarray, mm_per_px: float, seed: int = 0) -> SyntheticWall:
    """The wall a texture image covers at ``mm_per_px`` (for :func:`make_spool` with a real photograph)."""
    h, w = texture.shape[:2]
    return SyntheticWall(
        length_m=w * mm_per_px / 1000, height_m=h * mm_per_px / 1000, texture_mm_per_px=mm_per_px, seed=seed
    )


def make_texture(wall: SyntheticWall) -> np.ndarray:
    rng = np.random.default_rng(wall.seed)
    w = int(round(wall.length_m * 1000 / wall.texture_mm_per_px))
    h = int(round(wall.height_m * 1000 / wall.texture_mm_per_px))
    tex = np.zeros((h, w), np.float32)
    for cell in (8, 24, 64, 160):  # multi-scale value noise: texture at every scale SIFT looks at
        small = rng.random((max(2, h // cell), max(2, w // cell))).astype(np.float32)
        tex += cv2.resize(small, (w, h), interpolation=cv2.INTER_CUBIC) * (cell / 64.0) ** 0.5
    tex = (tex - tex.min()) / (tex.max() - tex.min()) * 160 + 40
    img = cv2.cvtColor(tex.astype(np.uint8), cv2.COLOR_GRAY2BGR)
    img[..., 0] = np.clip(img[..., 0] * 0.85, 0, 255).astype(np.uint8)  # a warm plaster tint
    for _ in range(int(wall.length_m * wall.height_m * 6)):  # cracks/stains: sharp features
        x, y = int(rng.integers(0, w)), int(rng.integers(0, h))
        col = tuple(int(c) for c in rng.integers(0, 255, 3))
        if rng.random() < 0.5:
            cv2.circle(img, (x, y), int(rng.integers(3, 25)), col, -1, cv2.LINE_AA)
        else:
            d = rng.integers(-60, 60, 2)
            cv2.line(img, (x, y), (x + int(d[0]), y + int(d[1])), col, int(rng.integers(1, 4)), cv2.LINE_AA)
    if wall.windows:
        px = 1000 / wall.texture_mm_per_px
        for cx in np.arange(0.6, wall.length_m - 0.6, 1.5):
            for cy in np.arange(0.6, wall.height_m - 0.6, 1.6):
                x0, y0 = int((cx - 0.4) * px), int(h - (cy + 0.5) * px)
                cv2.rectangle(img, (x0, y0), (x0 + int(0.8 * px), y0 + int(1.0 * px)), (40, 50, 60), -1)
                cv2.rectangle(img, (x0, y0), (x0 + int(0.8 * px), y0 + int(1.0 * px)), (230, 230, 230), 6)
                cv2.line(img, (x0 + int(0.4 * px), y0), (x0 + int(0.4 * px), y0 + int(1.0 * px)), (230, 230, 230), 4)
    return img


def _background(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed + 991)
    bg = np.full((600, 1600, 3), (235, 200, 150), np.uint8)  # sky
    for _ in range(220):  # trees and far buildings: strong features the masks must hide
        x, y = int(rng.integers(0, 1600)), int(rng.integers(250, 600))
        col = tuple(int(c) for c in rng.integers(0, 120, 3))
        cv2.rectangle(bg, (x, y), (x + int(rng.integers(10, 80)), 600), col, -1)
    return bg


def view(
    texture: np.ndarray,
    wall: SyntheticWall,
    camera: CameraModel,
    frame: FacadeFrame,
    along_m: float,
    up_m: float,
    standoff_m: float,
    *,
    yaw_offset_deg: float = 0.0,
    pitch_deg: float = 0.0,
    background: np.ndarray | None = None,
    hole_m: tuple[float, float, float, float] | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(image, mask, R_enu_from_cam) of a camera at facade (along, standoff, up) looking at the wall."""
    R = camera_rotation_enu(yaw_deg=frame.yaw_facing_wall_deg + yaw_offset_deg, pitch_deg=pitch_deg)
    e, n, u = frame.facade_to_enu(along_m, standoff_m, up_m)
    C = np.array([float(e), float(n), float(u)])
    de, dn = frame.along_enu
    a, up = np.array([de, dn, 0.0]), np.array([0.0, 0.0, 1.0])
    s = wall.texture_mm_per_px / 1000.0
    plane_from_tex = np.array([[s, 0, 0], [0, -s, wall.height_m], [0, 0, 1]])
    img_from_tex = camera.K @ R.T @ np.column_stack((a, up, -C)) @ plane_from_tex
    size = (camera.width, camera.height)
    img = cv2.warpPerspective(texture, img_from_tex, size, flags=cv2.INTER_LINEAR)
    ones = np.full(texture.shape[:2], 255, np.uint8)
    if hole_m is not None:  # a wall region the masks call background (e.g. a tree in front of the wall)
        a0, a1, u0, u1 = hole_m
        ones[int((wall.height_m - u1) / s) : int((wall.height_m - u0) / s), int(a0 / s) : int(a1 / s)] = 0
    mask = cv2.warpPerspective(ones, img_from_tex, size, flags=cv2.INTER_NEAREST)
    if background is not None:
        # a far plane 40 m behind the wall, 20 m x 7.5 m per background image, tiled
        out = np.array([frame.out_enu[0], frame.out_enu[1], 0.0])
        bs = 20.0 / background.shape[1]
        far_from_bg = np.array([[bs, 0, -10.0], [0, -bs, 7.5], [0, 0, 1]])
        origin = -40.0 * out
        img_from_bg = camera.K @ R.T @ np.column_stack((a, up, origin - C)) @ far_from_bg
        bgv = cv2.warpPerspective(background, img_from_bg, size, flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)
        img = np.where(mask[..., None] > 0, img, bgv)
    return img, mask, R


def make_spool(
    out_dir: str | Path,
    wall: SyntheticWall,
    *,
    width: int = 640,
    height: int = 360,
    hfov_deg: float = 70.0,
    standoff_m: float = 4.0,
    overlap: float = 0.6,
    pose_noise_m: float = 0.0,
    yaw_noise_deg: float = 0.0,
    background: bool = True,
    margin_m: float = 0.3,
    with_poses: bool = True,
    seed: int = 0,
    jitter_deg: float = 0.0,
    hole_m: tuple[float, float, float, float] | None = None,
    texture: np.ndarray | None = None,
    errors: TelemetryErrors | None = None,
    missing_m: tuple[float, float, float, float] | None = None,
) -> dict:
    """Writes a keyframe spool of the wall through the product's writer (one keyframe per view, its index the
    view's number); returns the truth (texture, camera, frame, views).

    ``texture`` (BGR, row 0 = top of the wall) replaces the generated one, e.g. a real photograph of a wall; it
    must cover ``wall`` at ``wall.texture_mm_per_px`` (see :func:`wall_for_texture`). ``errors`` replaces
    ``pose_noise_m``/``yaw_noise_deg`` with a full GNSS/IMU error model (roll too, and jumps). ``missing_m``
    (along0, along1, up0, up1): no keyframe whose footprint reaches into this wall rectangle is written, so no
    keyframe shows it (a re-fly target; ``hole_m`` is instead a patch every keyframe shows and masks out)."""
    out = Path(out_dir)
    rng = np.random.default_rng(seed)
    camera = CameraModel.from_hfov(width, height, hfov_deg)
    frame = _wall_frame(wall)
    texture = make_texture(wall) if texture is None else _checked_texture(texture, wall)
    bg = _background(seed) if background else None
    fw = standoff_m * width / camera.focal_px
    fh = standoff_m * height / camera.focal_px
    alongs = _centres(wall.length_m, fw, overlap, margin_m)
    ups = _centres(wall.height_m, fh, overlap, margin_m)
    spool = KeyframeSpool(out, meta=_spool_meta(frame, wall, width, height, hfov_deg, standoff_m),
                          settings={"synthetic": True})
    views = []
    for c, al in enumerate(alongs):  # vertical strips, up then down (the planner's 'vertical' pattern)
        for up in ups if c % 2 == 0 else ups[::-1]:
            if missing_m is not None and _reaches(missing_m, float(al), float(up), fw, fh):
                continue
            k = len(views)
            yaw_off = float(rng.normal(0, jitter_deg)) if jitter_deg else 0.0
            pitch = float(rng.normal(0, jitter_deg)) if jitter_deg else 0.0
            img, mask, _ = view(texture, wall, camera, frame, float(al), float(up), standoff_m,
                                yaw_offset_deg=yaw_off, pitch_deg=pitch, background=bg, hole_m=hole_m)
            pose = None
            if with_poses:
                true_pose = (float(al), standoff_m, float(up), pitch, yaw_off)
                if errors is None:
                    pose = _telemetry_pose(rng, frame, true_pose, pose_noise_m, yaw_noise_deg, k)
                else:
                    pose = reported_pose(rng, frame, true_pose, errors, k)
            decision = GateDecision() if k == 0 else GateDecision(overlap_to_previous=round(overlap * 100, 1),
                                                                   reason=GateReason.OVERLAP, previous_index=k - 1)
            spool.append(Keyframe(Frame(k, CAPTURE_EPOCH_S + k, img), pose, mask, decision))
            views.append({"along_m": float(al), "up_m": float(up)})
    return {"texture": texture, "camera": camera, "frame": frame, "views": views, "wall": wall}


def _reaches(rect: tuple[float, float, float, float], along: float, up: float, fw: float, fh: float) -> bool:
    """A level camera's footprint (``fw`` x ``fh`` centred at ``along``, ``up``) overlaps ``rect``."""
    a0, a1, u0, u1 = rect
    return along - fw / 2 < a1 and along + fw / 2 > a0 and up - fh / 2 < u1 and up + fh / 2 > u0


_WALL_START = GeoPoint(37.56650, 126.97800, 30.0)


def _wall_end(wall: SyntheticWall) -> GeoPoint:
    """The end of a west->east wall of the wall's length from a fixed start (flown from the south)."""
    start = _WALL_START
    _, end_lon, _ = pymap3d.enu2geodetic(wall.length_m, 0.0, 0.0, start.lat, start.lon, start.alt_amsl_m)
    return GeoPoint(start.lat, float(end_lon), 30.0)


def _wall_frame(wall: SyntheticWall) -> FacadeFrame:
    return FacadeFrame.from_wall(_WALL_START, _wall_end(wall))


def _checked_texture(texture: np.ndarray, wall: SyntheticWall) -> np.ndarray:
    want = (
        round(wall.height_m * 1000 / wall.texture_mm_per_px),
        round(wall.length_m * 1000 / wall.texture_mm_per_px),
    )
    if abs(texture.shape[0] - want[0]) > 1 or abs(texture.shape[1] - want[1]) > 1:
        raise ValueError(f"texture is {texture.shape[1]}x{texture.shape[0]} px, the wall needs {want[1]}x{want[0]}")
    return texture


def _centres(extent_m: float, footprint_m: float, overlap: float, margin_m: float) -> np.ndarray:
    """Frame centres along one axis: ``overlap`` between neighbours, the last frame ``margin_m`` past the end."""
    first, last = footprint_m / 2 - margin_m, extent_m - footprint_m / 2 + margin_m
    if first >= last:  # the footprint spans the wall (and its margins): one row or column, centred
        return np.array([extent_m / 2])
    centres = np.arange(first, last + 1e-6, footprint_m * (1 - overlap))
    if centres[-1] < last - 1e-6:
        centres = np.append(centres, last)
    return centres


def _telemetry_pose(rng, frame: FacadeFrame, true_pose, pose_noise_m: float, yaw_noise_deg: float, k: int) -> Pose:
    """The pose of keyframe ``k``, a camera at facade (along, out, up) with (pitch, yaw offset), as a GNSS/IMU
    would report it: position and attitude with Gaussian noise."""
    along, out, up, pitch, yaw_off = true_pose
    na, nu, no = rng.normal(0, pose_noise_m, 3) if pose_noise_m else (0.0, 0.0, 0.0)
    pitch_noise = float(rng.normal(0, yaw_noise_deg)) if yaw_noise_deg else 0.0
    yaw_noise = float(rng.normal(0, yaw_noise_deg)) if yaw_noise_deg else 0.0
    return _pose(frame, (along + na, out + no, up + nu), 0.0, pitch + pitch_noise,
                 frame.yaw_facing_wall_deg + yaw_off + yaw_noise, float(k))


def reported_pose(rng, frame: FacadeFrame, true_pose, errors: TelemetryErrors, k: int,
                  time_s: float | None = None) -> Pose:
    """The pose of keyframe ``k`` at facade (along, out, up) with (pitch, yaw offset), as a GNSS/IMU with
    ``errors`` reports it, stamped ``time_s`` (default ``k`` seconds) on the autopilot's clock."""
    along, out, up, pitch, yaw_off = true_pose
    na, no, nu = rng.normal(0, errors.noise_m, 3) if errors.noise_m else (0.0, 0.0, 0.0)
    dy, dp, dr = rng.normal(0, errors.noise_deg, 3) if errors.noise_deg else (0.0, 0.0, 0.0)
    ja, ju = errors.jump_at(k)
    ba, bo, bu = errors.bias_at(k)
    position = (along + na + ja + ba, out + no + bo, up + nu + ju + bu)
    return _pose(frame, position, float(dr), pitch + float(dp), frame.yaw_facing_wall_deg + yaw_off + float(dy),
                 float(k) if time_s is None else time_s)


def _pose(frame: FacadeFrame, facade_m: tuple[float, float, float], roll_deg: float, camera_pitch_deg: float,
          yaw_deg: float, time_s: float) -> Pose:
    """A telemetry pose at facade (along, out, up): the vehicle's attitude, the camera's pitch on its gimbal."""
    lat, lon, alt = frame.facade_to_geodetic(*facade_m)
    return Pose(time_s=time_s, lat=float(lat), lon=float(lon), alt_amsl_m=float(alt),
                relative_alt_m=float(alt) - frame.origin.alt_amsl_m, roll_deg=roll_deg, pitch_deg=camera_pitch_deg,
                yaw_deg=yaw_deg % 360.0, gimbal_pitch_deg=camera_pitch_deg, gimbal_yaw_deg=0.0,
                gimbal_source=GimbalSource.TELEMETRY)


def spool_meta(frame: FacadeFrame, wall: SyntheticWall, width, height, hfov_deg, standoff_m) -> dict:
    """spool.json of a pass over ``wall`` (west->east from the fixed start) with this camera."""
    return _spool_meta(frame, wall, width, height, hfov_deg, standoff_m)


def wall_frame(wall: SyntheticWall) -> FacadeFrame:
    """The facade frame of ``wall`` (its start at a fixed site, west->east, flown from the south)."""
    return _wall_frame(wall)


def _spool_meta(frame: FacadeFrame, wall: SyntheticWall, width, height, hfov_deg, standoff_m) -> dict:
    start, end = frame.origin, _wall_end(wall)
    return {
        "camera": {"width_px": width, "height_px": height, "hfov_deg": hfov_deg},
        "facade": {
            "start": {"lat": start.lat, "lon": start.lon},
            "end": {"lat": start.lat, "lon": end.lon},
            "ground_alt_amsl_m": 30.0,
            "height_m": wall.height_m,
        },
        "standoff_m": standoff_m,
    }

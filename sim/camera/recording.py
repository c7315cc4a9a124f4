"""Recordings: rendered frames with their ground truth on disk, the loader every evaluation reads them with, and
the fast generator (kinematic flight along the planner's path, no SITL) that tests and benchmarks use.

Layout of a recording directory::

    meta.json          mission name, seed, camera (size, K, fps, exposure), facade geometry, scene truth
    frames/%06d.jpg    what the camera delivered (JPEG)
    frames/times.csv   name,capture_time_s per frame (autopilot clock): the image folder `companion cull` reads
    depth/%06d.npy     float16 z-depth in metres, inf for sky
    masks/%06d.png     uint8 0/255, 255 = pixel sees the target facade
    truth.jsonl        one line per frame: index, capture_time_s, pose, K
    telemetry.jsonl    the format of `companion fly --telemetry-log`: written by the flight code in SITL, sampled
                       from the kinematic flight by the fast generator (sim/camera/telemetry_log.py)
    texture/           cache of the true wall texture images (made on first facade_texture call)
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from companion.errors import CompanionError
from companion.files import read_jsonl
from companion.geo import FacadeFrame, GeoPoint
from companion.progress import progress_bar
from companion.records import Frame
from sim.camera.model import CameraModel, TruePose
from sim.camera.overlap import clip_to_rect, footprint_on_wall, overlap_ratio
from sim.camera.render import AutoExposure, RenderedFrame
from sim.camera.scene import Scene

FORMAT_VERSION = 1


def facade_meta(frame: FacadeFrame, scene: Scene) -> dict:
    return {
        "origin": {"lat": frame.origin.lat, "lon": frame.origin.lon, "alt_amsl_m": frame.origin.alt_amsl_m},
        "along_enu": [float(v) for v in frame.along_enu],
        "length_m": float(frame.length_m),
        "height_m": float(scene.height_m),
        "building_depth_m": float(scene.depth_m),
        "convention": "facade coords (along_m, out_m, up_m), see companion.geo; world = ENU at origin",
    }


def frame_from_meta(meta: dict) -> FacadeFrame:
    f = meta["facade"]
    o = f["origin"]
    return FacadeFrame(GeoPoint(o["lat"], o["lon"], o["alt_amsl_m"]), tuple(f["along_enu"]), float(f["length_m"]))


class RecordingWriter:
    """Writes one rendered frame at a time (JPEG image, depth, mask, truth line); ``close`` finishes it."""

    def __init__(self, out_dir: str | Path, meta: dict, *, jpeg_quality: int = 92):
        self.dir = Path(out_dir)
        if self.dir.exists() and (self.dir / "meta.json").exists():
            raise CompanionError(f"{self.dir} already holds a recording", "choose a new --out directory or delete it")
        for sub in ("frames", "depth", "masks"):
            (self.dir / sub).mkdir(parents=True, exist_ok=True)
        self.meta = dict(meta, format_version=FORMAT_VERSION)
        self.jpeg_quality = int(jpeg_quality)
        self._truth = open(self.dir / "truth.jsonl", "w", encoding="utf-8")  # noqa: SIM115 (open until close)
        self._times = open(self.dir / "frames" / "times.csv", "w", encoding="utf-8")  # noqa: SIM115
        self.count = 0

    def add(self, rendered: RenderedFrame, capture_time_s: float, *, source_frame: int | None = None) -> int:
        i = self.count
        ok, jpg = cv2.imencode(".jpg", rendered.image, [cv2.IMWRITE_JPEG_QUALITY, self.jpeg_quality])
        if not ok:
            raise CompanionError("JPEG encoding failed", "check the rendered image (BGR uint8)")
        (self.dir / "frames" / f"{i:06d}.jpg").write_bytes(jpg.tobytes())
        d = rendered.depth
        d16 = np.where(np.isfinite(d), np.minimum(d, 60000.0), np.inf).astype(np.float16)  # float16 max 65504
        np.save(self.dir / "depth" / f"{i:06d}.npy", d16)
        cv2.imwrite(str(self.dir / "masks" / f"{i:06d}.png"), rendered.roi_mask)
        line = {
            "index": i,
            "capture_time_s": float(capture_time_s),
            "source_frame": source_frame if source_frame is not None else i,
            "pose": rendered.pose.to_json(),
            "K": rendered.K.tolist(),
            "exposure_gain": rendered.gain,
            "roi_fraction": float((rendered.roi_mask > 0).mean()),
        }
        self._truth.write(json.dumps(line) + "\n")
        self._truth.flush()
        self._times.write(f"{i:06d}.jpg,{float(capture_time_s)!r}\n")  # exact round trip
        self._times.flush()
        self.count += 1
        return i

    def close(self) -> Path:
        self._truth.close()
        self._times.close()
        self.meta["frames"] = self.count
        (self.dir / "meta.json").write_text(json.dumps(self.meta, indent=1), encoding="utf-8")
        return self.dir


@dataclass(frozen=True)
class FacadeTextureImage:
    """The true wall texture: row 0 is the top of the wall (up = height_m), column 0 is along = 0."""

    image: np.ndarray
    mm_per_px: float
    length_m: float
    height_m: float


class Recording:
    """Read access to a recording directory (see module docstring)."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        meta_p = self.path / "meta.json"
        if not meta_p.exists():
            raise CompanionError(f"{self.path} is not a recording (no meta.json)",
                                 "point at a directory written by generate_recording or `companion record`")
        self.meta = json.loads(meta_p.read_text(encoding="utf-8"))
        self._truth = read_jsonl(self.path / "truth.jsonl", skip_bad=False)
        cam = self.meta["camera"]
        self.width = int(cam["width"])
        self.height = int(cam["height"])
        self.K = np.asarray(cam["K"], dtype=float)
        self.frame = frame_from_meta(self.meta)
        self._poses: dict[int, TruePose] = {}
        self._foot: dict[int, np.ndarray] = {}
        self._scene: Scene | None = None

    def __len__(self) -> int:
        return len(self._truth)

    def _check(self, i: int) -> int:
        if not 0 <= i < len(self._truth):
            raise CompanionError(f"frame {i} is out of range: the recording has {len(self)} frames",
                                 f"use an index in 0..{len(self) - 1}")
        return i

    def image(self, i: int) -> np.ndarray:
        img = cv2.imread(str(self.path / "frames" / f"{self._check(i):06d}.jpg"), cv2.IMREAD_COLOR)
        if img is None:
            raise CompanionError(f"frame {i} of {self.path} is missing or unreadable", "re-generate the recording")
        return img

    def depth(self, i: int) -> np.ndarray:
        return np.load(self.path / "depth" / f"{self._check(i):06d}.npy").astype(np.float32)

    def roi_mask(self, i: int) -> np.ndarray:
        m = cv2.imread(str(self.path / "masks" / f"{self._check(i):06d}.png"), cv2.IMREAD_GRAYSCALE)
        if m is None:
            raise CompanionError(f"mask {i} of {self.path} is missing or unreadable", "re-generate the recording")
        return m

    def capture_time(self, i: int) -> float:
        return float(self._truth[self._check(i)]["capture_time_s"])

    def camera_pose(self, i: int) -> TruePose:
        if i not in self._poses:
            self._poses[i] = TruePose.from_json(self._truth[self._check(i)]["pose"])
        return self._poses[i]

    def frame_record(self, i: int) -> Frame:
        """Frame i as the companion's capture stage would deliver it."""
        return Frame(index=i, capture_time_s=self.capture_time(i), image=self.image(i))

    def footprint(self, i: int) -> np.ndarray:
        """Frame i's footprint polygon on the wall plane, facade (along_m, up_m)."""
        if i not in self._foot:
            self._foot[i] = footprint_on_wall(self.K, self.width, self.height, self.camera_pose(i), self.frame)
        return self._foot[i]

    def true_overlap(self, i: int, j: int, *, wall_only: bool = False) -> float:
        """Fraction (0..1) of frame i's footprint on the wall plane that frame j's footprint covers. With
        ``wall_only`` both footprints are first cut to the wall rectangle (the facade actually visible)."""
        pi, pj = self.footprint(i), self.footprint(j)
        if wall_only:
            L, H = self.meta["facade"]["length_m"], self.meta["facade"]["height_m"]
            pi, pj = clip_to_rect(pi, 0, 0, L, H), clip_to_rect(pj, 0, 0, L, H)
        return overlap_ratio(pi, pj)

    def scene(self) -> Scene:
        if self._scene is None:
            sc = self.meta["scene"]
            self._scene = Scene.build(self.meta["facade"]["length_m"], self.meta["facade"]["height_m"],
                                      seed=int(sc["seed"]), n_cracks=sc.get("n_cracks"))
        return self._scene

    def facade_texture(self, mm_per_px: float | None = None) -> FacadeTextureImage:
        """The true wall texture as one image; default scale keeps it at most 4000 px wide."""
        L, H = self.meta["facade"]["length_m"], self.meta["facade"]["height_m"]
        if mm_per_px is None:
            mm_per_px = max(2.0, math.ceil(L * 1000 / 4000))
        if mm_per_px <= 0:
            raise CompanionError(f"mm_per_px={mm_per_px} must be positive", "use e.g. 5 (mm per pixel)")
        cache = self.path / "texture" / f"facade_{mm_per_px:g}mm.png"
        img = cv2.imread(str(cache), cv2.IMREAD_COLOR) if cache.exists() else None
        if img is None:
            img = self.scene().texture.full_image(mm_per_px)  # seconds for a whole wall: cache it
            try:
                cache.parent.mkdir(exist_ok=True)
                cv2.imwrite(str(cache), img)
            except OSError:
                pass  # read-only recording: recompute next time
        return FacadeTextureImage(img, float(mm_per_px), float(L), float(H))


def load_recording(path: str | Path) -> Recording:
    return Recording(path)


def mission_file_meta(mission) -> dict:
    """``{"mission_file": absolute path}`` when the mission came from a file, for meta.json: `companion cull` of
    the recording finds its mission (camera, facade: the spool's scale) there without ``--mission``."""
    if isinstance(mission, str | Path):
        return {"mission_file": str(Path(mission).resolve())}
    return {}


def resolve_mission(mission):
    """A Mission object as is, or a mission YAML path loaded and validated."""
    if isinstance(mission, str | Path):
        from companion.mission import load_mission

        return load_mission(mission)
    return mission


def camera_from_mission(mission, width_px: int | None) -> CameraModel:
    c = mission.camera
    cam = CameraModel(int(c.width_px), int(c.height_px), float(c.hfov_deg))
    return cam.scaled(width_px) if width_px else cam


def generate_recording(mission, out_dir: str | Path, *, seed: int = 0, width_px: int = 640,
                       max_frames: int | None = None, stride: int = 1, jpeg_quality: int = 92,
                       n_cracks: int | None = None, progress: bool = False, telemetry_rate_hz: float = 10.0,
                       renderer: str = "warp") -> Path:
    """Fast recording: kinematic flight along the planner's scan path (first to last scan waypoint), frames at
    the mission camera's fps (every ``stride``-th, at most ``max_frames``), rendered at ``width_px`` wide, and
    the telemetry log of the recorded span at ``telemetry_rate_hz`` (``companion fly``'s default rate).
    ``renderer``: 'warp' (textures warped per plane, the default) or 'raycast' (the per-pixel reference)."""
    from companion.mission import plan_scan
    from sim.camera.telemetry_log import telemetry_rows, write_telemetry_log
    from sim.camera.trajectory import KinematicFlight, scan_path
    from sim.camera.warp_render import make_renderer

    source = mission_file_meta(mission)
    mission = resolve_mission(mission)
    if stride < 1:
        raise CompanionError(f"stride={stride} must be >= 1", "use stride=1 for every camera frame")
    if max_frames is not None and max_frames < 1:
        raise CompanionError(f"max_frames={max_frames} must be >= 1", "leave it out for the whole scan")
    plan = plan_scan(mission)
    frame = plan.frame
    cam = camera_from_mission(mission, width_px)
    scene = Scene.build(frame.length_m, float(mission.facade.height_m), seed=seed, n_cracks=n_cracks)
    fps = float(mission.camera.fps)
    exposure_s = float(mission.camera.exposure_s)
    render = make_renderer(renderer, scene, frame, cam, exposure_s=exposure_s, seed=seed)
    flight = KinematicFlight(frame, scan_path(plan), gimbal_pitch_deg=float(mission.gimbal_pitch_deg), seed=seed)
    meta = {
        "mission": mission.name,
        **source,
        "seed": seed,
        "generator": {"kind": "kinematic", "stride": stride, "max_frames": max_frames,
                      "flight_duration_s": flight.duration_s, "telemetry_rate_hz": telemetry_rate_hz,
                      "renderer": renderer},
        "camera": {"width": cam.width, "height": cam.height, "hfov_deg": cam.hfov_deg, "K": cam.K.tolist(),
                   "fps": fps, "exposure_s": exposure_s, "native_width": int(mission.camera.width_px),
                   "jpeg_quality": jpeg_quality},
        "facade": facade_meta(frame, scene),
        "scene": {"seed": seed, "n_cracks": n_cracks, **scene.truth_json()},
        "standoff_m": float(mission.standoff_m),
    }
    writer = RecordingWriter(out_dir, meta, jpeg_quality=jpeg_quality)
    ae = AutoExposure(seed=seed)
    times = list(flight.times(fps, stride=stride, max_frames=max_frames))
    try:
        for k, t in progress_bar(times, desc="rendering", unit="frame", disable=not progress):
            rendered = render.render(flight.pose(t), index=k, time_s=t, exposure=ae)
            writer.add(rendered, t, source_frame=k)
    finally:
        path = writer.close()
    if times:
        rows = telemetry_rows(flight, times[0][1], times[-1][1], home_alt_amsl_m=plan.home.alt_amsl_m,
                              rate_hz=telemetry_rate_hz, epoch_unix_s=round(time.time(), 3))
        write_telemetry_log(path / "telemetry.jsonl", rows)
    return path

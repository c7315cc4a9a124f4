"""The live simulated camera: follows the vehicle's true pose, renders at the camera's frame rate in simulated
time, and streams JPEG frames to the companion over TCP like a real camera (``python -m sim camera``).

Capture instants are ``k / fps`` seconds on the vehicle's clock (the pose channel's ``t_s``, the clock MAVLink
timestamps use); the pose at each instant is interpolated between the 50 Hz pose messages. When rendering falls
behind simulated time by more than ``max_lag_frames`` the camera drops frames spread over its catching up (as a
real camera's encoder would: never a stretch at once), so frame numbers can jump; the capture times stay exact.
Optionally writes a recording with full ground truth.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import math
import queue
import signal
import socket
import threading
import time
from collections import deque
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import pymap3d

from companion.attitude import camera_rotation_enu
from companion.capture.simcam import DEFAULT_PORT, encode_message
from companion.errors import CompanionError
from companion.geo import FacadeFrame
from sim.camera.model import TruePose
from sim.camera.recording import RecordingWriter, camera_from_mission, facade_meta, mission_file_meta, resolve_mission
from sim.camera.render import AutoExposure
from sim.camera.scene import Scene
from sim.camera.warp_render import RENDERERS, make_renderer

log = logging.getLogger(__name__)
_NUMERIC = ("lat", "lon", "alt_amsl_m", "north_m", "east_m", "down_m", "vn_m_s", "ve_m_s", "vd_m_s", "roll_deg",
            "pitch_deg", "gimbal_pitch_deg")
_ANGLES = ("yaw_deg", "gimbal_yaw_deg")


@dataclass
class LiveConfig:
    pose_port: int = 14660
    stream_host: str = "127.0.0.1"
    stream_port: int = DEFAULT_PORT
    width_px: int = 640
    fps: float | None = None  # default: the mission camera's
    seed: int = 0
    record_dir: Path | None = None
    jpeg_quality: int = 88
    max_lag_frames: int = 3
    catch_up_frames: int = 90  # further behind than this (3 s at 30 fps) the camera jumps to the newest pose
    duration_s: float | None = None  # wall seconds, for tests and scripted runs
    record_max_out_m: float | None = None  # record only frames taken this close to the wall plane (the scan)
    renderer: str = "warp"  # 'warp' (real time) or 'raycast' (the per-pixel reference, 4-6x the CPU)


def interpolate_pose(a: dict, b: dict, t: float) -> dict:
    """Pose message at time t between messages a and b (linear; angles the short way round)."""
    ta, tb = float(a["t_s"]), float(b["t_s"])
    s = 0.0 if tb <= ta else min(max((t - ta) / (tb - ta), 0.0), 1.0)
    out = dict(b)
    out["t_s"] = t
    for k in _NUMERIC:
        if k in a and k in b:
            out[k] = float(a[k]) + s * (float(b[k]) - float(a[k]))
    for k in _ANGLES:
        if k in a and k in b:
            d = (float(b[k]) - float(a[k]) + 180.0) % 360.0 - 180.0
            out[k] = (float(a[k]) + s * d) % 360.0
    return out


def camera_pose(msg: dict, frame: FacadeFrame, *, yaw_rate_deg_s: float = 0.0) -> TruePose:
    """Camera pose from a vehicle pose message. The gimbal is stabilised in pitch and roll: the camera points
    at vehicle yaw + gimbal yaw, gimbal pitch, and zero roll (body roll/pitch do not tilt it)."""
    o = frame.origin
    e, n, u = pymap3d.geodetic2enu(float(msg["lat"]), float(msg["lon"]), float(msg["alt_amsl_m"]),
                                   o.lat, o.lon, o.alt_amsl_m)
    yaw = (float(msg["yaw_deg"]) + float(msg.get("gimbal_yaw_deg", 0.0))) % 360.0
    pitch = float(msg.get("gimbal_pitch_deg", 0.0))
    R = camera_rotation_enu(yaw_deg=yaw, pitch_deg=pitch, roll_deg=0.0)
    w_world = np.array([0.0, 0.0, -math.radians(yaw_rate_deg_s)])  # yaw is clockwise: about -up
    return TruePose(
        position_enu=np.array([float(e), float(n), float(u)]),
        R_world_from_cam=R,
        yaw_deg=yaw,
        pitch_deg=pitch,
        roll_deg=0.0,
        lat=float(msg["lat"]),
        lon=float(msg["lon"]),
        alt_amsl_m=float(msg["alt_amsl_m"]),
        velocity_enu_m_s=np.array([float(msg.get("ve_m_s", 0.0)), float(msg.get("vn_m_s", 0.0)),
                                   -float(msg.get("vd_m_s", 0.0))]),
        angular_rate_cam_rad_s=R.T @ w_world,
    )


class PoseListener:
    """Receives the vehicle's true-pose datagrams and answers 'pose at time t' by interpolation."""

    def __init__(self, port: int, host: str = "127.0.0.1", keep: int = 500):
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self.sock.bind((host, port))
        except OSError as exc:
            self.sock.close()
            raise CompanionError(f"cannot listen for true poses on UDP {host}:{port} ({exc})",
                                 "another camera may be running; pick a free --pose-port") from exc
        self.port = self.sock.getsockname()[1]
        self.sock.settimeout(0.2)
        self.poses: deque[dict] = deque(maxlen=keep)
        self.cond = threading.Condition()
        self.bad = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="pose-listener", daemon=True)
        self._thread.start()

    def _run(self):
        while not self._stop.is_set():
            try:
                data = self.sock.recv(65536)
            except TimeoutError:
                continue
            except OSError:
                return
            try:
                msg = json.loads(data)
                float(msg["t_s"]), float(msg["lat"]), float(msg["lon"]), float(msg["alt_amsl_m"])
            except (ValueError, KeyError, TypeError):
                self.bad += 1
                continue
            with self.cond:
                if self.poses and float(msg["t_s"]) < float(self.poses[-1]["t_s"]) - 1.0:
                    self.poses.clear()  # the vehicle restarted: its clock began again
                self.poses.append(msg)
                self.cond.notify_all()

    def newest_time(self) -> float | None:
        with self.cond:
            return float(self.poses[-1]["t_s"]) if self.poses else None

    def wait_newer(self, t: float, timeout: float) -> bool:
        """Wait until a pose at or after time t has arrived."""
        with self.cond:
            return self.cond.wait_for(lambda: bool(self.poses) and float(self.poses[-1]["t_s"]) >= t, timeout)

    def at(self, t: float) -> tuple[dict, float] | None:
        """(interpolated pose message, yaw rate deg/s) at time t, or None if t is outside the buffer."""
        with self.cond:
            ps = list(self.poses)
        if not ps or float(ps[0]["t_s"]) > t or float(ps[-1]["t_s"]) < t:
            return None
        times = [float(p["t_s"]) for p in ps]
        i = int(np.searchsorted(times, t, side="right"))
        a, b = ps[max(i - 1, 0)], ps[min(i, len(ps) - 1)]
        dt = float(b["t_s"]) - float(a["t_s"])
        rate = ((float(b["yaw_deg"]) - float(a["yaw_deg"]) + 180) % 360 - 180) / dt if dt > 1e-6 else 0.0
        return interpolate_pose(a, b, t), rate

    def close(self):
        self._stop.set()
        self.sock.close()
        self._thread.join(timeout=1.0)


class FrameServer:
    """TCP server: every connected client gets every frame from its connection on (slow clients lose the
    oldest queued frames rather than stalling the camera)."""

    def __init__(self, host: str, port: int, queue_frames: int = 30):
        self.srv = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self.srv.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            self.srv.bind((host, port))
        except OSError as exc:
            self.srv.close()
            raise CompanionError(f"cannot serve camera frames on TCP {host}:{port} ({exc})",
                                 "pick a free --stream-port") from exc
        self.srv.listen(4)
        self.srv.settimeout(0.2)
        self.port = self.srv.getsockname()[1]
        self.queue_frames = queue_frames
        self.clients: list[queue.Queue] = []
        self.lock = threading.Lock()
        self._stop = threading.Event()
        self.dropped = 0
        threading.Thread(target=self._accept, name="camera-accept", daemon=True).start()

    def _accept(self):
        while not self._stop.is_set():
            try:
                conn, addr = self.srv.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            q: queue.Queue = queue.Queue(maxsize=self.queue_frames)
            with self.lock:
                self.clients.append(q)
            log.info("camera client %s connected", addr)
            threading.Thread(target=self._send, args=(conn, q), name="camera-client", daemon=True).start()

    def _send(self, conn: socket.socket, q: queue.Queue):
        try:
            while True:
                msg = q.get()
                if msg is None:
                    return
                conn.sendall(msg)
        except OSError:
            pass
        finally:
            with self.lock:
                if q in self.clients:
                    self.clients.remove(q)
            with contextlib.suppress(OSError):
                conn.close()

    def broadcast(self, msg: bytes):
        with self.lock:
            clients = list(self.clients)
        for q in clients:
            while True:
                try:
                    q.put_nowait(msg)
                    break
                except queue.Full:
                    with contextlib.suppress(queue.Empty):
                        q.get_nowait()
                        self.dropped += 1

    def close(self):
        self._stop.set()
        with self.lock:
            for q in self.clients:
                with contextlib.suppress(queue.Full):
                    q.put_nowait(None)
        self.srv.close()


class LiveCamera:
    """Pose listener + renderer + frame server (+ optional recording writer)."""

    def __init__(self, mission, cfg: LiveConfig):
        from companion.mission import plan_scan

        self._mission_source = mission_file_meta(mission)
        self.mission = resolve_mission(mission)
        self.cfg = cfg
        plan = plan_scan(self.mission)
        self.frame = plan.frame
        self.camera = camera_from_mission(self.mission, cfg.width_px)
        self.fps = float(cfg.fps or self.mission.camera.fps)
        if not self.fps > 0:
            raise CompanionError(f"camera fps {self.fps} must be positive", "give --fps, e.g. 30")
        self.scene = Scene.build(self.frame.length_m, float(self.mission.facade.height_m), seed=cfg.seed)
        self.renderer = make_renderer(cfg.renderer, self.scene, self.frame, self.camera,
                                      exposure_s=float(self.mission.camera.exposure_s), seed=cfg.seed)
        self.exposure = AutoExposure(seed=cfg.seed)
        # the wall texture is built ahead of the camera while it waits for poses (WarpRenderer.prefetch_wall):
        # at the level the scan's standoff gives, first around the first scan waypoint, then around the camera
        self._prefetch_level = (self.renderer.wall_level(float(self.mission.standoff_m))
                                if hasattr(self.renderer, "prefetch_wall") else None)
        first = plan.waypoints[plan.scan_legs[0][0]] if plan.scan_legs else None
        self._wall_point = (float(first.along_m), float(first.up_m)) if first is not None else (0.0, 0.0)
        self.listener = PoseListener(cfg.pose_port)
        try:
            self.server = FrameServer(cfg.stream_host, cfg.stream_port)
        except CompanionError:
            self.listener.close()
            raise
        self.writer: RecordingWriter | None = None
        if cfg.record_dir is not None:
            self.writer = RecordingWriter(cfg.record_dir, self._meta(), jpeg_quality=cfg.jpeg_quality)
        self.stop = threading.Event()
        self.sent = 0
        self._outbox: queue.Queue = queue.Queue(maxsize=2)
        self._delivery_error: Exception | None = None
        self._delivery = threading.Thread(target=self._deliver_frames, name="camera-delivery", daemon=True)
        self._delivery.start()
        self.skipped = 0
        self.prefetched = 0  # wall texture tiles built while waiting for poses

    def _meta(self) -> dict:
        cam = self.camera
        return {
            "mission": self.mission.name,
            **self._mission_source,
            "seed": self.cfg.seed,
            "generator": {"kind": "live", "pose_port": self.listener.port, "renderer": self.cfg.renderer},
            "camera": {"width": cam.width, "height": cam.height, "hfov_deg": cam.hfov_deg, "K": cam.K.tolist(),
                       "fps": self.fps, "exposure_s": float(self.mission.camera.exposure_s),
                       "native_width": int(self.mission.camera.width_px), "jpeg_quality": self.cfg.jpeg_quality},
            "facade": facade_meta(self.frame, self.scene),
            "scene": {"seed": self.cfg.seed, "n_cracks": None, **self.scene.truth_json()},
            "standoff_m": float(self.mission.standoff_m),
        }

    def run(self) -> int:
        """Render and stream until stopped (or ``duration_s`` wall seconds); returns frames sent."""
        t_end = time.monotonic() + self.cfg.duration_s if self.cfg.duration_s else math.inf
        k: int | None = None
        last_t = -math.inf
        try:
            while not self.stop.is_set() and time.monotonic() < t_end:
                newest = self.listener.newest_time()
                if newest is None:
                    if not self._prefetch():
                        self.listener.wait_newer(-math.inf, 0.2)
                    continue
                if k is None or newest < last_t - 1.0:  # first pose, or the vehicle's clock restarted
                    k = int(math.ceil(newest * self.fps))
                t = k / self.fps
                if newest < t:
                    if not self._prefetch():
                        self.listener.wait_newer(t, 0.2)
                    continue
                lag_frames = (newest - t) * self.fps
                if lag_frames > self.cfg.max_lag_frames:
                    k_new = self._next_when_behind(k, lag_frames, newest)
                    self.skipped += k_new - k
                    k, t = k_new, k_new / self.fps
                got = self.listener.at(t)
                if got is None:
                    k += 1
                    continue
                msg, rate = got
                self._emit(k, t, msg, rate)
                last_t = t
                k += 1
        finally:
            self.close()
        if self._delivery_error is not None:
            raise self._delivery_error
        return self.sent

    def _next_when_behind(self, k: int, lag_frames: float, newest: float) -> int:
        """The frame to render next when rendering is ``lag_frames`` behind simulated time.

        Why not the newest pose's frame, as before: that dropped every frame of a stall at once. With one core of
        the machine busy the camera stalled for up to 0.9 s now and then and so skipped 27 frames in a row, a gap
        a real camera (which encodes on its own hardware) never has; the keyframe gate then took a keyframe below
        its overlap target across it. Frames are dropped spread instead, a quarter of the lag per
        frame rendered: the camera catches up within a few frames, and what it delivers still holds frames from
        inside the stall (late, with exact capture times: the companion tags them with the telemetry it keeps).
        Only past ``catch_up_frames`` does it jump to the newest pose."""
        if lag_frames > self.cfg.catch_up_frames:
            return int(math.floor(newest * self.fps))
        return k + max(1, int(lag_frames // 4))

    def _prefetch(self) -> bool:
        """Use time the camera would spend waiting for the next pose to build one wall texture tile near the
        camera (about 30 ms at 1280 px); False when there is nothing left to build there."""
        if self._prefetch_level is None:
            return False
        built = self.renderer.prefetch_wall(self._prefetch_level, *self._wall_point)
        self.prefetched += built
        return built > 0

    def _emit(self, k: int, t: float, msg: dict, rate: float):
        """Render frame k here; JPEG encoding, streaming and recording happen on the delivery thread (the other
        core), in order. A full hand-over queue blocks, so a slow encoder makes the camera drop frames too."""
        pose = camera_pose(msg, self.frame, yaw_rate_deg_s=rate)
        along, _, up = self.frame.enu_to_facade(*pose.position_enu)
        self._wall_point = (float(along), float(up))
        rendered = self.renderer.render(pose, index=k, time_s=t, exposure=self.exposure)
        if self._delivery_error is not None:
            raise self._delivery_error
        self._outbox.put((k, t, pose, rendered))

    def _deliver_frames(self):
        while True:
            item = self._outbox.get()
            if item is None:
                return
            try:
                self._deliver(*item)
            except Exception as exc:  # noqa: BLE001 (re-raised on the render loop, which stops the camera)
                self._delivery_error = exc
                self.stop.set()

    def _deliver(self, k: int, t: float, pose: TruePose, rendered):
        ok, jpg = cv2.imencode(".jpg", rendered.image, [cv2.IMWRITE_JPEG_QUALITY, self.cfg.jpeg_quality])
        if not ok:
            return
        header = {"index": k, "capture_time_s": t, "time_boot_ms": int(round(t * 1000)),
                  "width": self.camera.width, "height": self.camera.height, "encoding": "jpeg"}
        self.server.broadcast(encode_message(header, jpg.tobytes()))
        if self.writer is not None and self._record_this(pose):
            self.writer.add(rendered, t, source_frame=k)
        self.sent += 1

    def _record_this(self, pose: TruePose) -> bool:
        if self.cfg.record_max_out_m is None:
            return True
        _, out, up = self.frame.enu_to_facade(*pose.position_enu)
        return 0.0 < float(out) <= self.cfg.record_max_out_m and float(up) > 0.3

    def close(self):
        if self._delivery.is_alive():
            self._outbox.put(None)  # after the frames already handed over
            self._delivery.join()
        self.listener.close()
        self.server.close()
        if self.writer is not None:
            self.writer.close()
            self.writer = None


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m sim camera", description=__doc__.split("\n\n")[0])
    p.add_argument("mission", type=Path, help="mission YAML (the facade and camera model)")
    p.add_argument("--pose-port", type=int, default=14660, help="UDP port of the vehicle's true-pose channel")
    p.add_argument("--stream-host", default="127.0.0.1", help="address the frame stream listens on")
    p.add_argument("--stream-port", type=int, default=DEFAULT_PORT, help="TCP port of the frame stream")
    p.add_argument("--width", type=int, default=640, help="working resolution (width in px; lens kept)")
    p.add_argument("--fps", type=float, help="frame rate in simulated time (default: the mission camera's)")
    p.add_argument("--seed", type=int, default=0, help="scene seed (wall material, windows, background)")
    p.add_argument("--record", type=Path, help="also write a recording with ground truth to this directory")
    p.add_argument("--record-max-out", type=float, metavar="M",
                   help="record only frames taken within M metres of the wall plane (the scan, not the transit)")
    p.add_argument("--jpeg-quality", type=int, default=88)
    p.add_argument("--duration", type=float, help="stop after this many wall seconds")
    p.add_argument("--renderer", choices=RENDERERS, default="warp",
                   help="warp: textures warped per plane (real time, default); raycast: per-pixel reference")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    cfg = LiveConfig(pose_port=args.pose_port, stream_host=args.stream_host, stream_port=args.stream_port,
                     width_px=args.width, fps=args.fps, seed=args.seed, record_dir=args.record,
                     jpeg_quality=args.jpeg_quality, duration_s=args.duration, record_max_out_m=args.record_max_out,
                     renderer=args.renderer)
    try:
        cam = LiveCamera(args.mission, cfg)
    except CompanionError as exc:
        print(f"error: {exc}")
        return 2
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: cam.stop.set())
    print(f"camera: poses on udp://127.0.0.1:{cam.listener.port}, frames on tcp://{cfg.stream_host}:"
          f"{cam.server.port} ({cam.camera.width}x{cam.camera.height} @ {cam.fps:g} fps)", flush=True)
    sent = cam.run()
    print(f"camera: {sent} frames sent, {cam.skipped} dropped (rendering behind simulated time)", flush=True)
    return 0

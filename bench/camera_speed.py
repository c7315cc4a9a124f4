"""Render speed of the simulated camera at several working resolutions, both renderers side by side in one run
(the per-pixel ray caster and the texture warp), and the fast recording generator.

    python bench/camera_speed.py [--mission missions/demo-facade.yaml] [--widths 640 1280 1920]
                                 [--renderers raycast warp] [--frames 20] [--live 30]

Poses come from the kinematic flight along the demo mission's first strip (left end of the wall: facade,
roof line and background in view), so the figures include the edge frames, not only plain wall. Prints CPU
(process) time and wall time per frame; the first frame (texture tiles generated) is reported separately, the
load average before and after, and the per-frame CPU ratio of each renderer to the first one.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import socket
import statistics
import tempfile
import threading
import time
from pathlib import Path

import cv2

from companion.mission import load_mission, plan_scan
from sim.camera.recording import camera_from_mission, generate_recording
from sim.camera.render import AutoExposure
from sim.camera.scene import Scene
from sim.camera.trajectory import KinematicFlight, scan_path
from sim.camera.warp_render import RENDERERS, make_renderer


def _camera_rig(mission, width: int, seed: int, renderer: str):
    """The mission's camera at ``width``, a renderer of its seeded scene, the kinematic flight of its planned scan
    and an auto-exposure: what every render benchmark here flies."""
    plan = plan_scan(mission)
    cam = camera_from_mission(mission, width)
    scene = Scene.build(plan.frame.length_m, float(mission.facade.height_m), seed=seed)
    r = make_renderer(renderer, scene, plan.frame, cam, exposure_s=float(mission.camera.exposure_s), seed=seed)
    return cam, r, KinematicFlight(plan.frame, scan_path(plan), seed=seed), AutoExposure(seed=seed)


def bench_width(mission, width: int, frames: int, seed: int, renderer: str = "raycast", view: str = "edge") -> dict:
    cam, r, flight, ae = _camera_rig(mission, width, seed, renderer)
    fps = float(mission.camera.fps)
    stride = 10  # 1/3 s apart: the view moves ~0.25 m between benchmark frames
    start = 0.0 if view == "edge" else flight.duration_s / 2  # middle: plain wall, the bulk of a scan
    times = [start + k / fps for k in range(0, frames * stride, stride)]
    c0, w0 = time.process_time(), time.perf_counter()
    f = r.render(flight.pose(times[0]), index=0, time_s=times[0], exposure=ae)
    first_cpu, first_wall = time.process_time() - c0, time.perf_counter() - w0
    cpu, wall, jpg = [], [], []
    for i, t in enumerate(times[1:], start=1):
        pose = flight.pose(t)
        c0, w0 = time.process_time(), time.perf_counter()
        f = r.render(pose, index=i, time_s=t, exposure=ae)
        cpu.append(time.process_time() - c0)
        wall.append(time.perf_counter() - w0)
        j0 = time.perf_counter()
        cv2.imencode(".jpg", f.image, [cv2.IMWRITE_JPEG_QUALITY, 92])
        jpg.append(time.perf_counter() - j0)
    return {
        "width": cam.width, "height": cam.height, "first_cpu_s": first_cpu, "first_wall_s": first_wall,
        "cpu_s": statistics.median(cpu), "wall_s": statistics.median(wall), "jpeg_s": statistics.median(jpg),
        "frames": len(cpu),
    }


def bench_scan(mission, width: int, every_s: float, seed: int, renderer: str) -> dict:
    """CPU per frame along the whole planned scan (kinematic flight), one frame every ``every_s`` seconds, each
    right after a frame 1/fps earlier (as in a 30 fps stream: that frame builds the texture tiles and patches
    the place needs, so the figure is the steady per-frame cost, tile building excluded for every renderer)."""
    import numpy as np

    cam, r, flight, ae = _camera_rig(mission, width, seed, renderer)
    dt = 1.0 / float(mission.camera.fps)
    cpu, jpg, wall_frac = [], [], []
    for i, t in enumerate(np.arange(dt, flight.duration_s, every_s)):
        r.render(flight.pose(float(t) - dt), index=2 * i, time_s=float(t) - dt, exposure=ae)
        pose = flight.pose(float(t))
        c0 = time.process_time()
        f = r.render(pose, index=2 * i + 1, time_s=float(t), exposure=ae)
        cpu.append(time.process_time() - c0)
        c0 = time.process_time()
        cv2.imencode(".jpg", f.image, [cv2.IMWRITE_JPEG_QUALITY, 88])
        jpg.append(time.process_time() - c0)
        wall_frac.append(float(np.mean(f.roi_mask > 0)))
    cpu, jpg, wall_frac = np.array(cpu), np.array(jpg), np.array(wall_frac)
    plain = wall_frac > 0.99
    return {"frames": len(cpu), "duration_s": flight.duration_s, "p": np.percentile(cpu, [10, 50, 90]),
            "mean": float(cpu.mean()), "jpeg": float(np.median(jpg)), "plain": int(plain.sum()),
            "with_jpeg": float((cpu + jpg).mean()), "plain_with_jpeg": float((cpu + jpg)[plain].mean()),
            "edge_with_jpeg": float((cpu + jpg)[~plain].mean()),
            "plain_median": float(np.median(cpu[plain])) if plain.any() else float("nan"),
            "edge_median": float(np.median(cpu[~plain])) if (~plain).any() else float("nan"),
            "in_budget": float(np.mean(cpu + jpg <= dt))}


def _climb_pose(frame, t: float, speed_m_s: float = 0.7) -> dict:
    """A vehicle climbing along the wall's middle at the scan speed, 4 m out (above the roof after ~15 s)."""
    lat, lon, alt = frame.facade_to_geodetic(frame.length_m / 2, 4.0, 1.5 + speed_m_s * t)
    return {"lat": float(lat), "lon": float(lon), "alt_amsl_m": float(alt), "vn_m_s": 0.0, "ve_m_s": 0.0,
            "vd_m_s": -speed_m_s, "yaw_deg": frame.yaw_facing_wall_deg, "gimbal_pitch_deg": 0.0,
            "gimbal_yaw_deg": 0.0}


def _scan_pose(flight, t: float) -> dict:
    """The mission's planned scan flown by the kinematic model (strips at the wall's ends and across it)."""
    p = flight.pose(min(t, flight.duration_s))
    v = p.velocity_enu_m_s
    return {"lat": p.lat, "lon": p.lon, "alt_amsl_m": p.alt_amsl_m, "vn_m_s": float(v[1]), "ve_m_s": float(v[0]),
            "vd_m_s": -float(v[2]), "yaw_deg": p.yaw_deg, "gimbal_pitch_deg": p.pitch_deg, "gimbal_yaw_deg": 0.0}


def _poses(port: int, pose_at, stop: threading.Event) -> None:
    """True poses at 50 Hz in real time from ``pose_at(t)``, as the simulated vehicle sends them."""
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    t0 = time.monotonic()
    k = 0
    while not stop.is_set():
        t = k * 0.02
        time.sleep(max(0.0, t0 + t - time.monotonic()))
        msg = {"t_s": round(t, 4), **pose_at(t)}
        s.sendto(json.dumps(msg).encode(), ("127.0.0.1", port))
        k += 1
    s.close()


def _cpu_s() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def bench_live(mission_path: Path, width: int, fps: float, seconds: float, renderer: str, path: str = "climb",
               lead_s: float = 0.0) -> dict:
    """The live camera process's own loop (render, then JPEG + stream on its delivery thread) fed real-time
    poses for ``seconds``: frames sent and dropped, and CPU of this process (camera + pose sender) per second
    and per frame sent. ``lead_s``: the camera runs this long before the first pose (a real flight's takeoff
    and transit), which it may use to build wall texture ahead (its CPU is reported separately)."""
    from sim.camera.live import LiveCamera, LiveConfig
    from sim.process import free_port

    pose_port = free_port()
    cam = LiveCamera(mission_path, LiveConfig(pose_port=pose_port, stream_port=free_port(socket.SOCK_STREAM),
                                              width_px=width, fps=fps, duration_s=lead_s + seconds,
                                              renderer=renderer))
    if path == "scan":
        plan = plan_scan(load_mission(mission_path))
        flight = KinematicFlight(plan.frame, scan_path(plan), seed=0)

        def pose_at(t):
            return _scan_pose(flight, t)
    else:
        def pose_at(t):
            return _climb_pose(cam.frame, t)
    stop = threading.Event()
    sender = threading.Thread(target=_poses, args=(pose_port, pose_at, stop), daemon=True)
    result: dict = {}
    runner = threading.Thread(target=lambda: result.update(sent=cam.run()), daemon=True)
    c0 = _cpu_s()
    runner.start()
    time.sleep(lead_s)
    c1 = _cpu_s()
    sender.start()
    runner.join()
    stop.set()
    cpu = _cpu_s() - c1
    sent = result.get("sent", 0)
    return {"sent": sent, "dropped": cam.skipped, "fps": sent / seconds, "cpu_per_s": cpu / seconds,
            "cpu_per_frame": cpu / max(sent, 1), "lead_cpu": c1 - c0,
            "prefetched": getattr(cam, "prefetched", "-")}


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--mission", type=Path, default=Path("missions/demo-facade.yaml"))
    p.add_argument("--widths", type=int, nargs="+", default=[640, 1280, 1920])
    p.add_argument("--renderers", nargs="+", choices=RENDERERS, default=["raycast", "warp"])
    p.add_argument("--views", nargs="+", choices=["edge", "middle"], default=["edge", "middle"],
                   help="edge: the first strip at the wall's left end (trees, far buildings, roof line); middle: "
                        "frames from the middle of the scan (plain wall)")
    p.add_argument("--frames", type=int, default=20, help="frames per width (the 3840 run uses a quarter)")
    p.add_argument("--generator-frames", type=int, default=100)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--scan-every", type=float, default=0.0, metavar="S",
                   help="also render the whole planned scan at --live-width, one frame every S seconds (each after "
                        "a frame 1/fps earlier), per-frame CPU percentiles, plain-wall and edge frames apart")
    p.add_argument("--live", type=float, default=0.0, metavar="S",
                   help="also run the live camera for S wall seconds per renderer on real-time poses (mid-wall)")
    p.add_argument("--live-width", type=int, default=1280)
    p.add_argument("--live-fps", type=float, default=30.0)
    p.add_argument("--live-path", choices=["climb", "scan"], default="climb",
                   help="climb: up the wall's middle at 0.7 m/s, 4 m out (above the roof after ~15 s); scan: the "
                        "mission's planned scan from its first strip (the wall's left end), kinematic flight")
    p.add_argument("--live-lead", type=float, default=0.0, metavar="S",
                   help="seconds the camera runs before the first pose (takeoff and transit in a real flight)")
    a = p.parse_args()
    mission = load_mission(a.mission)
    print(f"machine: {platform.platform()}, {platform.processor() or platform.machine()}, {os.cpu_count()} CPUs; "
          f"mission {a.mission}; load average {os.getloadavg()[0]:.1f}")
    print("view | renderer | width x height | first frame cpu/wall s | per frame cpu s | per frame wall s | "
          "frames/s (cpu) | jpeg s | cpu vs first renderer")
    for view in a.views if a.frames > 0 else []:  # --frames 0: only the live camera
        for w in a.widths:
            n = max(3, a.frames // 4) if w >= 2000 else a.frames
            base = None
            for kind in a.renderers:
                r = bench_width(mission, w, n + 1, a.seed, kind, view)
                base = base or r["cpu_s"]
                print(f"{view} | {kind} | {r['width']} x {r['height']} | {r['first_cpu_s']:.2f} / "
                      f"{r['first_wall_s']:.2f} | {r['cpu_s']:.3f} | {r['wall_s']:.3f} | {1 / r['cpu_s']:.1f} | "
                      f"{r['jpeg_s']:.4f} | "
                      f"{r['cpu_s'] / base:.2f}  (median of {r['frames']})", flush=True)
    for kind in a.renderers if a.scan_every > 0 else []:
        r = bench_scan(mission, a.live_width, a.scan_every, a.seed, kind)
        p10, p50, p90 = (1000 * v for v in r["p"])
        print(f"whole scan, {kind}, {a.live_width} px, {r['frames']} frames over {r['duration_s']:.0f} s: CPU per "
              f"frame p10/median/p90 {p10:.1f} / {p50:.1f} / {p90:.1f} ms, mean {1000 * r['mean']:.1f} ms; plain wall "
              f"({r['plain']} frames) median {1000 * r['plain_median']:.1f} ms, frames with an edge median "
              f"{1000 * r['edge_median']:.1f} ms; JPEG q88 {1000 * r['jpeg']:.1f} ms; render + JPEG within "
              f"1/{mission.camera.fps:g} s: {100 * r['in_budget']:.0f} % of frames; mean render + JPEG "
              f"{1000 * r['with_jpeg']:.1f} ms (plain wall {1000 * r['plain_with_jpeg']:.1f}, with an edge "
              f"{1000 * r['edge_with_jpeg']:.1f}) (load average "
              f"{os.getloadavg()[0]:.1f})", flush=True)
    for kind in a.renderers if a.live > 0 else []:
        r = bench_live(a.mission, a.live_width, a.live_fps, a.live, kind, a.live_path, a.live_lead)
        lead = (f"; {a.live_lead:g} s lead before the first pose: {r['lead_cpu']:.1f} CPU-s, "
                f"{r['prefetched']} wall tiles built ahead in all" if a.live_lead > 0 else "")
        print(f"live camera, {kind}, {a.live_path}, {a.live_width} px at {a.live_fps:g} fps for {a.live:g} s: "
              f"{r['sent']} frames sent ({r['fps']:.1f}/s), {r['dropped']} dropped, {r['cpu_per_s']:.2f} CPU-s per "
              f"second, {r['cpu_per_frame'] * 1000:.1f} CPU-ms per frame sent{lead} "
              f"(load average {os.getloadavg()[0]:.1f})", flush=True)
    print(f"load average after: {os.getloadavg()[0]:.1f}")
    with tempfile.TemporaryDirectory() as tmp:
        for kind in a.renderers if a.generator_frames > 0 else []:
            c0, w0 = time.process_time(), time.perf_counter()
            generate_recording(mission, Path(tmp) / kind, seed=a.seed, width_px=640, max_frames=a.generator_frames,
                               renderer=kind)
            print(f"generate_recording(width_px=640, max_frames={a.generator_frames}, renderer={kind}): "
                  f"{time.process_time() - c0:.1f} s cpu, {time.perf_counter() - w0:.1f} s wall "
                  f"(scene, sky, render, JPEG + depth + mask files)", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

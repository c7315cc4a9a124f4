"""What the simulator provides to companion (``companion/plugins.py`` names each need): recordings, SITL
vehicles and cameras, training scenes. Registered when ``sim`` is imported; each part is imported only when used."""

from __future__ import annotations

from pathlib import Path

from companion.plugins import SitlRequest, provide


def open_recording(path: str | Path):
    from sim.camera.recording import load_recording

    return load_recording(path)


def start_sitl(request: SitlRequest):
    """The simulated vehicle, and with ``request.camera_fps`` the simulated camera wired to it (a ``SitlRig``);
    started, so the caller connects to ``.url`` (and reads frames from ``.capture``) and calls ``.stop()``."""
    from companion.mission import load_mission, plan_scan
    from sim.process import SimulatorProcess, with_mission_wall
    from sim.rig import SitlRig

    if request.camera_fps is not None:
        return SitlRig(request.mission_path, log_dir=request.log_dir, speedup=request.speedup,
                       fps=request.camera_fps, width_px=request.camera_width_px, autopilot=request.autopilot,
                       sim_options=dict(request.options)).start()
    plan = plan_scan(load_mission(request.mission_path))
    home = plan.home
    vehicle = SimulatorProcess(speedup=request.speedup, home=f"{home.lat},{home.lon},{home.alt_amsl_m}",
                               autopilot=request.autopilot,
                               **with_mission_wall(dict(request.options), plan.mission)).start()
    vehicle.capture = None
    return vehicle


def ensure_recordings(mission_path, seeds, data_dir, *, width_px: int = 640, stride: int = 1):
    from sim.camera.training_recordings import ensure_recordings

    return ensure_recordings(mission_path, seeds, data_dir, width_px=width_px, stride=stride)


def training_views(cache_dir, seeds, n_views, height, width, max_depth):
    from sim.camera.training_views import cached_views

    return cached_views(cache_dir, seeds, n_views, height, width, max_depth)


def register() -> None:
    provide("open_recording", open_recording)
    provide("start_sitl", start_sitl)
    provide("ensure_recordings", ensure_recordings)
    provide("training_views", training_views)

"""Optional packages that extend companion, and what companion needs from them.

The simulator is one: companion names each need here, ``sim`` fills it in when it is imported (``sim/__init__.py``)
and adds its commands (``sim/commands.py``), so no module of companion imports sim and a companion installed without
sim still plans, flies, culls and stitches. Plugins are imported by the names in ``PLUGIN_MODULES`` (the CLI's
plugin hook, and the first time a need is asked for); a need nobody provided is an error naming it.

Needs (name: signature):

* ``open_recording``: ``(path) -> recording`` with ``len()``, ``image(i)``, ``depth(i)``, ``roi_mask(i)``,
  ``capture_time(i)``, ``camera_pose(i)``, ``meta``, ``K``, ``width``, ``height``, ``frame`` (a ``FacadeFrame``).
* ``start_sitl``: ``(SitlRequest) -> running`` with ``url``, ``capture`` (a frame source spec or None), ``stop()``.
* ``ensure_recordings``: ``(mission_path, seeds, data_dir, *, width_px, stride) -> [recording paths]``.
* ``training_views``: ``(cache_dir, seeds, n_views, height, width, max_depth) -> FrameSet`` (rendered scenes).
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from types import ModuleType
from typing import Any

from companion.errors import CompanionError

# module -> the top-level commands it adds (its ``register(subparsers)``); the CLI names them when it is missing
PLUGIN_MODULES: dict[str, tuple[str, ...]] = {"sim.commands": ("sim", "record", "demo", "eval")}
_LOADED: dict[str, ModuleType | None] = {}


def load_plugin(module: str) -> ModuleType | None:
    """Import the plugin ``module``; None when its package is not installed. A plugin that is installed but fails
    to import raises, so its real error shows."""
    if module not in _LOADED:
        try:
            _LOADED[module] = importlib.import_module(module)
        except ModuleNotFoundError as exc:
            if exc.name != module.split(".")[0]:
                raise
            _LOADED[module] = None
    return _LOADED[module]


@dataclass(frozen=True)
class SitlRequest:
    """A simulated vehicle (and camera) for one flight of ``mission_path``, homed where the plan takes off."""

    mission_path: Path
    autopilot: str = "px4"  # the firmware flavour the simulator follows: px4 | ardupilot
    speedup: float = 10.0  # simulated seconds per wall second
    options: dict[str, str] = field(default_factory=dict)  # more `python -m sim vehicle` options (gusts=5)
    camera_fps: float | None = None  # None: no simulated camera; else its frame rate in simulated time
    camera_width_px: int = 640
    log_dir: Path | None = None  # the camera's and vehicle's logs (needed with a camera)


_PROVIDED: dict[str, Callable[..., Any]] = {}


def provide(name: str, function: Callable[..., Any]) -> None:
    """Called by the simulator package for each need it fills."""
    _PROVIDED[name] = function


def provided(name: str, needed_for: str) -> Callable[..., Any]:
    """The function that fills ``name``, or a clear error saying ``needed_for`` needs the simulator package."""
    if name not in _PROVIDED:
        for module in PLUGIN_MODULES:
            load_plugin(module)
    try:
        return _PROVIDED[name]
    except KeyError:
        raise CompanionError(
            f"{needed_for} needs the simulator package `sim` ({name}), which is not installed here",
            "install companion with its simulator (the companion wheel ships sim; in a checkout: pip install -e .)",
        ) from None

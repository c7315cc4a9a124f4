"""What companion needs from the simulator, provided by the simulator: companion names each need here, ``sim``
fills it in when it is imported (``sim/__init__.py``), so no module of companion imports sim and a companion
installed without sim still plans, flies, culls and stitches. A need nobody provided is an error naming it.

Needs (name: signature):

* ``open_recording``: ``(path) -> recording`` with ``len()``, ``image(i)``, ``depth(i)``, ``roi_mask(i)``,
  ``capture_time(i)``, ``camera_pose(i)``, ``meta``, ``K``, ``width``, ``height``, ``frame`` (a ``FacadeFrame``).
* ``start_sitl``: ``(SitlRequest) -> running`` with ``url``, ``capture`` (a frame source spec or None), ``stop()``.
* ``ensure_recordings``: ``(mission_path, seeds, data_dir, *, width_px, stride) -> [recording paths]``.
* ``training_views``: ``(cache_dir, seeds, n_views, height, width, max_depth) -> FrameSet`` (rendered scenes).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from companion.errors import CompanionError


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
    try:
        return _PROVIDED[name]
    except KeyError:
        raise CompanionError(
            f"{needed_for} needs the simulator package `sim` ({name}), which is not installed here",
            "install companion with its simulator (the companion wheel ships sim; in a checkout: pip install -e .)",
        ) from None

"""Which mission a recorded flight flew, for ``companion cull``.

The mission is what gives a spool its scale: the camera's make, model and true focal in every keyframe's EXIF,
and ``spool.json`` (camera, facade, standoff) that the stitcher rectifies the map with. Culled without it, a spool
silently makes a map in pixels, OpenDroneMap guesses the focal and nothing says why (issue 29). So the mission is
``--mission``, or found in a ``companion record`` recording's ``meta.json`` (beside the frames folder), or the cull
is refused with that fix; ``--no-mission`` asks for the pixel-only spool on purpose.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

from companion.errors import CompanionError

RECORDING_META = "meta.json"
# how far (m) a recording's wall start may lie from the named mission's before the two are different walls
SAME_WALL_M = 1.0
NO_MISSION_FIX = ("pass --mission FILE: the mission YAML this flight flew (or a shipped mission's name, e.g. "
                  "demo-facade); --no-mission culls anyway, for a map in pixels with no scale")


@dataclass(frozen=True)
class CullMission:
    """The mission a cull uses (None: none, asked for with ``--no-mission``) and where it was found."""

    path: Path | None
    found_in: str  # "--mission", the recording's meta.json, or "--no-mission"


def find_cull_mission(video: str, mission: Path | None, *, allow_none: bool = False) -> CullMission:
    """``mission`` when given; none when asked for (``allow_none``: ``--no-mission``); else the mission of the
    recording ``video`` belongs to; else refused (see the module docstring)."""
    if mission is not None:
        return CullMission(Path(mission), "--mission")
    if allow_none:
        return CullMission(None, "--no-mission")
    if "://" not in video and not Path(video).exists():  # said first: no mission could be found for it anyway
        raise CompanionError(f"{video} does not exist",
                             "give the recorded flight's video file or image folder (a `companion record` "
                             "recording's: REC/frames)")
    meta_path = recording_meta_path(Path(video))
    if meta_path is not None:
        return CullMission(mission_of_recording(meta_path), str(meta_path))
    raise CompanionError(
        f"no mission for {video}: without one the spool has no scale (no camera make, model or focal in the EXIF, "
        "no spool.json), so `companion stitch` can only make a map in pixels and OpenDroneMap guesses the focal",
        NO_MISSION_FIX)


def recording_meta_path(video: Path) -> Path | None:
    """``meta.json`` of the ``companion record`` recording whose frames ``video`` is (REC/frames or REC)."""
    for folder in (video, video.parent):
        candidate = folder / RECORDING_META
        if video.is_dir() and candidate.is_file():
            return candidate
    return None


def mission_of_recording(meta_path: Path) -> Path:
    """The mission file a recording was made from: its ``mission_file``, else the shipped mission it names; the
    wall it recorded must be that mission's."""
    from companion.resources import shipped_missions

    try:
        meta = json.loads(meta_path.read_text(encoding="utf-8"))
        name = str(meta.get("mission", ""))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, AttributeError) as exc:
        raise CompanionError(f"{meta_path} is not a recording's meta.json ({exc})", NO_MISSION_FIX) from None
    recorded = meta.get("mission_file")
    if recorded and Path(recorded).is_file():
        path = Path(recorded)
    elif name in shipped_missions():
        path = shipped_missions()[name]
    else:
        raise CompanionError(
            f"{meta_path} says the recording flew mission {name!r}, which is not a shipped mission and whose file "
            f"{recorded or '(not recorded)'} is not there", NO_MISSION_FIX)
    _check_same_wall(meta, meta_path, path)
    return path


def _check_same_wall(meta: dict, meta_path: Path, mission_path: Path) -> None:
    """Refuses a mission whose wall start is not the recording's (a mission edited since, or a name reused)."""
    from companion.geo import FacadeFrame
    from companion.mission import load_mission
    from companion.mission.geometry import wall_ends

    origin = (meta.get("facade") or {}).get("origin")
    if not isinstance(origin, dict):
        return  # an older recording without its wall: the name is all there is
    frame = FacadeFrame.from_wall(*wall_ends(load_mission(mission_path)))
    try:
        offset = frame.geodetic_to_facade(float(origin["lat"]), float(origin["lon"]), frame.origin.alt_amsl_m)
    except (KeyError, TypeError, ValueError):
        return
    distance = float(sum(float(v) ** 2 for v in offset) ** 0.5)
    if distance > SAME_WALL_M:
        raise CompanionError(
            f"the wall recorded in {meta_path} starts {distance:.1f} m from the wall of mission {mission_path}",
            NO_MISSION_FIX)

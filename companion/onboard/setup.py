"""Builds a CullChain from a mission and options (shared by `companion cull`, `companion fly --capture`, demo)."""

from __future__ import annotations

from pathlib import Path

from companion.capture.tagging import FrameTagger
from companion.keyframes.gate import GateConfig, KeyframeGate
from companion.onboard.chain import CullChain
from companion.onboard.standoff_watch import StandoffWatch
from companion.onboard.working import WorkingCopy
from companion.spool import KeyframeSpool
from companion.spool.camera import camera_tags_for_mission
from companion.spool.clock import CaptureClock


def spool_meta(mission) -> dict:
    """spool.json for the stitching worker: camera, facade and standoff (docs/STITCH.md)."""
    from companion.mission.geometry import wall_ends

    start, end = wall_ends(mission)
    cam = mission.camera
    return {
        "mission": mission.name,
        "camera": {"width_px": cam.width_px, "height_px": cam.height_px, "hfov_deg": cam.hfov_deg},
        "facade": {
            "start": {"lat": start.lat, "lon": start.lon},
            "end": {"lat": end.lat, "lon": end.lon},
            "ground_alt_amsl_m": mission.facade.ground_alt_amsl_m,
            "height_m": mission.facade.height_m,
        },
        "standoff_m": mission.standoff_m,
    }


def scan_scope(mission):
    """The frames of this mission's scan (``companion.keyframes.gate_scope``): its wall, standoff, scan extent and
    lens."""
    from companion.geo import FacadeFrame
    from companion.keyframes.gate_scope import ScanScope
    from companion.mission.geometry import wall_ends
    from companion.mission.planner import scan_extent

    cam = mission.camera
    wall = FacadeFrame.from_wall(*wall_ends(mission))
    extent = scan_extent(mission, wall.length_m)
    return ScanScope(wall, float(mission.standoff_m),
                     extent=(extent.along_min_m, extent.along_max_m, extent.up_min_m, extent.up_max_m),
                     hfov_deg=cam.hfov_deg, aspect=cam.height_px / cam.width_px,
                     wall=(0.0, wall.length_m, 0.0, float(mission.facade.height_m)))


def build_chain(
    out: Path,
    tagger: FrameTagger,
    *,
    mission_path: Path | None = None,
    mission=None,
    model: Path | None = None,
    mask: bool = True,
    capture_clock: CaptureClock | None = None,
    on_keyframe=None,
    on_warning=None,
    parallax: bool = True,
) -> CullChain:
    """Every frame is followed by the wall tracker and only the frames around keyframe decisions are measured.
    ``parallax``: with a mission (its camera's field of view), the depth mask is confirmed or corrected by the
    motion parallax against a frame a few centimetres back along the telemetry's baseline, and frames whose
    trusted pixels are all far are dropped (``companion.depth.parallax``, docs/DEPTH.md); False: network alone.
    With a mission whose standoff is beyond 4 m, each frame is also masked only where the mission's wall can be in
    view from its pose (``companion.depth.pose_bound``)."""
    if mission is None and mission_path is not None:
        from companion.mission import load_mission

        mission = load_mission(mission_path)
    gate_cfg = GateConfig.for_mission(mission) if mission is not None else GateConfig()
    if model is None and mission is not None and mission.depth_model is not None:
        model = Path(mission.depth_model)  # the mission's choice; a command's --model wins
    masker = None
    model_name = None
    if mask:
        from companion.depth.masker import Masker

        seq = None
        if parallax and mission is not None:
            from companion.depth.parallax import SequenceParallax

            seq = SequenceParallax(mission.camera.hfov_deg, standoff_m=mission.standoff_m)
        bound = None
        if mission is not None:
            from companion.depth.pose_bound import TelemetryWallBound

            bound = TelemetryWallBound.for_mission(mission)
        masker = Masker(model, parallax=seq, bound=bound)
        model_name = str(model) if model is not None else "shipped default"
    working = WorkingCopy()
    settings = {"rth": gate_cfg.rth, "depth_model": model_name, "mask": mask,
                "parallax": bool(masker is not None and masker.parallax is not None),
                "working_long_side_px": working.long_side_px}
    spool = KeyframeSpool(
        out,
        meta=spool_meta(mission) if mission is not None else None,
        settings=settings,
        camera_tags=camera_tags_for_mission(mission.camera) if mission is not None else None,
        capture_clock=capture_clock,
    )
    crosscheck = scope = watch = None
    if mission is not None:
        from companion.onboard.crosscheck import OverlapCrossCheck

        cam = mission.camera
        scope = scan_scope(mission)
        wall = scope.frame
        crosscheck = OverlapCrossCheck(
            wall,
            cam.hfov_deg,
            cam.height_px / cam.width_px,
            standoff_m=float(mission.standoff_m),
        )
        watch = StandoffWatch(wall, cam.hfov_deg, float(mission.standoff_m))
    return CullChain(
        tagger,
        masker,
        KeyframeGate(gate_cfg, predictor=None if crosscheck is None else crosscheck.predictor),
        spool,
        on_keyframe=on_keyframe,
        on_warning=on_warning,
        crosscheck=crosscheck,
        working=working,
        scope=scope,
        standoff_watch=watch,
    )

"""A map without scale says so: why it has none, how to get one, and its areas in map pixels, never in metres.

Without the wall and the camera-wall distance (a spool culled without a mission has no ``spool.json``) the
stitcher lays the keyframes out in an arbitrary plane unit; printing those numbers as "m" or "m2" (issue 29:
"343 724 m2 uncovered") sends the user to re-fly areas that do not exist, so every output of such a map speaks
in pixels and names the fix.
"""

from __future__ import annotations

from dataclasses import dataclass

from companion.spool.reader import StitchInput
from companion.stitch.output import UncoveredArea
from companion.stitch.render import MapGrid


@dataclass(frozen=True)
class ScaleNote:
    """Why a map has no scale, and what gives it one."""

    why: str
    fix: str

    def as_dict(self) -> dict:
        return {"why": self.why, "fix": self.fix}

    def text(self) -> str:
        return f"the map has no scale: {self.why}; lengths and areas are in map pixels; to get metres: {self.fix}"


def scale_note(inp: StitchInput, use_poses_asked: bool) -> ScaleNote:
    """The reason the scale of ``inp``'s map is unknown (call only when it is)."""
    if inp.facade is None:
        return ScaleNote(
            "the spool has no spool.json (no wall, camera or standoff: it was culled without a mission)",
            "cull the flight again with --mission FILE (the mission it flew), then stitch that spool")
    if not use_poses_asked:
        return ScaleNote("it was stitched with --no-poses and the spool gives no standoff",
                         "stitch without --no-poses")
    return ScaleNote("no keyframe carries a telemetry pose",
                     "cull with the flight's telemetry log (--telemetry) and --time-offset that places the frames")


def area_px(area: UncoveredArea, grid: MapGrid) -> dict:
    """An area of the map in map image pixels: x right, y down, from the image's top-left corner (the areas are
    cut along pixel edges: ``output.uncovered_areas``)."""
    s = grid.m_per_px
    return {
        "x_min_px": round((area.along_min_m - grid.along0_m) / s, 1),
        "x_max_px": round((area.along_max_m - grid.along0_m) / s, 1),
        "y_min_px": round((grid.up_top_m - area.up_max_m) / s, 1),
        "y_max_px": round((grid.up_top_m - area.up_min_m) / s, 1),
        "area_px2": round(area.area_m2 / (s * s)),
    }


def area_text(area: dict) -> str:
    """One line of ``companion stitch``'s listing for a pixel area."""
    return (f"x {area['x_min_px']:.0f}..{area['x_max_px']:.0f} px, y {area['y_min_px']:.0f}..{area['y_max_px']:.0f} "
            f"px ({area['area_px2']} px2)")

"""Re-fly missions: the uncovered areas of a stitched facade map become a short mission that scans only them.

The stitcher (``companion stitch``) lists the wall rectangles no keyframe shows in ``report.json``
(``uncovered_areas_m``, wall metres: along from the wall start, up from the wall base) and anchors its map on the
Earth in ``map_georef.json``. Here those rectangles are grown by the mission's overlap (so the first and last
re-fly frames share the planned overlap with the map already made, and the stitcher can register them), nearby
ones are grouped, and the planner scans only the groups, at the mission's standoff and overlap, with its takeoff,
transit, landing, standoff and geofence rules (``planner.plan_scan(mission, regions)``).

Between groups the vehicle moves along the wall at the standoff, at scan speed, like between strips: the frames
it takes there show map already made (the stitcher registers them like any overlapping keyframe). Areas below the
lowest frame the bottom clearance allows (or outside the wall and its margins) cannot be re-flown and are listed
with the reason; a map with nothing left to fly gives no mission.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

from companion.errors import CompanionError
from companion.geo import FacadeFrame
from companion.mission.exports import render_outputs, write_outputs
from companion.mission.geometry import wall_frame
from companion.mission.planner import ScanPlan, WallRegion, camera_footprint, plan_scan, scan_extent
from companion.mission.spec import Mission, load_mission

REPORT_JSON = "report.json"
GEOREF_JSON = "map_georef.json"  # written by companion.stitch.output (read-only here)
# How far the map's wall anchor may sit from the mission's wall before the map is taken for another wall:
# the anchor comes from the same mission file, so anything beyond GNSS-survey noise means a different wall.
WALL_MATCH_TOLERANCE_M = 1.0
# The rule for what is worth a flight: an uncovered area is flown when its narrow side is at least MIN_AREA_SIZE_M
# and its area at least MIN_AREA_M2; anything smaller is listed as left out, not flown. Why: thinner areas are
# slivers (the map's edge missing the wall's by rounding, a seam between strips a few cells wide; the stitcher's
# cells are 10 cm, so 20 cm is two cells) and a re-fly for one costs whole strips (a 0.1 m x 7.5 m seam gave two
# full-height strips 0.13 m apart), and on PX4 a low patch waits for its 120 s home window; a smaller patch than
# 0.5 m x 0.5 m is better looked at in the keyframes around it.
MIN_AREA_SIZE_M = 0.2
MIN_AREA_M2 = 0.25
# A clip to the scan extent by less than this (below the stitcher's 10 cm cells) is rounding, not worth a note.
CLIP_NOTE_M = 0.05
_STITCH_FIX = "make the map with `companion stitch SPOOL --out MAPDIR` and give that MAPDIR to --refly"


@dataclass(frozen=True)
class MapGaps:
    """What a map folder says is missing: the uncovered wall rectangles and the wall the map is of."""

    map_dir: Path
    areas: tuple[WallRegion, ...]
    coverage_fraction: float | None
    wall: dict | None  # map_georef.json's "wall" anchor (start/end lat lon, ground altitude), when present


@dataclass(frozen=True)
class ReflyGroup:
    """Uncovered areas flown together, and the wall rectangle the re-fly frames cover for them."""

    areas: tuple[WallRegion, ...]
    region: WallRegion  # the areas' bounding box grown by the overlap margins, within the scan extent


@dataclass(frozen=True)
class ReflyPlan:
    """A re-fly: the plan (None when there is nothing to re-fly), its groups, and what was left out and why."""

    plan: ScanPlan | None
    groups: tuple[ReflyGroup, ...]
    margins_m: tuple[float, float]  # (along, up) overlap with the existing map around each area
    skipped: tuple[str, ...]  # areas no frame can show (e.g. below the bottom clearance), with the reason
    notes: tuple[str, ...]
    message: str


def _read_json(path: Path, what: str) -> dict:
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as exc:
        raise CompanionError(f"{path} is not valid JSON ({exc}): the {what} is damaged", _STITCH_FIX) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise CompanionError(f"cannot read {path}: {exc}", _STITCH_FIX) from None
    if not isinstance(doc, dict):
        raise CompanionError(f"{path} is not a JSON object: the {what} is damaged", _STITCH_FIX)
    return doc


def read_map_gaps(map_dir: str | Path) -> MapGaps:
    """Reads the uncovered areas of a ``companion stitch`` output folder; a folder that is not one is an error
    naming the missing file."""
    map_dir = Path(map_dir)
    if not map_dir.is_dir():
        raise CompanionError(f"map folder {map_dir} does not exist", _STITCH_FIX)
    report_path = map_dir / REPORT_JSON
    if not report_path.is_file():
        raise CompanionError(
            f"{report_path} is missing: {map_dir} is not a stitched map folder (the stitcher lists the uncovered "
            f"areas in {REPORT_JSON})",
            _STITCH_FIX,
        )
    report = _read_json(report_path, "stitch report")
    unscaled = report.get("scale_unknown")
    if isinstance(unscaled, dict):  # a map in pixels: its reason and fix, not a guess at one
        raise CompanionError(f"the map in {map_dir} has no scale ({unscaled.get('why')}), so its uncovered areas "
                             "are not in wall metres and cannot be flown", str(unscaled.get("fix")))
    if not (report.get("map") or {}).get("rectified_to_facade"):
        raise CompanionError(
            f"the map in {map_dir} is not rectified to the facade (stitched with --no-poses, or from keyframes "
            "without telemetry poses), so its uncovered areas are not in wall metres and cannot be flown",
            "stitch the spool again without --no-poses, then plan the re-fly from that map",
        )
    raw = report.get("uncovered_areas_m")
    if not isinstance(raw, list):
        raise CompanionError(f"{report_path} has no 'uncovered_areas_m' list", f"re-run the stitch: {_STITCH_FIX}")
    areas = []
    for k, a in enumerate(raw):
        try:
            region = WallRegion(
                float(a["along_min_m"]), float(a["along_max_m"]), float(a["up_min_m"]), float(a["up_max_m"])
            )
        except (KeyError, TypeError, ValueError):
            raise CompanionError(
                f"{report_path}: uncovered area {k} is not {{along_min_m, along_max_m, up_min_m, up_max_m}}: {a!r}",
                f"re-run the stitch: {_STITCH_FIX}",
            ) from None
        values = (region.along_min_m, region.along_max_m, region.up_min_m, region.up_max_m)
        if (
            not all(math.isfinite(v) for v in values)
            or region.along_max_m <= region.along_min_m
            or (region.up_max_m <= region.up_min_m)
        ):
            raise CompanionError(f"{report_path}: uncovered area {k} is empty or not finite: {a!r}", _STITCH_FIX)
        areas.append(region)
    georef_path = map_dir / GEOREF_JSON
    wall = _read_json(georef_path, "map georeferencing").get("wall") if georef_path.is_file() else None
    coverage = report.get("coverage_fraction")
    return MapGaps(map_dir, tuple(areas), float(coverage) if coverage is not None else None, wall)


def check_same_wall(gaps: MapGaps, mission: Mission, frame: FacadeFrame) -> None:
    """The map's wall anchor (map_georef.json) must be the mission's wall: areas are metres along *that* wall."""
    wall = gaps.wall
    if not wall:
        return
    try:
        ends = [(float(wall[k]["lat"]), float(wall[k]["lon"])) for k in ("start", "end")]
        ground = float(wall["ground_alt_amsl_m"])
    except (KeyError, TypeError, ValueError):
        raise CompanionError(f"{gaps.map_dir / GEOREF_JSON}: its 'wall' anchor is incomplete", _STITCH_FIX) from None
    expected = ((0.0, 0.0), (frame.length_m, 0.0))
    for (lat, lon), (a_exp, o_exp), name in zip(ends, expected, ("start", "end"), strict=True):
        a, o, _ = frame.geodetic_to_facade(lat, lon, frame.origin.alt_amsl_m)
        off = math.hypot(float(a) - a_exp, float(o) - o_exp)
        if off > WALL_MATCH_TOLERANCE_M:
            raise CompanionError(
                f"the map in {gaps.map_dir} is of another wall: its wall {name} is {off:.1f} m from mission "
                f"{mission.name}'s facade.{name}",
                "give the mission file the map was flown with (or the map of this mission's wall)",
            )
    if abs(ground - mission.facade.ground_alt_amsl_m) > WALL_MATCH_TOLERANCE_M:
        raise CompanionError(
            f"the map in {gaps.map_dir} has its wall base at {ground:.1f} m AMSL, mission {mission.name} at "
            f"{mission.facade.ground_alt_amsl_m:.1f} m: the areas' heights would be flown at the wrong altitude",
            "give the mission file the map was flown with (facade.ground_alt_amsl_m must match)",
        )


def overlap_margins(mission: Mission) -> tuple[float, float]:
    """(along, up) metres of existing map each re-fly frame at an area's edge keeps showing: the side overlap
    across strips and the keyframe overlap along them, the same overlaps the mission plans between its frames."""
    fp = camera_footprint(mission)
    if mission.pattern == "vertical":
        return fp.width_m * mission.side_overlap, fp.height_m * mission.overlap
    return fp.width_m * mission.overlap, fp.height_m * mission.side_overlap


def _grow(r: WallRegion, along: float, up: float) -> WallRegion:
    return WallRegion(r.along_min_m - along, r.along_max_m + along, r.up_min_m - up, r.up_max_m + up)


def _clip(r: WallRegion, to: WallRegion) -> WallRegion | None:
    c = WallRegion(
        max(r.along_min_m, to.along_min_m),
        min(r.along_max_m, to.along_max_m),
        max(r.up_min_m, to.up_min_m),
        min(r.up_max_m, to.up_max_m),
    )
    return c if c.along_max_m > c.along_min_m and c.up_max_m > c.up_min_m else None


def _bbox(rs: list[WallRegion]) -> WallRegion:
    return WallRegion(
        min(r.along_min_m for r in rs),
        max(r.along_max_m for r in rs),
        min(r.up_min_m for r in rs),
        max(r.up_max_m for r in rs),
    )


def _touch(a: WallRegion, b: WallRegion) -> bool:
    return (
        a.along_min_m <= b.along_max_m
        and b.along_min_m <= a.along_max_m
        and a.up_min_m <= b.up_max_m
        and b.up_min_m <= a.up_max_m
    )


def group_areas(areas: list[WallRegion], margins: tuple[float, float], extent: WallRegion) -> list[ReflyGroup]:
    """Areas whose grown rectangles touch are flown as one group (their strips would cover the same wall anyway);
    each group's region is the bounding box of its areas grown by ``margins``, clipped to the scan extent."""
    groups = [[a] for a in areas]
    merged = True
    while merged:  # merging two groups grows their box, which may now touch a third
        merged = False
        for i in range(len(groups)):
            for j in range(i + 1, len(groups)):
                if _touch(_grow(_bbox(groups[i]), *margins), _grow(_bbox(groups[j]), *margins)):
                    groups[i] += groups.pop(j)
                    merged = True
                    break
            if merged:
                break
    out = []
    for g in groups:
        region = _clip(_grow(_bbox(g), *margins), extent)
        if region is not None:
            out.append(ReflyGroup(tuple(sorted(g, key=lambda r: (r.along_min_m, r.up_min_m))), region))
    return sorted(out, key=lambda g: g.region.along_min_m)


def metres(v: float) -> str:
    """``v`` to the centimetre, never "-0.00" (a wall edge at -0.001 m is the edge)."""
    return f"{round(v, 2) + 0.0:.2f}"


def format_region(r: WallRegion) -> str:
    return (f"along {metres(r.along_min_m)}..{metres(r.along_max_m)} m, "
            f"up {metres(r.up_min_m)}..{metres(r.up_max_m)} m")


def _too_small(a: WallRegion, min_size_m: float, min_area_m2: float) -> str | None:
    """Why ``a`` is not worth a flight (see MIN_AREA_SIZE_M), or None."""
    thin = min(a.along_max_m - a.along_min_m, a.up_max_m - a.up_min_m)
    area = (a.along_max_m - a.along_min_m) * (a.up_max_m - a.up_min_m)
    if thin < min_size_m:
        return f"only {100 * thin:.1f} cm thin, under the {100 * min_size_m:g} cm minimum (a sliver)"
    if area < min_area_m2:
        return f"only {area:.2f} m2, under the {min_area_m2:g} m2 minimum"
    return None


def _clipped_by(a: WallRegion, clipped: WallRegion) -> float:
    return max(abs(x - y) for x, y in zip((a.along_min_m, a.along_max_m, a.up_min_m, a.up_max_m),
                                          (clipped.along_min_m, clipped.along_max_m, clipped.up_min_m,
                                           clipped.up_max_m), strict=True))


def plan_refly(mission: Mission, map_dir: str | Path, *, min_size_m: float = MIN_AREA_SIZE_M,
               min_area_m2: float = MIN_AREA_M2) -> ReflyPlan:
    """Plans the re-fly of ``map_dir``'s uncovered areas with ``mission``'s standoff, overlap, camera and rules;
    areas thinner than ``min_size_m`` (along or up) or smaller than ``min_area_m2`` are left out and listed."""
    gaps = read_map_gaps(map_dir)
    frame = wall_frame(mission)
    check_same_wall(gaps, mission, frame)
    notes = []
    if gaps.wall is None:
        notes.append(f"{GEOREF_JSON} not found in {gaps.map_dir}: could not check the map is of this mission's wall")
    extent = scan_extent(mission, frame.length_m)
    margins = overlap_margins(mission)
    reachable, skipped = [], []
    for a in gaps.areas:
        small = _too_small(a, min_size_m, min_area_m2)
        if small is not None:
            skipped.append(f"{format_region(a)}: {small}")
            continue
        clipped = _clip(a, extent)
        if clipped is None:
            why = (
                f"below the lowest frame edge ({metres(extent.up_min_m)} m; margins.bottom_clearance_m="
                f"{mission.margins.bottom_clearance_m} m): lower the clearance or inspect it from the ground"
                if a.up_max_m <= extent.up_min_m
                else "outside the wall and its margins"
            )
            skipped.append(f"{format_region(a)}: {why}")
            continue
        if _clipped_by(a, clipped) >= CLIP_NOTE_M:
            notes.append(f"{format_region(a)}: only {format_region(clipped)} can be flown "
                         f"(scan extent {format_region(extent)})")
        reachable.append(clipped)
    coverage = f" (coverage {100 * gaps.coverage_fraction:.1f} %)" if gaps.coverage_fraction is not None else ""
    if not reachable:
        why = "has no uncovered area" if not gaps.areas else "has no uncovered area a re-fly can reach"
        return ReflyPlan(
            None,
            (),
            margins,
            tuple(skipped),
            tuple(notes),
            f"the map in {gaps.map_dir} {why}{coverage}: nothing to re-fly, no mission written",
        )
    groups = group_areas(reachable, margins, extent)
    name = f"{mission.name[:74]}-refly"
    plan = plan_scan(mission.model_copy(update={"name": name}), [g.region for g in groups])
    message = (
        f"re-fly of {len(reachable)} uncovered area(s) of {gaps.map_dir}{coverage} in {len(groups)} group(s), "
        f"{margins[0]:.2f} m along / {margins[1]:.2f} m up of overlap with the existing map"
    )
    return ReflyPlan(plan, tuple(groups), margins, tuple(skipped), tuple(notes), message)


def refly_to_dir(
    mission_path: Path, map_dir: Path, out: Path, *, min_size_m: float = MIN_AREA_SIZE_M,
    min_area_m2: float = MIN_AREA_M2,
) -> tuple[ReflyPlan, list[Path]]:
    """Plans the re-fly and writes its exports to ``out`` (all or none); nothing is written when there is nothing
    to re-fly."""
    refly = plan_refly(load_mission(mission_path), map_dir, min_size_m=min_size_m, min_area_m2=min_area_m2)
    if refly.plan is None:
        return refly, []
    files = render_outputs(refly.plan)  # everything rendered before anything is written
    return refly, write_outputs(files, out)

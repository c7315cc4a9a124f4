"""The report stage: what the map covers, where it is still open, and one ``StitchReport`` of every stage.

``report.json`` is ``StitchReport.as_dict()``: the keyframes used, skipped and dropped (with reasons), every pair
tried, the alignment's residuals before and after the mesh (px, and mm where the scale is known), the map's
grid, coverage and uncovered areas (the re-fly input), exposure gains, per-stage timings and the files written.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields
from pathlib import Path

import cv2
import numpy as np

from companion.errors import CompanionError
from companion.files import atomic_path
from companion.stitch.align import AlignedKeyframes
from companion.stitch.canvas import RenderedMap
from companion.stitch.config import StitchConfig
from companion.stitch.geometry import apply_h
from companion.stitch.inputs import StitchInput
from companion.stitch.layout import MapLayout
from companion.stitch.output import (
    RELIEF_BGR,
    UncoveredArea,
    annotate_uncovered,
    draw_scale_bar,
    uncovered_areas,
)
from companion.stitch.pairs import PairResult
from companion.stitch.render import PlacedKeyframe
from companion.stitch.unscaled import area_px, scale_note
from companion.stitch.wall_anchor import WallPlacement
from companion.stitch.wall_distance import WallDistance


@dataclass(frozen=True)
class MapCoverage:
    fraction: float  # share of the map's grid (the facade, or the content without telemetry) drawn
    uncovered: list[UncoveredArea]  # wall no keyframe showed: re-fly areas
    # wall at least ``RELIEF_VIEWS`` keyframes showed but none kept as the wall plane (the depth mask or the wall
    # check cut it: a portal, a recess, window glass): a re-fly at the same standoff cannot fill it
    relief: list[UncoveredArea] = ()


RELIEF_VIEWS = 2  # keyframes whose frames must show a place (and all cut it) for it to count as relief
_VIEWS_MAX_PX = 2000  # the views are counted on a copy of the coverage grid at most this wide


def measure_coverage(rendered: RenderedMap, layout: MapLayout, cfg: StitchConfig) -> MapCoverage:
    """Coverage of the grid, and its holes on a coarse grid (from the preview when the map is only tiles): the
    wall no keyframe showed (re-fly areas) apart from the wall keyframes showed but cut (relief)."""
    grid = layout.grid
    if rendered.coverage is not None:
        cov = rendered.coverage
    else:
        cov = np.where(rendered.coverage_preview > 127, 255, 0).astype(np.uint8)
    sc = cov.shape[1] / grid.width
    box = tuple(int(round(v * sc)) for v in layout.facade_px)  # the facade, not the anchoring margin around it
    relief_px = (cov == 0) & (_views(layout, cov.shape, sc) >= RELIEF_VIEWS)
    holes_cfg = {"cell_m": cfg.uncovered_cell_m if layout.scale_known else 16 * grid.m_per_px,
                 "min_area_m2": cfg.min_uncovered_m2 if layout.scale_known else 0.0}
    holes = uncovered_areas(np.where(relief_px, 255, cov).astype(np.uint8), grid, box, **holes_cfg)
    relief = [a for a in uncovered_areas(np.where(relief_px, 0, 255).astype(np.uint8), grid, box, **holes_cfg)
              if min(a.along_max_m - a.along_min_m, a.up_max_m - a.up_min_m) >= holes_cfg["cell_m"] / 2]
    x0, y0, x1, y1 = layout.facade_px
    if (x0, y0, x1, y1) == (0, 0, grid.width, grid.height):
        fraction = rendered.covered_px / max(1, grid.width * grid.height)
    else:
        inside = cov[box[1] : box[3], box[0] : box[2]]
        fraction = np.count_nonzero(inside) / max(1, inside.size)
    return MapCoverage(float(fraction), holes, relief)


def _views(layout: MapLayout, shape: tuple[int, int], sc: float) -> np.ndarray:
    """How many placed keyframes' whole frames (mask or not) cover each pixel of a ``shape`` grid (the map's
    grid scaled by ``sc``): counted on a copy at most ``_VIEWS_MAX_PX`` wide."""
    down = max(1, int(math.ceil(shape[1] / _VIEWS_MAX_PX)))
    small = (-(-shape[0] // down), -(-shape[1] // down))
    count = np.zeros(small, np.uint8)
    frame = np.zeros(small, np.uint8)
    for pk in layout.placed.values():
        m = pk.mesh_px
        ring = np.vstack((m[0, :], m[1:, -1], m[-1, -2::-1], m[-2:0:-1, 0])) * (sc / down)
        frame[:] = 0
        cv2.fillPoly(frame, [np.round(ring).astype(np.int32)], 1)
        count = cv2.add(count, frame)
    return cv2.resize(count, (shape[1], shape[0]), interpolation=cv2.INTER_NEAREST) if down > 1 else count


def write_map_images(out: Path, rendered: RenderedMap, layout: MapLayout, coverage: MapCoverage) -> dict[str, str]:
    """map.png + coverage.png (or the tiles and a coverage preview) and the preview with a scale bar and the
    uncovered areas in red; each written under a temporary name and renamed, so a file is whole or absent."""
    files = {}
    if rendered.canvas is not None:
        files["map"] = _write_image(out / "map.png", rendered.canvas)
        files["coverage"] = _write_image(out / "coverage.png", rendered.coverage)
    else:
        files["tiles"] = str(rendered.tiles_dir)
        files["coverage_preview"] = _write_image(out / "coverage_preview.png", rendered.coverage_preview)
    m_per_preview_px = layout.grid.m_per_px / rendered.preview_scale if layout.scale_known else None
    files["preview"] = _write_image(
        out / "map_preview.jpg",
        draw_scale_bar(
            annotate_uncovered(annotate_uncovered(rendered.preview, layout.grid, coverage.relief, RELIEF_BGR),
                               layout.grid, coverage.uncovered),
            m_per_preview_px,
        ),
    )
    return files


def _write_image(path: Path, img: np.ndarray) -> str:
    with atomic_path(path) as tmp:
        if not cv2.imwrite(str(tmp), img):
            raise CompanionError(f"cannot write {path}", "check free disk space and permissions of --out")
    return str(path)


@dataclass(frozen=True)
class StitchRun:
    """Every stage's output of one stitch, as the report reads them."""

    input: StitchInput  # the usable keyframes (damaged ones in ``skipped``)
    config: StitchConfig
    use_poses: bool
    aligned: AlignedKeyframes
    layout: MapLayout
    rendered: RenderedMap
    timing_s: dict[str, float]
    wall: WallDistance | None = None  # the measured camera-wall distance (None: not run)
    placement: WallPlacement | None = None  # the wall's edges the map was moved onto (None: no telemetry)


@dataclass(frozen=True)
class StitchReport:
    """``report.json``; field order is the file's key order."""

    source: str
    keyframes_in: int
    keyframes_used: list[int]
    keyframes_skipped: list[dict]
    keyframes_dropped: list[dict]
    warnings: list[str]
    telemetry_prior: bool
    pairs_tried: int
    pairs_accepted: int
    pairs_affine_fallback: int
    pairs_rejected: list[dict]
    pairs: list[dict]
    alignment: dict
    anchor: dict | None  # how well the map is anchored on the wall by telemetry (None without telemetry)
    wall_distance: dict | None  # the camera-wall distance the scale stands on, measured by the images
    placement: dict | None  # where the map sits on the wall: the wall's edges it was moved onto, sigma per axis
    map: dict
    coverage_fraction: float
    gains: dict[int, float]
    # None when the map has no scale: then the ``_px`` lists (map pixels) and ``scale_unknown`` (why, fix) say it
    uncovered_areas_m: list[dict] | None
    relief_areas_m: list[dict] | None  # wall keyframes showed and all cut (portals, recesses, glass): not re-flown
    uncovered_areas_px: list[dict] | None
    relief_areas_px: list[dict] | None
    scale_unknown: dict | None
    timing_s: dict[str, float]
    files: dict[str, str]
    config: dict
    render: dict

    def as_dict(self) -> dict:
        return {f.name: getattr(self, f.name) for f in fields(self)}


def build_report(run: StitchRun, coverage: MapCoverage, files: dict[str, str]) -> StitchReport:
    inp, al, layout = run.input, run.aligned.alignment, run.layout
    kfs = inp.keyframes
    pairs, glob, loc = _pair_entries(run)
    mm = layout.mm_per_px
    dropped = [{"index": kfs[k].index, "reason": why} for k, why in sorted(al.dropped.items())]
    dropped += [
        {"index": kfs[k].index, "reason": "outside the map"}
        for k in range(len(kfs))
        if k not in layout.placed and k not in al.dropped
    ]
    results = run.aligned.pairs
    return StitchReport(
        source=inp.source,
        keyframes_in=len(kfs) + len(inp.skipped),
        keyframes_used=[kfs[k].index for k in sorted(layout.placed)],
        keyframes_skipped=[sk.as_dict() for sk in inp.skipped],
        keyframes_dropped=dropped,
        warnings=[sk.warning() for sk in inp.skipped] + (list(run.placement.warnings) if run.placement else []),
        telemetry_prior=run.use_poses,
        pairs_tried=len(results),
        pairs_accepted=sum(r.accepted for r in results),
        pairs_affine_fallback=sum(r.accepted and r.model == "affine" for r in results),
        pairs_rejected=[p for p in pairs if not p["accepted"]],
        pairs=[p for p in pairs if p["accepted"]],
        alignment={
            "iterations": al.iterations,
            "transfer_rms_before_px": round(al.initial_rms * inp.camera.focal_px, 3),
            "transfer_rms_after_px": round(al.final_rms * inp.camera.focal_px, 3),
            "global_residual_px": _stats(glob),
            "global_residual_mm": _in_mm(_stats(glob), mm),
            "local_residual_px": _stats(loc),
            "local_residual_mm": _in_mm(_stats(loc), mm),
        },
        anchor=_anchor_section(run),
        wall_distance=run.wall.summary() if run.wall is not None else None,
        placement=run.placement.summary() if run.placement is not None else None,
        map=_map_section(layout, run.rendered, run.use_poses),
        coverage_fraction=round(coverage.fraction, 4),
        gains={kfs[k].index: round(float(run.rendered.gains[k]), 4) for k in layout.placed},
        **_area_lists(run, coverage),
        timing_s=run.timing_s,
        files=files,
        config=asdict(run.config),
        render=run.rendered.info,
    )


def _area_lists(run: StitchRun, coverage: MapCoverage) -> dict:
    """The uncovered and relief areas in wall metres, or (no scale) in map pixels with why and the fix."""
    if run.layout.scale_known:
        return {"uncovered_areas_m": [a.as_dict() for a in coverage.uncovered],
                "relief_areas_m": [a.as_dict() for a in coverage.relief],
                "uncovered_areas_px": None, "relief_areas_px": None, "scale_unknown": None}
    grid = run.layout.grid
    return {"uncovered_areas_m": None, "relief_areas_m": None,
            "uncovered_areas_px": [area_px(a, grid) for a in coverage.uncovered],
            "relief_areas_px": [area_px(a, grid) for a in coverage.relief],
            "scale_unknown": scale_note(run.input, run.config.use_poses).as_dict()}


def _pair_entries(run: StitchRun) -> tuple[list[dict], list[float], list[float]]:
    """One entry per pair tried; for aligned pairs the median residual of its matches on the map after the
    global homographies and after the mesh, whose values also go into the overall statistics."""
    kfs, cam = run.input.keyframes, run.input.camera
    placed, G = run.layout.placed, run.aligned.alignment.G
    to_norm = np.linalg.inv(cam.K)
    px_per_unit = 1.0 / run.layout.grid.m_per_px
    glob, loc, entries = [], [], []
    for r in run.aligned.pairs:
        entry = pair_summary(r, kfs)
        if not r.accepted:
            entry["reason"] = r.reason
        elif r.i in placed and r.j in placed:
            g = np.linalg.norm(apply_h(G[r.i] @ to_norm, r.pts_i) - apply_h(G[r.j] @ to_norm, r.pts_j), axis=1)
            g = g * px_per_unit
            lo = np.linalg.norm(
                forward_points(placed[r.i], r.pts_i, cam.width, cam.height)
                - forward_points(placed[r.j], r.pts_j, cam.width, cam.height),
                axis=1,
            )
            glob.extend(g.tolist())
            loc.extend(lo.tolist())
            entry["global_residual_px"] = round(float(np.median(g)), 3)
            entry["local_residual_px"] = round(float(np.median(lo)), 3)
        entries.append(entry)
    return entries, glob, loc


def pair_summary(r: PairResult, kfs) -> dict:
    """A pair as the report lists it: spool indices, outcome, model, matches, inliers, RANSAC rms."""
    return {
        "a": kfs[r.i].index,
        "b": kfs[r.j].index,
        "accepted": r.accepted,
        "model": r.model,
        "matches": r.matches,
        "inliers": r.inliers,
        "ransac_rms_px": None if r.rms_px is None else round(r.rms_px, 3),
    }


def _anchor_section(run: StitchRun) -> dict | None:
    """The residual between image alignment and telemetry, by keyframe spool index where it was outvoted."""
    anchoring = run.aligned.anchoring
    if anchoring is None:
        return None
    kfs = run.input.keyframes
    off = dict(zip(anchoring.positions, anchoring.offsets_m, strict=True))
    return {
        **anchoring.summary(),
        "outvoted": [{"index": kfs[k].index, "offset_m": round(off[k], 3)} for k in anchoring.outvoted],
        "meaning": "offset between where the images put each keyframe and where its telemetry does; outvoted "
        "keyframes' telemetry was overruled by the images; the map's position on the wall is good to about "
        "placement_sigma_m",
    }


def _map_section(layout: MapLayout, rendered: RenderedMap, use_poses: bool) -> dict:
    grid, mm = layout.grid, layout.mm_per_px
    known = layout.scale_known  # without a scale the plane's units are no metres: no extent in metres
    return {
        "width_px": grid.width,
        "height_px": grid.height,
        "mm_per_px": None if mm is None else round(mm, 4),
        "along_m": [round(grid.along0_m, 3), round(grid.along0_m + grid.width * grid.m_per_px, 3)] if known else None,
        "up_m": [round(grid.up_top_m - grid.height * grid.m_per_px, 3), round(grid.up_top_m, 3)] if known else None,
        "in_memory": rendered.canvas is not None,
        "rectified_to_facade": use_poses,
    }


def forward_points(pk: PlacedKeyframe, pts: np.ndarray, width: int, height: int) -> np.ndarray:
    """Keyframe pixels -> map pixels through the mesh cell that contains each point."""
    cy, cx = pk.src_px.shape[0] - 1, pk.src_px.shape[1] - 1
    c = np.clip((pts[:, 0] / (width / cx)).astype(int), 0, cx - 1)
    r = np.clip((pts[:, 1] / (height / cy)).astype(int), 0, cy - 1)
    Hf = np.linalg.inv(pk.cell_inv[r * cx + c])
    q = np.einsum("nij,nj->ni", Hf, np.column_stack((pts, np.ones(len(pts)))))
    return q[:, :2] / q[:, 2:3]


def _stats(v: list[float] | np.ndarray) -> dict:
    a = np.asarray(v, dtype=float)
    if a.size == 0:
        return {"median": None, "p95": None, "max": None}
    return {
        "median": round(float(np.median(a)), 3),
        "p95": round(float(np.percentile(a, 95)), 3),
        "max": round(float(a.max()), 3),
    }


def _in_mm(stats_px: dict, mm_per_px: float | None) -> dict | None:
    if not mm_per_px:
        return None
    return {k: (None if v is None else round(v * mm_per_px, 3)) for k, v in stats_px.items()}

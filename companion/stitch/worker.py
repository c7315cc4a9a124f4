"""The stitching worker: keyframes in, rectified facade map + coverage + report out (resumable, tiled).

``Stitcher.stitch`` is the whole pipeline as named stages over typed, frozen intermediates, one module each:

    features (features.py)  -> KeyframeFeatures   SIFT inside the ROI; damaged keyframes left out, named
    priors   (priors.py)    -> PlanePriors        where telemetry puts each keyframe on the wall, the scale
    pairs    (pairs.py)     -> RegisteredPairs    DLT/MAGSAC per candidate pair, telemetry gate, cached
    wall distance (wall_distance.py) -> WallDistance  the camera-wall distance the images measure: the scale
    alignment (align.py)    -> AlignedKeyframes   global least squares onto the plane, outlier pairs dropped
    wall check (wallcheck.py) -> masks             pixels the neighbours show off the wall plane cut
    placement (wall_anchor.py) -> WallPlacement   the map moved onto the wall's ends / roof line where seen
    mesh     (layout.py)    -> MapLayout          the map grid and APAP meshes (paper Eq. 4)
    render   (canvas.py)    -> RenderedMap        tiles, seams, gains; map in memory or as tiles
    report   (report.py)    -> StitchReport       coverage and holes, images, georeferencing, report.json

With a debug directory each stage also leaves what it decided there (debug.py).
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from companion.errors import CompanionError
from companion.files import write_atomic
from companion.stitch.align import AlignedKeyframes, align_keyframes
from companion.stitch.canvas import RenderedMap, TileRunner, render_map
from companion.stitch.config import StitchConfig, worker_count
from companion.stitch.debug import StageDebug
from companion.stitch.features import KeyframeFeatures, find_features
from companion.stitch.inputs import StitchInput
from companion.stitch.layout import MapLayout, lay_out
from companion.stitch.output import UncoveredArea, write_georeferencing
from companion.stitch.pairs import PairRunner, RegisteredPairs, register_pairs
from companion.stitch.priors import PlanePriors, plane_priors
from companion.stitch.render import MapGrid
from companion.stitch.report import StitchRun, build_report, measure_coverage, write_map_images
from companion.stitch.wall_anchor import WallPlacement, place_on_wall
from companion.stitch.wall_distance import WallDistance, measure_wall_distance
from companion.stitch.wallcheck import check_wall
from companion.viewer import write_viewer

__all__ = ["StitchConfig", "StitchResult", "Stitcher", "stitch"]


@dataclass(frozen=True)
class StitchResult:
    out_dir: Path
    grid: MapGrid
    mm_per_px: float | None  # None when the scale is unknown (no telemetry and no standoff)
    coverage_fraction: float
    uncovered: list[UncoveredArea]
    report: dict
    map_image: np.ndarray | None = None  # BGR, when the map fits in memory
    coverage: np.ndarray | None = None  # 0/255, same size as map_image
    files: dict[str, str] = field(default_factory=dict)


class _StageClock:
    """Wall-clock seconds per stage, in the order the stages ran (the report's ``timing_s``)."""

    def __init__(self):
        self._last = time.perf_counter()
        self.seconds: dict[str, float] = {}

    def lap(self, stage: str) -> None:
        now = time.perf_counter()
        self.seconds[stage] = round(now - self._last, 3)
        self._last = now


class Stitcher:
    """features -> priors -> pairs -> alignment -> mesh -> render -> report; each stage a method that takes the
    earlier stages' records and returns its own."""

    def __init__(
        self, config: StitchConfig | None = None, *, progress: bool = True, debug_dir: str | Path | None = None,
        tiles: TileRunner | None = None, pair_tasks: PairRunner | None = None,
    ):
        self.config = config or StitchConfig()
        self.progress = progress
        self.tiles = tiles  # where a map kept as tiles is drawn (the site's cluster); None: this process's threads
        self.pair_tasks = pair_tasks  # where the pairs are matched (the site's cluster); None: this process's threads
        self.debug = StageDebug(debug_dir)

    def stitch(self, inp: StitchInput, out_dir: str | Path) -> StitchResult:
        out = self._prepare(inp, out_dir)
        clock = _StageClock()
        found = self.features(inp, out)
        clock.lap("features")
        priors = self.priors(found)
        pairs = self.pairs(found, priors, out)
        clock.lap("matching")
        wall, priors = self.wall_distance(found, priors, pairs)
        aligned = self.alignment(found, priors, pairs)
        clock.lap("alignment")
        found = self.wall_check(found, aligned, out)
        clock.lap("wall_check")
        aligned, placement = self.placement(found, priors, aligned, wall)
        layout = self.mesh(found, priors, aligned)
        clock.lap("mesh")
        rendered = self.render(found, aligned, layout, out)
        clock.lap("render")
        return self.report(
            StitchRun(found.input, self.config, priors.use_poses, aligned, layout, rendered, clock.seconds, wall,
                      placement),
            out,
        )

    def _prepare(self, inp: StitchInput, out_dir: str | Path) -> Path:
        if len(inp.keyframes) < 2 and not inp.skipped:
            raise CompanionError(
                f"the map needs at least 2 keyframes, the input has {len(inp.keyframes)}",
                "fly the scan (or wait for the spool to fill) and run again",
            )
        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        return out

    def features(self, inp: StitchInput, out: Path) -> KeyframeFeatures:
        found = find_features(inp, self.config, out / "cache" / "features", progress=self.progress)
        self.debug.features(found)
        return found

    def priors(self, found: KeyframeFeatures, wall: WallDistance | None = None) -> PlanePriors:
        """Telemetry's placement of every keyframe; with ``wall``, each camera moved across the wall by the
        correction the images measured."""
        shifts = wall.shifts(len(found.input.keyframes)) if wall is not None else 0.0
        return plane_priors(found.input, self.config, shifts)

    def wall_distance(self, found: KeyframeFeatures, priors: PlanePriors,
                      pairs: RegisteredPairs) -> tuple[WallDistance | None, PlanePriors]:
        """The camera-wall distance measured by the images against the telemetry's relative motion, and the
        priors made again at that distance when it differs from the telemetry's (None with ``measure_wall``
        off: the telemetry's priors as they are)."""
        if not self.config.measure_wall:
            return None, priors
        wall = measure_wall_distance(found.input, priors, pairs)
        return wall, (self.priors(found, wall) if wall.applied else priors)

    def pairs(self, found: KeyframeFeatures, priors: PlanePriors, out: Path) -> RegisteredPairs:
        pairs = register_pairs(found, priors, self.config, out / "cache" / "pairs", progress=self.progress,
                               runner=self.pair_tasks, feature_dir=out / "cache" / "features")
        self.debug.pairs(found, pairs)
        return pairs

    def alignment(self, found: KeyframeFeatures, priors: PlanePriors, pairs: RegisteredPairs) -> AlignedKeyframes:
        aligned = align_keyframes(pairs, priors, found.input.camera, self.config)
        self.debug.alignment(found, aligned)
        return aligned

    def wall_check(self, found: KeyframeFeatures, aligned: AlignedKeyframes, out: Path) -> KeyframeFeatures:
        """Mask pixels the neighbouring keyframes show are not on the wall plane are cut (``wallcheck.py``)."""
        if not self.config.wall_check:
            return found
        checked = check_wall(found.input, aligned.accepted, out / "cache" / "masks", workers=worker_count(self.config))
        return replace(found, input=checked.input)

    def placement(self, found: KeyframeFeatures, priors: PlanePriors, aligned: AlignedKeyframes,
                  wall: WallDistance | None) -> tuple[AlignedKeyframes, WallPlacement | None]:
        """The aligned map moved onto the wall's ends and roof line where the keyframes show them
        (``wall_anchor.py``); the anchoring's placement sigma then counts what is left: those edges' sigma, or
        GNSS's absolute error on an axis no edge fixes."""
        if not priors.use_poses or aligned.anchoring is None or wall is None:
            return aligned, None
        cfg = self.config
        moved, placement = place_on_wall(found.input, aligned, gnss_sigma_m=cfg.gnss_sigma_m,
                                         search_m=max(1.0, 2.0 * cfg.gnss_sigma_m), scale_sigma=wall.scale_sigma,
                                         internal_m=aligned.anchoring.placement_sigma_m)
        return replace(moved, anchoring=aligned.anchoring.with_absolute(placement.sigma_m)), placement

    def mesh(self, found: KeyframeFeatures, priors: PlanePriors, aligned: AlignedKeyframes) -> MapLayout:
        layout = lay_out(found.input, priors, aligned, self.config, progress=self.progress)
        self.debug.mesh(found, layout)
        return layout

    def render(self, found: KeyframeFeatures, aligned: AlignedKeyframes, layout: MapLayout, out: Path) -> RenderedMap:
        return render_map(found.input, aligned, layout, self.config, out, progress=self.progress, tiles=self.tiles)

    def report(self, run: StitchRun, out: Path) -> StitchResult:
        """Coverage, images, georeferencing and report.json; report.json is written last, so a finished report
        means a finished map folder (and the report lists every file)."""
        coverage = measure_coverage(run.rendered, run.layout, self.config)
        self.debug.render(run.rendered, run.layout, coverage)
        files = write_map_images(out, run.rendered, run.layout, coverage)
        report = build_report(run, coverage, files)
        result = StitchResult(
            out,
            run.layout.grid,
            run.layout.mm_per_px,
            coverage.fraction,
            coverage.uncovered,
            report.as_dict(),
            run.rendered.canvas,
            run.rendered.coverage,
            files,
        )
        # World file / CRS in wall metres, alpha for uncovered areas, the wall's geographic anchor (docs/OUTPUTS.md)
        files = {**files, **write_georeferencing(result, run.input)}
        # the inspector's viewer (docs/OUTPUTS.md), from the report as it stands (report.json is written after it)
        images = {kf.index: kf.image_path for kf in run.input.keyframes}
        in_memory = (run.rendered.canvas, run.rendered.coverage) if run.rendered.canvas is not None else None
        files["viewer"] = write_viewer(out, images, report=replace(report, files=dict(files)).as_dict(),
                                       image=in_memory)
        files["report"] = str(out / "report.json")
        report = replace(report, files=files)
        write_atomic(out / "report.json", json.dumps(report.as_dict(), indent=1), durable=True)
        return replace(result, report=report.as_dict(), files=files)


def stitch(
    inp: StitchInput,
    out_dir: str | Path,
    config: StitchConfig | None = None,
    *,
    progress: bool = True,
    debug_dir: str | Path | None = None,
    tiles: TileRunner | None = None,
    pair_tasks: PairRunner | None = None,
) -> StitchResult:
    """The facade map of ``inp`` in ``out_dir`` (see :class:`Stitcher`)."""
    return Stitcher(config, progress=progress, debug_dir=debug_dir, tiles=tiles, pair_tasks=pair_tasks).stitch(
        inp, out_dir)

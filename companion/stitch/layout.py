"""The map's grid and every keyframe's mesh on it (paper Eq. 4): the mesh stage between alignment and rendering.

The grid spans the facade (telemetry: the wall's length and height) or the aligned images' content (no
telemetry), at the keyframes' median native resolution unless a scale is asked for. With telemetry the facade
rectangle is grown, where the images reach, by how uncertain telemetry's placement of the map is (three times
the anchoring's ``placement_sigma_m``, at most ``MAX_ANCHOR_MARGIN_M``): a map the images hold together but GNSS
puts 20 cm off is not cut at the wall's ends. Coverage is still measured on the facade rectangle.
Each keyframe's APAP mesh pulls its matched features towards the midpoints of their matches on the plane, so
neighbours meet.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from companion.errors import CompanionError
from companion.progress import progress_bar
from companion.stitch.align import AlignedKeyframes
from companion.stitch.config import StitchConfig
from companion.stitch.geometry import apply_h
from companion.stitch.inputs import CameraModel, StitchInput
from companion.stitch.mesh import WarpedMesh, mesh_for_keyframe
from companion.stitch.priors import PlanePriors
from companion.stitch.render import MapGrid, PlacedKeyframe, place


@dataclass(frozen=True)
class MapLayout:
    """The mesh stage's output: the map grid, each placed keyframe's mesh on the plane and in map pixels."""

    grid: MapGrid
    facade_px: tuple[int, int, int, int]  # (x0, y0, x1, y1): the facade rectangle (the whole grid without poses)
    meshes: dict[int, WarpedMesh]  # keyframe position -> mesh on the plane (every aligned keyframe)
    placed: dict[int, PlacedKeyframe]  # keyframe position -> mesh in map pixels (only those inside the map)
    scale_known: bool

    @property
    def mm_per_px(self) -> float | None:
        return self.grid.m_per_px * 1000.0 if self.scale_known else None


def lay_out(
    inp: StitchInput, priors: PlanePriors, aligned: AlignedKeyframes, cfg: StitchConfig, *, progress: bool
) -> MapLayout:
    grid, facade_px = map_grid(inp, priors, aligned, cfg)
    targets = _mesh_targets(aligned, inp.camera)
    ransac_px = cfg.ransac_threshold_px(inp.camera.width)
    max_shift_m = max(cfg.pose_gate(priors.plane_unit_m * inp.camera.focal_px), 50 * ransac_px * priors.plane_unit_m)
    meshes, placed = {}, {}
    for k in progress_bar(aligned.placed, desc="mesh", disable=not progress, leave=False, unit="it"):
        pts, tgt = targets[k] if cfg.local and targets[k][0].size else (np.zeros((0, 2)), np.zeros((0, 2)))
        meshes[k] = mesh_for_keyframe(
            aligned.alignment.G[k],
            np.linalg.inv(inp.camera.K),
            inp.camera.width,
            inp.camera.height,
            pts,
            tgt,
            cells=cfg.cells,
            rho_px=cfg.rho_px,
            gamma=cfg.gamma,
            max_shift_m=max_shift_m,
        )
        pk = place(k, meshes[k], grid)
        if pk is not None:
            placed[k] = pk
    return MapLayout(grid, facade_px, meshes, placed, priors.scale_known)


MAX_ANCHOR_MARGIN_M = 1.0
MIN_ANCHOR_MARGIN_M = 0.05


def map_grid(
    inp: StitchInput, priors: PlanePriors, aligned: AlignedKeyframes, cfg: StitchConfig
) -> tuple[MapGrid, tuple[int, int, int, int]]:
    """The map's pixel grid on the plane and the facade rectangle in it; an absurd size (a bad scale or
    geometry) is refused before anything is allocated."""
    native = _native_m_per_px(aligned, inp.camera)
    m_per_px = (cfg.mm_per_px / 1000.0) if (cfg.mm_per_px and priors.scale_known) else native
    W, H = inp.camera.width, inp.camera.height
    to_norm = np.linalg.inv(inp.camera.K)
    image = np.array([[0, 0], [W, 0], [W, H], [0, H]])
    pts = np.vstack([apply_h(aligned.alignment.G[k] @ to_norm, image) for k in aligned.placed])
    content = (pts[:, 0].min(), pts[:, 0].max(), pts[:, 1].min(), pts[:, 1].max())
    if priors.use_poses:
        facade = (0.0, inp.facade.frame.length_m, 0.0, inp.facade.height_m)
        anchoring = aligned.anchoring
        margin = min(MAX_ANCHOR_MARGIN_M, 3.0 * anchoring.placement_sigma_m) if anchoring else 0.0
        margin = margin if margin >= MIN_ANCHOR_MARGIN_M else 0.0  # well-anchored maps keep the facade's grid
        extent = (
            min(facade[0], max(content[0], facade[0] - margin)),
            max(facade[1], min(content[1], facade[1] + margin)),
            min(facade[2], max(content[2], facade[2] - margin)),
            max(facade[3], min(content[3], facade[3] + margin)),
        )
    else:
        facade = extent = content
    gw = int(math.ceil((extent[1] - extent[0]) / m_per_px))
    gh = int(math.ceil((extent[3] - extent[2]) / m_per_px))
    if gw <= 0 or gh <= 0:
        raise CompanionError(
            f"the map would be {gw}x{gh} px at {m_per_px * 1000:.2f} mm/px",
            "check the telemetry/facade geometry",
        )
    if gw * gh > cfg.max_map_px:
        raise CompanionError(
            f"the map would be {gw}x{gh} px ({gw * gh / 1e6:.3g} MP) at {m_per_px * 1000:.3f} mm/px, over the "
            f"limit of {cfg.max_map_px / 1e6:.3g} MP (StitchConfig.max_map_px, --max-map-px)",
            f"pass a coarser --mm-per-px; or, if a map this large is meant, --max-map-px {_above(gw * gh)} "
            "(rendered and written tile by tile: memory does not grow with it); or check the telemetry/facade "
            "geometry (a wrong scale)",
        )
    grid = MapGrid(extent[0], extent[3], m_per_px, gw, gh)
    x0, y0 = np.round(grid.to_px(np.array([facade[0], facade[3]]))).astype(int)
    x1, y1 = np.round(grid.to_px(np.array([facade[1], facade[2]]))).astype(int)
    return grid, (max(0, int(x0)), max(0, int(y0)), min(gw, int(x1)), min(gh, int(y1)))


def _above(px: int) -> str:
    """A round limit just above ``px`` pixels, as the option takes it (``2e9``)."""
    e = math.floor(math.log10(px))
    return f"{math.ceil(px / 10**e)}e{e}"


def _native_m_per_px(aligned: AlignedKeyframes, camera: CameraModel) -> float:
    """The median size on the plane of a keyframe's centre pixel (the keyframes' own resolution)."""
    W, H = camera.width, camera.height
    to_norm = np.linalg.inv(camera.K)
    centre = np.array([[W / 2, H / 2], [W / 2 + 1, H / 2], [W / 2, H / 2 + 1]])
    gsd = []
    for k in aligned.placed:
        c = apply_h(aligned.alignment.G[k] @ to_norm, centre)
        u, v = c[1] - c[0], c[2] - c[0]
        gsd.append(math.sqrt(abs(u[0] * v[1] - u[1] * v[0])))
    return float(np.median(gsd))


def _mesh_targets(aligned: AlignedKeyframes, camera: CameraModel) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """Per placed keyframe: its inlier pixels and where each must land (the midpoint of the match on the plane)."""
    to_norm = np.linalg.inv(camera.K)
    G = aligned.alignment.G
    corr: dict[int, list[tuple[np.ndarray, np.ndarray]]] = {k: [] for k in aligned.placed}
    for r in aligned.accepted:
        if G[r.i] is None or G[r.j] is None:
            continue
        mid = 0.5 * (apply_h(G[r.i] @ to_norm, r.pts_i) + apply_h(G[r.j] @ to_norm, r.pts_j))
        corr[r.i].append((r.pts_i, mid))
        corr[r.j].append((r.pts_j, mid))
    empty = (np.zeros((0, 2)), np.zeros((0, 2)))
    return {k: (np.vstack([c[0] for c in v]), np.vstack([c[1] for c in v])) if v else empty for k, v in corr.items()}

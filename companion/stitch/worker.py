"""The stitching worker: keyframes in, rectified facade map + coverage + report out (resumable, tiled)."""

from __future__ import annotations

import hashlib
import json
import logging
import math
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import cv2
import numpy as np

from companion.errors import CompanionError
from companion.progress import progress_bar
from companion.stitch.align import global_alignment
from companion.stitch.exposure import apply_gain, apply_gain_numpy, solve_gains
from companion.stitch.features import cached_features, detect_settings, feature_key, load_image_and_mask, load_mask
from companion.stitch.geometry import (
    apply_h,
    camera_distance_to_wall,
    prior_plane_from_image,
    reference_plane_from_image,
)
from companion.stitch.inputs import SkippedKeyframe, StitchInput
from companion.stitch.mesh import mesh_for_keyframe
from companion.stitch.output import (
    UncoveredArea,
    annotate_uncovered,
    draw_scale_bar,
    uncovered_areas,
    write_georeferencing,
)
from companion.stitch.pairs import PairSettings, candidate_pairs, load_pair, match_pair, save_pair
from companion.stitch.render import (
    RENDERERS,
    MapGrid,
    PlacedKeyframe,
    SourceCache,
    drawable,
    place,
    render_tile,
)
from companion.stitch.render_plan import plan_render
from companion.viewer import write_viewer

log = logging.getLogger(__name__)


@dataclass
class StitchConfig:
    work_width: int = 1600  # SIFT runs on a copy this wide (4K keyframes are downscaled for features only)
    max_features: int = 4000
    contrast_threshold: float = 0.01  # SIFT; OpenCV's 0.04 finds too little on plain walls (the gate's setting)
    equalize: bool = True  # CLAHE before SIFT, as the gate: plain cladding gives many more matchable features
    neighbours: int = 2  # sequence neighbours matched besides telemetry-overlapping keyframes
    ratio: float = 0.75
    ransac_px: float | None = None  # default: 0.4 % of the image width, at least 2 px
    min_inliers: int = 15
    max_pair_residual_px: float = 8.0  # a pair still this far off after global alignment is an outlier
    pose_gate_m: float = 1.0  # matches/models landing further apart than this on the wall contradict telemetry
    use_poses: bool = True
    sigma_prior_m: float = 0.5  # how far GNSS may put an image centre off on the wall
    sigma_shape_m: float = 0.05  # how far attitude/range errors may bend an image's corners (relative to centre)
    local: bool = True  # APAP mesh; False draws each keyframe with its global homography only
    cells: tuple[int, int] = (16, 9)  # Cx x Cy
    rho_px: float | None = None  # Eq. 4 scale; default 10 % of the image width
    gamma: float = 0.01  # weight floor: far cells fall back to the global homography
    mm_per_px: float | None = None  # map scale; default the keyframes' median native resolution
    max_map_px: float = 4e8  # refuse absurd map sizes (bad scale) before allocating anything
    tile_px: int = 1024
    max_in_memory_px: float = 6e7  # larger maps are written only as tiles (+ a preview)
    feather_px: float = 4.0
    renderer: str = "warp"  # "warp": per-cell cv2.warpPerspective; "pullback": the per-pixel numpy reference
    gain_compensation: bool = True
    preview_width: int = 3000
    min_uncovered_m2: float = 0.02
    uncovered_cell_m: float = 0.1  # holes are reported on this grid (re-fly planning, not pixel accuracy)


@dataclass
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


def _progress(it, desc, enabled, total=None):
    return progress_bar(it, desc=desc, total=total, disable=not enabled, leave=False, unit="it")


def stitch(
    inp: StitchInput, out_dir: str | Path, config: StitchConfig | None = None, *, progress: bool = True
) -> StitchResult:
    cfg = config or StitchConfig()
    if cfg.renderer not in RENDERERS:
        raise CompanionError(f"unknown renderer {cfg.renderer!r}", f"use one of {', '.join(RENDERERS)}")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    if len(inp.keyframes) < 2 and not inp.skipped:
        raise CompanionError(
            f"the map needs at least 2 keyframes, the input has {len(inp.keyframes)}",
            "fly the scan (or wait for the spool to fill) and run again",
        )
    cam = inp.camera
    t = {"start": time.perf_counter()}
    to_norm = np.linalg.inv(cam.K)
    W, H = cam.width, cam.height
    ransac_px = cfg.ransac_px or max(2.0, 0.004 * W)
    settings = PairSettings(
        ratio=cfg.ratio, ransac_px=ransac_px, min_inliers=cfg.min_inliers, pose_gate_m=cfg.pose_gate_m
    )

    # 1. features inside the ROI; a keyframe whose files are damaged is left out (and named), not fatal
    feat_dir = out / "cache" / "features"
    feature_settings = detect_settings(cfg.work_width, cfg.max_features, cfg.contrast_threshold, cfg.equalize)
    feats, keys, usable, skipped = [], [], [], list(inp.skipped)
    for kf in _progress(inp.keyframes, "features", progress):
        try:
            f = cached_features(
                kf,
                feat_dir,
                work_width=cfg.work_width,
                max_features=cfg.max_features,
                contrast_threshold=cfg.contrast_threshold,
                equalize=cfg.equalize,
            )
        except CompanionError as exc:
            skipped.append(SkippedKeyframe(kf.index, exc.problem))
            continue
        except OSError as exc:
            skipped.append(SkippedKeyframe(kf.index, f"cannot read its files ({exc})"))
            continue
        if f.image_size != (W, H):
            skipped.append(
                SkippedKeyframe(
                    kf.index,
                    f"image is {f.image_size[0]}x{f.image_size[1]}, the camera's are {W}x{H} "
                    "(all keyframes of one stitch come from one camera mode)",
                )
            )
            continue
        feats.append(f)
        keys.append(feature_key(kf, feature_settings))
        usable.append(kf)
    for sk in skipped:
        log.warning("%s", sk.warning())
    if not usable:
        reasons = "; ".join(sk.warning() for sk in skipped[:3]) + ("; ..." if len(skipped) > 3 else "")
        raise CompanionError(
            f"no usable keyframe is left: {reasons}",
            "check the spool's frames/ directory (complete JPEG/PNG files, masks of the image size)",
        )
    inp = replace(inp, keyframes=usable, skipped=tuple(skipped))
    kfs = inp.keyframes
    n = len(kfs)
    t["features"] = time.perf_counter()

    # 2. telemetry priors
    use_poses = cfg.use_poses and inp.has_poses
    priors = [prior_plane_from_image(kf.pose, inp.facade) if use_poses and kf.pose is not None else None for kf in kfs]
    if use_poses:
        dists = [camera_distance_to_wall(kf.pose, inp.facade) for kf in kfs if kf.pose is not None]
        distance = float(np.median(dists))
        if distance <= 0:
            raise CompanionError(
                f"telemetry puts the camera {distance:.1f} m behind the wall plane",
                "check the facade start/end order (drone on the right-hand side) in spool.json",
            )
        plane_unit_m, scale_known = distance / cam.focal_px, True
        reference = np.eye(3)
    else:
        scale_known = inp.standoff_m is not None
        plane_unit_m = (inp.standoff_m / cam.focal_px) if scale_known else 1.0
        reference = reference_plane_from_image(inp.standoff_m if scale_known else cam.focal_px)

    # 3. pairwise registration (cached per pair)
    corners = np.array([[-W / 2, -H / 2], [W / 2, -H / 2], [W / 2, H / 2], [-W / 2, H / 2]]) / cam.focal_px
    cands = candidate_pairs(n, priors, corners, neighbours=cfg.neighbours)
    pair_dir = out / "cache" / "pairs"
    gate_tag = f"{use_poses}-{settings}"
    results = []
    for i, j in _progress(cands, "matching", progress):
        tag = hashlib.sha1(f"{keys[i]}|{keys[j]}|{gate_tag}".encode()).hexdigest()[:16]
        path = pair_dir / f"{kfs[i].index:06d}-{kfs[j].index:06d}-{tag}.npz"
        r = load_pair(path)
        if r is None:
            r = match_pair(
                i, j, feats[i], feats[j], settings=settings, prior_i=priors[i], prior_j=priors[j], pixel_to_norm=to_norm
            )
            save_pair(path, r)
        r.i, r.j = i, j
        results.append(r)
    t["matching"] = time.perf_counter()
    if n >= 2 and not any(r.accepted for r in results) and not use_poses:
        raise CompanionError(
            "no two keyframes could be registered (no shared features inside the ROI masks)",
            "check that keyframes overlap (gate threshold) and that the masks keep the facade",
        )

    # 4. global alignment onto the plane; pairs that disagree with all the others are dropped and it is re-run
    for _round in range(4):
        al = global_alignment(
            n,
            results,
            to_norm,
            priors,
            reference,
            sigma_match=ransac_px / cam.focal_px,
            sigma_prior_m=cfg.sigma_prior_m,
            sigma_shape_m=cfg.sigma_shape_m,
        )
        errs = {}
        for r in results:
            if r.accepted and al.G[r.i] is not None and al.G[r.j] is not None:
                M = np.linalg.inv(al.G[r.j]) @ al.G[r.i]
                e = apply_h(M, apply_h(to_norm, r.pts_i)) - apply_h(to_norm, r.pts_j)
                errs[id(r)] = float(np.median(np.linalg.norm(e, axis=1))) * cam.focal_px
        if not errs:
            break
        limit = max(cfg.max_pair_residual_px, 6.0 * float(np.median(list(errs.values()))))
        bad = [r for r in results if id(r) in errs and errs[id(r)] > limit]
        if not bad:
            break
        for r in bad:
            r.accepted = False
            r.reason = f"inconsistent with the other pairs after global alignment ({errs[id(r)]:.1f} px)"
    placed_idx = [k for k in range(n) if al.G[k] is not None]
    accepted = [r for r in results if r.accepted]
    t["alignment"] = time.perf_counter()

    # 5. map grid
    gsd = []
    for k in placed_idx:
        Gp = al.G[k] @ to_norm
        c = apply_h(Gp, np.array([[W / 2, H / 2], [W / 2 + 1, H / 2], [W / 2, H / 2 + 1]]))
        u, v = c[1] - c[0], c[2] - c[0]
        gsd.append(math.sqrt(abs(u[0] * v[1] - u[1] * v[0])))
    native = float(np.median(gsd))
    m_per_px = (cfg.mm_per_px / 1000.0) if (cfg.mm_per_px and scale_known) else native
    if use_poses:
        extent = (0.0, inp.facade.frame.length_m, 0.0, inp.facade.height_m)
    else:
        pts = np.vstack([apply_h(al.G[k] @ to_norm, np.array([[0, 0], [W, 0], [W, H], [0, H]])) for k in placed_idx])
        extent = (pts[:, 0].min(), pts[:, 0].max(), pts[:, 1].min(), pts[:, 1].max())
    gw = int(math.ceil((extent[1] - extent[0]) / m_per_px))
    gh = int(math.ceil((extent[3] - extent[2]) / m_per_px))
    if gw * gh > cfg.max_map_px or gw <= 0 or gh <= 0:
        raise CompanionError(
            f"the map would be {gw}x{gh} px at {m_per_px * 1000:.2f} mm/px",
            "pass a coarser --mm-per-px, or check the telemetry/facade geometry",
        )
    grid = MapGrid(extent[0], extent[3], m_per_px, gw, gh)

    # 6. local mesh homographies (APAP)
    corr: dict[int, list[tuple[np.ndarray, np.ndarray]]] = {k: [] for k in placed_idx}
    for r in accepted:
        Gi, Gj = al.G[r.i], al.G[r.j]
        if Gi is None or Gj is None:
            continue
        pi_plane = apply_h(Gi @ to_norm, r.pts_i)
        pj_plane = apply_h(Gj @ to_norm, r.pts_j)
        mid = 0.5 * (pi_plane + pj_plane)
        corr[r.i].append((r.pts_i, mid))
        corr[r.j].append((r.pts_j, mid))
    placed: dict[int, PlacedKeyframe] = {}
    for k in _progress(placed_idx, "mesh", progress):
        if cfg.local and corr[k]:
            pts = np.vstack([c[0] for c in corr[k]])
            tgt = np.vstack([c[1] for c in corr[k]])
        else:
            pts, tgt = np.zeros((0, 2)), np.zeros((0, 2))
        mesh = mesh_for_keyframe(
            al.G[k],
            to_norm,
            W,
            H,
            pts,
            tgt,
            cells=cfg.cells,
            rho_px=cfg.rho_px,
            gamma=cfg.gamma,
            max_shift_m=max(cfg.pose_gate_m, 50 * ransac_px * plane_unit_m),
        )
        pk = place(k, mesh, grid)
        if pk is not None:
            placed[k] = pk
    t["mesh"] = time.perf_counter()

    # 7. render tiles
    gains = solve_gains(n, accepted) if cfg.gain_compensation else np.ones(n)

    legacy = cfg.renderer == "pullback"  # the render stage as it was before the OpenCV renderer (reference)

    def load(k):
        img, mask = load_image_and_mask(kfs[k])
        return (apply_gain_numpy if legacy else apply_gain)(img, float(gains[k])), mask

    # decoded keyframes kept for neighbouring tiles: image + mask + float32 seam weight, within ~600 MB
    cache_size = int(np.clip(6e8 / (W * H * 8), 3, 16))
    in_memory = gw * gh <= cfg.max_in_memory_px
    canvas = np.zeros((gh, gw, 3), np.uint8) if in_memory else None
    cov_full = np.zeros((gh, gw), np.uint8) if in_memory else None
    ps = min(1.0, cfg.preview_width / gw)
    pw, ph = max(1, round(gw * ps)), max(1, round(gh * ps))
    preview = np.zeros((ph, pw, 3), np.uint8)
    cov_prev = np.zeros((ph, pw), np.uint8)
    reg = (0, 0, gw, gh)  # the grid spans the facade (telemetry) or the content (no telemetry)
    covered_px = 0
    tiles_dir = out / "tiles"
    order = sorted(placed.values(), key=lambda p: p.bbox[0])
    needs, planned = None, {}
    if legacy:
        tiles = [(x, y) for y in range(0, gh, cfg.tile_px) for x in range(0, gw, cfg.tile_px)]
    else:

        def weight_of(k):
            return drawable(load_mask(kfs[k], (W, H)))[1]

        plan = plan_render(order, weight_of, gw, gh, cfg.tile_px, cfg.feather_px, cache_size)
        tiles, needs = plan.order, plan.needs
        per_tile = [len(v) for v in needs.values() if v]
        planned = {
            "planned_decodes": plan.decodes,
            "keyframes_per_tile": {"max": max(per_tile, default=0), "mean": round(float(np.mean(per_tile or [0])), 2)},
        }
    drawn: dict[tuple[int, int], list[PlacedKeyframe]] = {}
    for x0, y0 in tiles:
        w, h = min(cfg.tile_px, gw - x0), min(cfg.tile_px, gh - y0)
        near = [p for p in order if p.bbox[0] < x0 + w and p.bbox[2] > x0 and p.bbox[1] < y0 + h and p.bbox[3] > y0]
        drawn[(x0, y0)] = near if needs is None else [p for p in near if p.position in needs[(x0, y0)]]
    # with the plan, the cache knows every request ahead and keeps what is needed soonest
    schedule = None if legacy else [p.position for tile in tiles for p in drawn[tile]]
    sources = SourceCache(load, size=cache_size, schedule=schedule)
    for x0, y0 in _progress(tiles, "render", progress):
        w, h = min(cfg.tile_px, gw - x0), min(cfg.tile_px, gh - y0)
        near = drawn[(x0, y0)]
        img, cov = render_tile(x0, y0, w, h, near, sources, feather_px=cfg.feather_px, renderer=cfg.renderer)
        covered_px += int(np.count_nonzero(cov[max(reg[1] - y0, 0) : reg[3] - y0, max(reg[0] - x0, 0) : reg[2] - x0]))
        if in_memory:
            canvas[y0 : y0 + h, x0 : x0 + w] = img
            cov_full[y0 : y0 + h, x0 : x0 + w] = cov
        else:
            tiles_dir.mkdir(exist_ok=True)
            cv2.imwrite(str(tiles_dir / f"tile_y{y0:07d}_x{x0:07d}.png"), cv2.merge((img, cov)))
        px0, py0 = round(x0 * ps), round(y0 * ps)
        px1, py1 = min(pw, round((x0 + w) * ps)), min(ph, round((y0 + h) * ps))
        if px1 > px0 and py1 > py0:
            preview[py0:py1, px0:px1] = cv2.resize(img, (px1 - px0, py1 - py0), interpolation=cv2.INTER_AREA)
            cov_prev[py0:py1, px0:px1] = cv2.resize(cov, (px1 - px0, py1 - py0), interpolation=cv2.INTER_AREA)
    t["render"] = time.perf_counter()
    render_info = {"renderer": cfg.renderer, "tiles": len(tiles), "keyframe_decodes": sources.decoded, **planned}

    # 8. coverage, residuals, files
    cov_for_holes = cov_full if in_memory else np.where(cov_prev > 127, 255, 0).astype(np.uint8)
    sc = cov_for_holes.shape[1] / gw
    holes = uncovered_areas(
        cov_for_holes,
        grid,
        tuple(int(round(v * sc)) for v in reg),
        cell_m=cfg.uncovered_cell_m if scale_known else 16 * m_per_px,
        min_area_m2=cfg.min_uncovered_m2 if scale_known else 0.0,
    )
    reg_px = (reg[2] - reg[0]) * (reg[3] - reg[1])
    coverage_fraction = covered_px / max(1, reg_px)
    files = {}
    mm = m_per_px * 1000.0 if scale_known else None
    if in_memory:
        files["map"] = _write(out / "map.png", canvas)
        files["coverage"] = _write(out / "coverage.png", cov_full)
    else:
        files["tiles"] = str(tiles_dir)
        files["coverage_preview"] = _write(out / "coverage_preview.png", cov_prev)
    files["preview"] = _write(
        out / "map_preview.jpg",
        draw_scale_bar(annotate_uncovered(preview, grid, holes), m_per_px / ps if scale_known else None),
    )
    report_gains = {kfs[k].index: round(float(gains[k]), 4) for k in placed}
    report = _report(
        inp,
        cfg,
        results,
        al,
        placed,
        grid,
        mm,
        coverage_fraction,
        holes,
        t,
        to_norm,
        plane_unit_m,
        ransac_px,
        use_poses,
        in_memory,
        files,
        report_gains,
    )
    report["render"] = render_info
    result = StitchResult(out, grid, mm, coverage_fraction, holes, report, canvas, cov_full, files)
    # World file / CRS in wall metres, alpha for uncovered areas, the wall's geographic anchor (docs/OUTPUTS.md):
    # written before report.json so the report lists them and a finished report means a finished map folder.
    files.update(write_georeferencing(result, inp))
    files["viewer"] = write_viewer(out, {kf.index: kf.image_path for kf in inp.keyframes}, report=report)
    files["report"] = str(out / "report.json")
    tmp = out / "report.json.tmp"
    tmp.write_text(json.dumps(report, indent=1))
    tmp.replace(out / "report.json")
    return result


def _write(path: Path, img: np.ndarray) -> str:
    tmp = path.with_name(path.stem + ".tmp" + path.suffix)
    if not cv2.imwrite(str(tmp), img):
        raise CompanionError(f"cannot write {path}", "check free disk space and permissions of --out")
    tmp.replace(path)
    return str(path)


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


def _report(
    inp,
    cfg,
    results,
    al,
    placed,
    grid,
    mm,
    coverage,
    holes,
    t,
    to_norm,
    unit_m,
    ransac_px,
    use_poses,
    in_memory,
    files,
    gains,
) -> dict:
    kfs = inp.keyframes
    W, H = inp.camera.width, inp.camera.height
    px_per_unit = 1.0 / grid.m_per_px
    glob, loc, pairs = [], [], []
    for r in results:
        entry = {
            "a": kfs[r.i].index,
            "b": kfs[r.j].index,
            "accepted": r.accepted,
            "model": r.model,
            "matches": r.matches,
            "inliers": r.inliers,
            "ransac_rms_px": None if r.rms_px is None else round(r.rms_px, 3),
        }
        if not r.accepted:
            entry["reason"] = r.reason
        elif r.i in placed and r.j in placed:
            g = np.linalg.norm(apply_h(al.G[r.i] @ to_norm, r.pts_i) - apply_h(al.G[r.j] @ to_norm, r.pts_j), axis=1)
            g = g * px_per_unit
            lo = np.linalg.norm(
                forward_points(placed[r.i], r.pts_i, W, H) - forward_points(placed[r.j], r.pts_j, W, H), axis=1
            )
            glob.extend(g.tolist())
            loc.extend(lo.tolist())
            entry["global_residual_px"] = round(float(np.median(g)), 3)
            entry["local_residual_px"] = round(float(np.median(lo)), 3)
        pairs.append(entry)
    used = [kfs[k].index for k in sorted(placed)]
    dropped = [{"index": kfs[k].index, "reason": why} for k, why in sorted(al.dropped.items())]
    dropped += [
        {"index": kfs[k].index, "reason": "outside the map"}
        for k in range(len(kfs))
        if k not in placed and k not in al.dropped
    ]
    mmf = (lambda s: {k: (None if v is None else round(v * mm, 3)) for k, v in s.items()}) if mm else (lambda s: None)
    return {
        "source": inp.source,
        "keyframes_in": len(kfs) + len(inp.skipped),
        "keyframes_used": used,
        "keyframes_skipped": [sk.as_dict() for sk in inp.skipped],
        "keyframes_dropped": dropped,
        "warnings": [sk.warning() for sk in inp.skipped],
        "telemetry_prior": use_poses,
        "pairs_tried": len(results),
        "pairs_accepted": sum(r.accepted for r in results),
        "pairs_affine_fallback": sum(r.accepted and r.model == "affine" for r in results),
        "pairs_rejected": [p for p in pairs if not p["accepted"]],
        "pairs": [p for p in pairs if p["accepted"]],
        "alignment": {
            "iterations": al.iterations,
            "transfer_rms_before_px": round(al.initial_rms * inp.camera.focal_px, 3),
            "transfer_rms_after_px": round(al.final_rms * inp.camera.focal_px, 3),
            "global_residual_px": _stats(glob),
            "global_residual_mm": mmf(_stats(glob)),
            "local_residual_px": _stats(loc),
            "local_residual_mm": mmf(_stats(loc)),
        },
        "map": {
            "width_px": grid.width,
            "height_px": grid.height,
            "mm_per_px": None if mm is None else round(mm, 4),
            "along_m": [round(grid.along0_m, 3), round(grid.along0_m + grid.width * grid.m_per_px, 3)],
            "up_m": [round(grid.up_top_m - grid.height * grid.m_per_px, 3), round(grid.up_top_m, 3)],
            "in_memory": in_memory,
            "rectified_to_facade": use_poses,
        },
        "coverage_fraction": round(coverage, 4),
        "gains": gains,
        "uncovered_areas_m": [a.as_dict() for a in holes],
        "timing_s": {k: round(t[k] - t[p], 3) for p, k in zip(list(t)[:-1], list(t)[1:], strict=True)},
        "files": files,
        "config": {k: v for k, v in asdict(cfg).items()},
    }

"""Per-stage debug dump (``companion stitch --debug-dir DIR``): what each stage decided, in files a person can
open, so a bad map can be traced to the stage that went wrong.

    DIR/1-features/features.json   keypoints per keyframe, keyframes left out and why
    DIR/2-pairs/pairs.json         every candidate pair: matches, inliers, model, accepted or why not
    DIR/2-pairs/AAAAAA-BBBBBB.jpg  the inlier matches of each accepted pair, the two keyframes side by side
    DIR/3-alignment/alignment.json each round's residual per pair and the pairs it rejected; each keyframe's
                                   homography onto the plane, or why it was dropped
    DIR/4-mesh/mesh.json, mesh.png the map grid and every keyframe's mesh in map pixels, drawn on the map's frame
    DIR/5-render/coverage.png      what was drawn (white), the uncovered areas outlined; render.json

Without a directory every method does nothing, so the stitcher calls them unconditionally.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np

from companion.stitch.align import AlignedKeyframes
from companion.stitch.canvas import RenderedMap
from companion.stitch.features import KeyframeFeatures, load_image_and_mask
from companion.stitch.layout import MapLayout
from companion.stitch.output import annotate_uncovered
from companion.stitch.pairs import PairResult, RegisteredPairs
from companion.stitch.report import MapCoverage, pair_summary
from companion.stitch.unscaled import area_px

_DRAWING_WIDTH_PX = 1600  # match drawings and the mesh picture are at most this wide
_MAX_LINES = 150  # inlier lines drawn per pair


class StageDebug:
    def __init__(self, root: str | Path | None):
        self.root = None if root is None else Path(root)

    @property
    def enabled(self) -> bool:
        return self.root is not None

    def _dir(self, name: str) -> Path:
        d = self.root / name
        d.mkdir(parents=True, exist_ok=True)
        return d

    def _json(self, stage: str, name: str, doc) -> None:
        (self._dir(stage) / name).write_text(json.dumps(doc, indent=1, default=_plain))

    def features(self, found: KeyframeFeatures) -> None:
        if not self.enabled:
            return
        kfs = found.input.keyframes
        doc = {
            "keyframes": [
                {"index": kf.index, "image": str(kf.image_path), "keypoints": len(f.keypoints)}
                for kf, f in zip(kfs, found.features, strict=True)
            ],
            "left_out": [sk.as_dict() for sk in found.input.skipped],
        }
        self._json("1-features", "features.json", doc)

    def pairs(self, found: KeyframeFeatures, pairs: RegisteredPairs) -> None:
        if not self.enabled:
            return
        kfs = found.input.keyframes
        self._json(
            "2-pairs", "pairs.json", {"settings": pairs.settings, "pairs": [_pair_doc(r, kfs) for r in pairs.results]}
        )
        d = self._dir("2-pairs")
        for r in pairs.accepted:
            name = f"{kfs[r.i].index:06d}-{kfs[r.j].index:06d}.jpg"
            cv2.imwrite(str(d / name), _draw_matches(found, r), [cv2.IMWRITE_JPEG_QUALITY, 85])

    def alignment(self, found: KeyframeFeatures, aligned: AlignedKeyframes) -> None:
        if not self.enabled:
            return
        kfs = found.input.keyframes
        idx = [kf.index for kf in kfs]
        rounds = [
            {
                "transfer_rms_px": rd.transfer_rms_px,
                "iterations": rd.iterations,
                "limit_px": rd.limit_px,
                "pair_residual_px": [
                    {"a": idx[i], "b": idx[j], "median_px": round(e, 3)} for (i, j), e in rd.pair_residual_px.items()
                ],
                "rejected": [[idx[i], idx[j]] for i, j in rd.rejected],
            }
            for rd in aligned.rounds
        ]
        al = aligned.alignment
        keyframes = [
            {"index": idx[k], "plane_from_normalised": None if G is None else G, "dropped": al.dropped.get(k)}
            for k, G in enumerate(al.G)
        ]
        self._json("3-alignment", "alignment.json", {"rounds": rounds, "keyframes": keyframes})

    def mesh(self, found: KeyframeFeatures, layout: MapLayout) -> None:
        if not self.enabled:
            return
        kfs = found.input.keyframes
        g = layout.grid
        doc = {
            "grid": {
                "along0_m": g.along0_m,
                "up_top_m": g.up_top_m,
                "m_per_px": g.m_per_px,
                "size": [g.width, g.height],
            },
            "keyframes": [
                {
                    "index": kfs[k].index,
                    "local": bool(layout.meshes[k].local),
                    "inside_map": k in layout.placed,
                    "vertices_map_px": np.round(g.to_px(layout.meshes[k].dst_plane), 2),
                }
                for k in sorted(layout.meshes)
            ],
        }
        self._json("4-mesh", "mesh.json", doc)
        cv2.imwrite(str(self._dir("4-mesh") / "mesh.png"), _draw_meshes(layout))

    def render(self, rendered: RenderedMap, layout: MapLayout, coverage: MapCoverage) -> None:
        if not self.enabled:
            return
        cov = cv2.cvtColor(rendered.coverage_preview, cv2.COLOR_GRAY2BGR)
        cv2.imwrite(
            str(self._dir("5-render") / "coverage.png"), annotate_uncovered(cov, layout.grid, coverage.uncovered)
        )
        doc = {
            "info": rendered.info,
            "covered_px": rendered.covered_px,
            "coverage_fraction": coverage.fraction,
            # metres only where the map has a scale (companion.stitch.unscaled), else map pixels
            **({"uncovered_areas_m": [a.as_dict() for a in coverage.uncovered]} if layout.scale_known else
               {"uncovered_areas_px": [area_px(a, layout.grid) for a in coverage.uncovered]}),
            "gains": [round(float(v), 4) for v in rendered.gains],
        }
        self._json("5-render", "render.json", doc)


def _pair_doc(r: PairResult, kfs) -> dict:
    """The report's entry with the reason (also for accepted pairs: empty) and the model's homography."""
    return {**pair_summary(r, kfs), "reason": r.reason, "H": r.H}


def _draw_matches(found: KeyframeFeatures, r: PairResult) -> np.ndarray:
    """Both keyframes side by side (background outside the ROI darkened), the inlier matches as lines."""
    kfs = found.input.keyframes
    views = []
    for k in (r.i, r.j):
        img, mask = load_image_and_mask(kfs[k])
        views.append(np.where(mask[..., None] > 0, img, img // 3))
    h, w = views[0].shape[:2]
    s = min(1.0, _DRAWING_WIDTH_PX / (2 * w))
    both = cv2.resize(np.hstack(views), (round(2 * w * s), round(h * s)), interpolation=cv2.INTER_AREA)
    step = max(1, len(r.pts_i) // _MAX_LINES)
    for p, q in zip(r.pts_i[::step], r.pts_j[::step], strict=True):
        a = tuple(int(round(v)) for v in p * s)
        b = (int(round((q[0] + w) * s)), int(round(q[1] * s)))
        cv2.line(both, a, b, (0, 255, 0), 1, cv2.LINE_AA)
        cv2.circle(both, a, 2, (0, 0, 255), -1)
        cv2.circle(both, b, 2, (0, 0, 255), -1)
    return both


def _draw_meshes(layout: MapLayout) -> np.ndarray:
    """Every keyframe's mesh cells on the map's frame (grey: outside the map), downscaled to fit."""
    g = layout.grid
    s = min(1.0, _DRAWING_WIDTH_PX / g.width)
    canvas = np.zeros((max(1, round(g.height * s)), max(1, round(g.width * s)), 3), np.uint8)
    rng = np.random.default_rng(0)
    for k, mesh in sorted(layout.meshes.items()):
        colour = tuple(int(c) for c in rng.integers(80, 256, 3)) if k in layout.placed else (90, 90, 90)
        px = g.to_px(mesh.dst_plane) * s
        if not np.all(np.isfinite(px)):
            continue
        for row in px:
            cv2.polylines(canvas, [np.round(row).astype(np.int32)], False, colour, 1, cv2.LINE_AA)
        for col in px.transpose(1, 0, 2):
            cv2.polylines(canvas, [np.round(col).astype(np.int32)], False, colour, 1, cv2.LINE_AA)
    return canvas


def _plain(value):
    """JSON for the numpy arrays and settings records in the dump."""
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if hasattr(value, "__dataclass_fields__"):
        return {k: getattr(value, k) for k in value.__dataclass_fields__}
    raise TypeError(f"{type(value).__name__} is not JSON")

"""Mask accuracy against the simulator's ground truth: pixel error ratio (paper: 0.75 % mean) and ROI nearness."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from companion.depth.masker import Masker
from companion.depth.roi import RoiResult
from companion.depth.visual import save_visual
from companion.errors import CompanionError
from companion.plugins import provided
from companion.records import Frame, TaggedFrame


@dataclass
class FrameEval:
    index: int
    error_ratio: float
    roi_fraction: float
    true_roi_fraction: float
    empty: bool
    no_boundary: bool
    roi_nearer: bool | None  # predicted ROI's mean disparity > predicted background's (None: one side only)
    true_roi_nearer: bool | None  # model disparity, true masks: facade's mean > background's
    depth_ms: float
    mask_ms: float
    # share of the true facade pixels the mask calls background (nan: no facade in the frame)
    facade_lost: float = float("nan")
    # share of the true background pixels the mask keeps as facade (nan: no background in the frame)
    background_kept: float = float("nan")

    @property
    def wall_only(self) -> bool:
        return self.true_roi_fraction >= 1.0

    @property
    def background_only(self) -> bool:
        return self.true_roi_fraction <= 0.0


def frame_eval(index: int, truth: np.ndarray, disparity: np.ndarray, roi: RoiResult, *,
               depth_ms: float = float("nan"), mask_ms: float = float("nan")) -> FrameEval:
    """Compare one frame's ROI (at the frame's size) with its true mask (255 = facade)."""
    if truth.shape != roi.mask.shape:
        truth = cv2.resize(truth, (roi.mask.shape[1], roi.mask.shape[0]), interpolation=cv2.INTER_NEAREST)
    true_wall = truth > 127
    kept = roi.mask > 127
    n_wall = int(np.count_nonzero(true_wall))
    n_bg = true_wall.size - n_wall
    t_small = cv2.resize(truth, (disparity.shape[1], disparity.shape[0]), interpolation=cv2.INTER_NEAREST) > 127
    true_nearer = None
    if t_small.any() and not t_small.all():
        true_nearer = bool(disparity[t_small].mean() > disparity[~t_small].mean())
    return FrameEval(
        index=index,
        error_ratio=float(np.count_nonzero(kept != true_wall)) / kept.size,
        roi_fraction=roi.roi_fraction,
        true_roi_fraction=n_wall / true_wall.size,
        empty=roi.empty,
        no_boundary=roi.no_boundary,
        roi_nearer=roi.roi_nearer,
        true_roi_nearer=true_nearer,
        depth_ms=depth_ms,
        mask_ms=mask_ms,
        facade_lost=float(np.count_nonzero(true_wall & ~kept)) / n_wall if n_wall else float("nan"),
        background_kept=float(np.count_nonzero(kept & ~true_wall)) / n_bg if n_bg else float("nan"),
    )


def _mean(values) -> float:
    v = [x for x in values if not np.isnan(x)]
    return float(np.mean(v)) if v else float("nan")


@dataclass
class MaskEval:
    recording: str
    frames: list[FrameEval] = field(default_factory=list)

    @property
    def errors(self) -> np.ndarray:
        return np.array([f.error_ratio for f in self.frames])

    def summary(self) -> dict:
        e = self.errors
        nearer = [f.roi_nearer for f in self.frames if f.roi_nearer is not None]
        true_nearer = [f.true_roi_nearer for f in self.frames if f.true_roi_nearer is not None]
        return {
            "recording": self.recording,
            "frames": len(self.frames),
            "error_mean": float(e.mean()) if len(e) else float("nan"),
            "error_p95": float(np.percentile(e, 95)) if len(e) else float("nan"),
            "error_max": float(e.max()) if len(e) else float("nan"),
            "dropped_empty": sum(f.empty for f in self.frames),
            "true_empty": sum(f.true_roi_fraction == 0.0 for f in self.frames),
            # the costly mistake: a frame that shows facade dropped as all-background (lost for the map)
            "dropped_with_facade": sum(f.empty and f.true_roi_fraction > 0.0 for f in self.frames),
            # how much wall the worst of those showed (a sliver at the wall's end costs the map nothing)
            "dropped_with_facade_max_share": max((f.true_roi_fraction for f in self.frames
                                                  if f.empty and f.true_roi_fraction > 0.0), default=0.0),
            "no_boundary": sum(f.no_boundary for f in self.frames),
            "frames_with_both_sides": len(nearer),
            "roi_nearer_fraction": float(np.mean(nearer)) if nearer else float("nan"),
            "true_roi_nearer_fraction": float(np.mean(true_nearer)) if true_nearer else float("nan"),
            # what the real-texture passes report (issue 13): wall-only frames, facade lost, background kept
            "wall_only_frames": sum(f.wall_only for f in self.frames),
            "error_wall_only_mean": _mean([f.error_ratio for f in self.frames if f.wall_only]),
            "facade_lost_mean": _mean([f.facade_lost for f in self.frames]),
            "mixed_frames": sum(not f.wall_only and not f.background_only for f in self.frames),
            "background_kept_mixed_mean": _mean([f.background_kept for f in self.frames
                                                 if not f.wall_only and not f.background_only]),
            "depth_ms_median": float(np.median([f.depth_ms for f in self.frames])) if self.frames else float("nan"),
            "mask_ms_median": float(np.median([f.mask_ms for f in self.frames])) if self.frames else float("nan"),
        }


def evaluate_recording(
    path: str | Path,
    masker: Masker | None = None,
    *,
    stride: int = 1,
    max_frames: int | None = None,
    save_dir: str | Path | None = None,
) -> MaskEval:
    """Mask every ``stride``-th frame of a recording and compare with its true ROI masks."""
    open_recording = provided("open_recording", "measuring the mask against a simulator recording")
    if not Path(path).is_dir():
        raise CompanionError(f"recording not found: {path}", "pass a folder written by the camera simulator")
    rec = open_recording(path)
    masker = masker or Masker()
    result = MaskEval(recording=str(path))
    indices = list(range(0, len(rec), max(1, stride)))[: max_frames or None]
    for i in indices:
        image = rec.image(i)
        tagged = TaggedFrame(Frame(index=i, capture_time_s=rec.capture_time(i), image=image), pose=None)
        _, roi, disp = masker.mask_measured(tagged)
        truth = rec.roi_mask(i)
        result.frames.append(frame_eval(i, truth, disp, roi, depth_ms=masker.stats.depth_ms[-1],
                                        mask_ms=masker.stats.mask_ms[-1]))
        if save_dir is not None:
            save_visual(Path(save_dir) / f"{i:06d}.jpg", image, disp, roi.mask, truth)
    return result

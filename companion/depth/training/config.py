"""The settings of one ``companion depth train`` run, importable without torch (the command line reads its
defaults from here before the training extra is needed)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path


@dataclass
class TrainConfig:
    out: Path
    recordings: list[Path]
    eval_recordings: list[Path] = field(default_factory=list)
    view_seeds: list[int] = field(default_factory=list)  # random-viewpoint scenes (training)
    eval_view_seeds: list[int] = field(default_factory=list)  # random-viewpoint scenes (held out)
    views_per_seed: int = 50
    height: int = 192
    width: int = 640
    crop: tuple[int, int] | None = (128, 320)
    model_width: float = 0.25
    batch: int = 8
    lr: float = 1e-4
    lr_final: float = 1e-5
    final_fraction: float = 0.25
    smoothness: float = 1e-3
    si_lambda: float = 0.5
    min_depth: float = 0.1
    max_depth: float = 100.0
    max_minutes: float = 45.0
    max_steps: int = 1_000_000
    checkpoint_minutes: float = 3.0
    threads: int = 1
    seed: int = 0
    stride: int = 1
    source: str = ""
    init_from: Path | None = None  # fine-tune: start from this run's weights or a .onnx (fresh optimiser and clock)
    real_photos: Path | None = None  # ../shared/data: mix in real-photo composites (train split only)
    real_fraction: float = 0.5  # share of each batch that is real-photo composites
    head_warmup_steps: int = 60  # from a .onnx: steps that fit only the coarse disparity heads first
    mask_loss_weight: float = 0.0  # weight of the near/far mask hinge (training.maskloss); 0 = depth loss only
    mask_margin: float = 1.25  # the hinge's margin, a factor on disparity around the ROI keep/cut threshold
    reflect_windows: float = 0.0  # share of wall composites whose windows reflect the background (CompositeOptions)
    bright_walls: float = 0.0  # share of composites whose wall is bright grey cladding (CompositeOptions)

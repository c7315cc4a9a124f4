"""``companion depth average``: the uniform weight average of training runs (a "model soup", Wortsman et al. 2022).

Runs that share an ancestor (a base run and the runs fine-tuned from it with ``--init-from``) sit in one basin of
the loss, and the average of their weights is usually better than each of them: for our depth model the average of
the base run and its plain-wall/overcast fine-tune has a lower simulator mask error than either and keeps the
whole plain wall on the real photos, where each alone cuts a patch (docs/DEPTH.md). Runs with different
architectures, input sizes or depth ranges cannot be averaged and are refused.
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass
from pathlib import Path

import torch

from companion.depth.training.networks import Monodepth2, encoder_state_dict
from companion.depth.training.train import initial_weights
from companion.errors import CompanionError

log = logging.getLogger(__name__)

# run settings that must agree for an average to mean anything
SHARED_SETTINGS = ("model_width", "height", "width", "min_depth", "max_depth")


@dataclass
class AverageReport:
    onnx: Path
    runs: list[Path]
    max_abs_diff: float
    held_out: dict | None = None  # loss and abs. rel. depth error on the first run's held-out scenes


def _run_config(run: Path) -> dict:
    config = Path(run) / "config.json"
    if not config.is_file():
        raise CompanionError(f"{run} has no config.json", "pass run folders written by companion depth train")
    return json.loads(config.read_text())


def _held_out(model: Monodepth2, run: Path, config: dict) -> dict | None:
    """The held-out loss and depth error of the average on the first run's held-out scenes (as training reports
    them for each run), so the three can be compared; None when that run had no held-out scenes."""
    from companion.depth.training.train import TrainConfig, evaluate_torch, training_frames

    seeds = config.get("eval_view_seeds") or []
    if not seeds:
        return None
    cfg = TrainConfig(out=Path(run), recordings=[], **{k: config[k] for k in SHARED_SETTINGS})
    return evaluate_torch(model, training_frames(cfg, [], seeds, 4, 30), cfg)


def average_state_dicts(states: list[dict]) -> dict:
    """Uniform average of floating-point tensors; integer buffers (BatchNorm's step counters) from the first."""
    first = states[0]
    for other in states[1:]:
        if other.keys() != first.keys() or any(other[k].shape != first[k].shape for k in first):
            raise CompanionError(
                "the runs' networks differ (other layers or channel counts)",
                "average only runs of one architecture and width, fine-tuned from one another (--init-from)",
            )
    out = {}
    for key, value in first.items():
        if value.is_floating_point():
            out[key] = torch.stack([s[key].float() for s in states]).mean(0).to(value.dtype)
        else:
            out[key] = value.clone()
    return out


def average_runs(runs: list[Path], out: Path) -> AverageReport:
    """Average the weights of ``runs`` into ``out``: model.onnx (verified export), encoder.pth + depth.pth in the
    official layout, summary.json."""
    from companion.depth.training.export import export_onnx

    runs = [Path(r) for r in runs]
    if len(runs) < 2:
        raise CompanionError("averaging needs at least two runs", "pass two or more run folders")
    configs = [_run_config(r) for r in runs]
    settings = [{k: c.get(k) for k in SHARED_SETTINGS} for c in configs]
    for run, s in zip(runs[1:], settings[1:], strict=True):
        if s != settings[0]:
            diff = {k: (settings[0][k], s[k]) for k in SHARED_SETTINGS if s[k] != settings[0][k]}
            raise CompanionError(f"{run} was trained with other settings than {runs[0]}: {diff}",
                                 "average only runs of one model width, input size and depth range")
    cfg = settings[0]
    model = Monodepth2(width=float(cfg["model_width"]))
    model.load_state_dict(average_state_dicts([initial_weights(r) for r in runs]))
    model.eval()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    torch.save(encoder_state_dict(model, int(cfg["height"]), int(cfg["width"])), out / "encoder.pth")
    torch.save(model.depth.state_dict(), out / "depth.pth")
    names = ", ".join(r.name for r in runs)
    report = export_onnx(
        model, out / "model.onnx", height=int(cfg["height"]), width=int(cfg["width"]),
        min_depth=float(cfg["min_depth"]), max_depth=float(cfg["max_depth"]),
        source=f"companion depth average: uniform weight average of the companion depth train runs {names} "
               f"(Monodepth2 ResNet-18 layout at width {cfg['model_width']}, simulator data)",
        licence="BSD-3-Clause (companion project, trained on its simulator)",
        extra_metadata={"metric_depth": "true", "encoder_width": str(cfg["model_width"]), "averaged_runs": names},
    )
    summary = {"runs": [str(r) for r in runs], "onnx": str(report.path), "onnx_max_abs_diff": report.max_abs_diff}
    held = _held_out(model, runs[0], configs[0])
    if held is not None:
        summary["held_out"] = held
        log.info("held-out scenes %s: %s", configs[0]["eval_view_seeds"], held)
    (out / "summary.json").write_text(json.dumps(summary, indent=1))
    log.info("averaged %d runs into %s", len(runs), report.path)
    return AverageReport(report.path, runs, report.max_abs_diff, held)

"""``companion depth train``: Monodepth2 (ResNet-18 layout, reduced width) trained on simulator recordings.

Supervision: the simulator's true depth, through a scale-invariant log loss on disparity (Eigen et al., with
lambda = 0.5 so that absolute scale is learned too: the shipped model is metric, which lets the masker drop a
frame that is all background) at Monodepth2's four output scales, plus Monodepth2's edge-aware smoothness
(weight 1e-3). Adam, lr 1e-4 then 1e-5 for the last quarter of the budget (the paper's schedule in time rather
than epochs). Photometric domain randomisation (colour, light, blur, noise, JPEG) in companion.depth.training.data.

The run is bounded by wall time (``--max-minutes``), checkpoints every few minutes and resumes from ``DIR``.
"""

from __future__ import annotations

import json
import logging
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from companion.depth.training.config import TrainConfig
from companion.depth.training.data import FrameSet, augment_crop, load_frames, sample_batch
from companion.depth.training.maskloss import MaskLossParams, mask_hinge_loss
from companion.depth.training.networks import Monodepth2, disp_to_depth, encoder_state_dict
from companion.errors import CompanionError
from companion.files import atomic_path
from companion.plugins import provided

log = logging.getLogger(__name__)

SIM_LICENCE = "BSD-3-Clause (companion project, trained on its simulator)"
REAL_NC_LICENCE = (
    "research / non-commercial: trained on CMP Facade Database and LabelMeFacade photos (no permissive licence; "
    "LabelMe images for non-commercial and research use only), see ../shared/data/real-facades/ATTRIBUTION.md"
)




def silog_loss(disp: torch.Tensor, depth_gt: torch.Tensor, cfg: TrainConfig) -> torch.Tensor:
    """Scale-invariant log loss between predicted and true (scaled) disparity, per image then averaged."""
    scaled, _ = disp_to_depth(disp, cfg.min_depth, cfg.max_depth)
    g = (torch.log(scaled) - torch.log(1.0 / depth_gt)).flatten(1)
    return ((g**2).mean(1) - cfg.si_lambda * g.mean(1) ** 2).mean()


def smooth_loss(disp: torch.Tensor, img: torch.Tensor) -> torch.Tensor:
    """Monodepth2's edge-aware smoothness on mean-normalised disparity."""
    disp = disp / (disp.mean((2, 3), keepdim=True) + 1e-7)
    gdx = (disp[:, :, :, :-1] - disp[:, :, :, 1:]).abs()
    gdy = (disp[:, :, :-1, :] - disp[:, :, 1:, :]).abs()
    gix = (img[:, :, :, :-1] - img[:, :, :, 1:]).abs().mean(1, keepdim=True)
    giy = (img[:, :, :-1, :] - img[:, :, 1:, :]).abs().mean(1, keepdim=True)
    return (gdx * torch.exp(-gix)).mean() + (gdy * torch.exp(-giy)).mean()


def total_loss(
    outputs: dict, x: torch.Tensor, depth_gt: torch.Tensor, cfg: TrainConfig, facade: torch.Tensor | None = None
) -> torch.Tensor:
    """Scale-invariant depth loss + smoothness at the 4 scales, plus ``cfg.mask_loss_weight`` x the near/far mask
    hinge (companion.depth.training.maskloss) where the facade mask is given."""
    use_mask = facade is not None and cfg.mask_loss_weight > 0
    params = MaskLossParams(margin=cfg.mask_margin, min_depth=cfg.min_depth, max_depth=cfg.max_depth)
    loss = x.new_zeros(())
    for s in range(4):
        disp = outputs[("disp", s)]
        up = F.interpolate(disp, size=depth_gt.shape[-2:], mode="bilinear", align_corners=False)
        img_s = F.interpolate(x, size=disp.shape[-2:], mode="area") if s else x
        loss = loss + silog_loss(up, depth_gt, cfg) + cfg.smoothness * smooth_loss(disp, img_s) / (2**s)
        if use_mask:
            loss = loss + cfg.mask_loss_weight * mask_hinge_loss(up, depth_gt, facade, params)
    return loss / 4.0


def init_disparity_bias(model: Monodepth2, cfg: TrainConfig, typical_depth_m: float) -> None:
    """Start the sigmoid outputs at a typical scan depth instead of 0.5 (= 0.2 m), so that the lr 1e-4 steps go
    to shapes, not to shifting every output by 4 logits first."""
    min_disp, max_disp = 1.0 / cfg.max_depth, 1.0 / cfg.min_depth
    p = (1.0 / typical_depth_m - min_disp) / (max_disp - min_disp)
    logit = float(np.log(p / (1 - p)))
    for s in model.depth.scales:
        torch.nn.init.constant_(model.depth._conv("dispconv", s).conv.bias, logit)


def initial_weights(path: Path) -> dict:
    """Model weights of an earlier run (its folder or its checkpoint.pt), for fine-tuning on changed data."""
    path = Path(path)
    if path.suffix == ".onnx":
        if not path.is_file():
            raise CompanionError(f"no model at {path}", "pass an existing .onnx file or a run folder")
        return {}  # rebuilt from the ONNX file once training data is there (BatchNorm calibration)
    ckpt = path / "checkpoint.pt" if path.is_dir() else path
    if not ckpt.is_file():
        raise CompanionError(f"no training checkpoint at {ckpt}", "pass a run folder of companion depth train")
    state = torch.load(ckpt, map_location="cpu", weights_only=False)
    if not isinstance(state, dict) or "model" not in state:
        raise CompanionError(f"{ckpt} is not a companion depth train checkpoint", "pass a run folder's checkpoint.pt")
    return state["model"]


def _save_checkpoint(path: Path, model, opt, step: int, elapsed_s: float) -> None:
    with atomic_path(path) as tmp:
        torch.save({"model": model.state_dict(), "opt": opt.state_dict(), "step": step, "elapsed_s": elapsed_s}, tmp)


@torch.no_grad()
def evaluate_torch(model: Monodepth2, frames: FrameSet, cfg: TrainConfig, batch: int = 4) -> dict:
    """Held-out loss and absolute relative depth error of the full-size frames (no augmentation)."""
    model.eval()
    losses, absrel = [], []
    for i in range(0, len(frames), batch):
        x = torch.from_numpy(
            np.stack([f[..., ::-1].transpose(2, 0, 1) for f in frames.images[i : i + batch]]).astype(np.float32) / 255
        )
        d = torch.from_numpy(frames.depths[i : i + batch][:, None].astype(np.float32))
        f = torch.from_numpy(frames.roi_masks[i : i + batch][:, None] > 0)
        out = model.forward_all(x)
        losses.append(float(total_loss(out, x, d, cfg, f)))
        _, depth = disp_to_depth(out[("disp", 0)], cfg.min_depth, cfg.max_depth)
        valid = d < cfg.max_depth * 0.99
        absrel.append(float(((depth - d).abs() / d)[valid].mean()))
    model.train()
    return {"loss": float(np.mean(losses)), "abs_rel_facade_and_near": float(np.mean(absrel))}


def training_frames(
    cfg: TrainConfig, recordings: list[Path], view_seeds: list[int], stride: int, n_views: int
) -> FrameSet:
    """Frames of recordings and random-view scenes (rendered once into ``cfg.out/data``), depth as float16."""
    parts = []
    if recordings:
        parts.append(load_frames(recordings, cfg.height, cfg.width, cfg.max_depth, stride))
    if view_seeds:
        cached_views = provided("training_views", "training on random-view simulator scenes (--view-seeds)")
        parts.append(cached_views(cfg.out / "data", view_seeds, n_views, cfg.height, cfg.width, cfg.max_depth))
    # depth kept as float16 in memory (metres to 0.05 %): ~0.25 MB per frame instead of 0.5
    return FrameSet(
        np.concatenate([p.images for p in parts]),
        np.concatenate([p.depths.astype(np.float16) for p in parts]),
        np.concatenate([p.roi_masks for p in parts]),
    )


def mixed_batch(
    frames: FrameSet, bank, cfg: TrainConfig, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A training batch (inputs, true depth, facade masks): simulator frames, and with a photo bank
    ``cfg.real_fraction`` of real-photo composites."""
    n_real = 0 if bank is None else int(round(cfg.batch * cfg.real_fraction))
    xs, ds, fs = [], [], []
    if cfg.batch - n_real:
        xs, ds, fs = (list(a) for a in sample_batch(frames, cfg.batch - n_real, cfg.crop, rng, max_depth=cfg.max_depth))
    if n_real:
        from companion.depth.training.composite import CompositeOptions, compose

        options = CompositeOptions(reflect_windows=cfg.reflect_windows, bright_walls=cfg.bright_walls)
        for _ in range(n_real):
            c = compose(bank, rng, cfg.height, cfg.width, cfg.max_depth, options=options)
            x, d, f = augment_crop(c.image, c.depth, c.facade, c.sky, rng, cfg.crop, bright_walls=options.bright_walls)
            xs.append(x)
            ds.append(d)
            fs.append(f)
    return np.stack(xs), np.stack(ds).astype(np.float32), np.stack(fs)


def start_from_onnx(path: Path, cfg: TrainConfig, frames: FrameSet, bank) -> Monodepth2:
    """The shipped ONNX model as a trainable network: BatchNorm rebuilt on 64 training crops, then the coarse
    disparity heads (absent from the file) fitted alone for ``cfg.head_warmup_steps`` batches."""
    from companion.depth.training.onnx_weights import fit_missing_heads, model_from_onnx

    rng = np.random.default_rng(cfg.seed + 7)
    n_batches = max(1, 64 // cfg.batch)
    calib = torch.from_numpy(np.concatenate([mixed_batch(frames, bank, cfg, rng)[0] for _ in range(n_batches)]))
    model = model_from_onnx(path, calib)
    if model.width != cfg.model_width:
        raise CompanionError(f"{path} has encoder width {model.width}, the run asks for {cfg.model_width}",
                             f"pass --model-width {model.width}")

    def batches():
        while True:
            xb, db, _ = mixed_batch(frames, bank, cfg, rng)
            yield torch.from_numpy(xb), torch.from_numpy(db)

    last = fit_missing_heads(model, batches(), lambda out, x, d: total_loss(out, x, d, cfg), cfg.head_warmup_steps)
    log.info("started from %s (BatchNorm rebuilt, coarse heads fitted: loss %.4f)", path, last)
    model.train()
    return model


def train(cfg: TrainConfig) -> Path:
    """Train (or resume) into ``cfg.out``; returns the exported ONNX path. Bounded by ``cfg.max_minutes``."""
    if not cfg.recordings and not cfg.view_seeds:
        raise CompanionError("no training data", "pass --seeds / --view-seeds (rendered here) or --recordings DIR ...")
    torch.set_num_threads(cfg.threads)
    torch.manual_seed(cfg.seed)
    out = cfg.out
    out.mkdir(parents=True, exist_ok=True)
    ckpt = out / "checkpoint.pt"
    # read before the (slow) data so that a wrong path fails at once
    initial = initial_weights(cfg.init_from) if cfg.init_from is not None and not ckpt.is_file() else None
    (out / "config.json").write_text(json.dumps(asdict(cfg), default=str, indent=1))
    frames = training_frames(cfg, cfg.recordings, cfg.view_seeds, cfg.stride, cfg.views_per_seed)
    bank = None
    if cfg.real_photos is not None:
        from companion.depth.training.composite import load_photo_bank

        bank = load_photo_bank(cfg.real_photos)
    held = None
    if cfg.eval_recordings or cfg.eval_view_seeds:
        held = training_frames(cfg, cfg.eval_recordings, cfg.eval_view_seeds, 4, 30)
    log.info("training on %d frames (%d recordings, %d view scenes)", len(frames), len(cfg.recordings),
             len(cfg.view_seeds))

    model = Monodepth2(width=cfg.model_width)
    opt = torch.optim.Adam(model.parameters(), lr=cfg.lr)
    step, elapsed0 = 0, 0.0
    if ckpt.is_file():
        state = torch.load(ckpt, map_location="cpu", weights_only=False)
        model.load_state_dict(state["model"])
        opt.load_state_dict(state["opt"])
        step, elapsed0 = int(state["step"]), float(state["elapsed_s"])
        log.info("resumed from step %d (%.1f min)", step, elapsed0 / 60)
    elif initial is not None and Path(cfg.init_from).suffix == ".onnx":
        model = start_from_onnx(Path(cfg.init_from), cfg, frames, bank)
        opt = torch.optim.Adam(model.parameters(), lr=cfg.lr)
    elif initial is not None:
        model.load_state_dict(initial)
        log.info("fine-tuning from %s", cfg.init_from)
    else:
        init_disparity_bias(model, cfg, typical_depth_m=6.0)
    rng = np.random.default_rng(cfg.seed + step)
    budget_s = cfg.max_minutes * 60.0
    t_start = time.monotonic()
    last_ckpt = t_start
    logf = (out / "train.jsonl").open("a")
    model.train()
    while True:
        elapsed = elapsed0 + time.monotonic() - t_start
        if elapsed >= budget_s or step >= cfg.max_steps:
            break
        progress = max(elapsed / budget_s, step / cfg.max_steps)
        lr = cfg.lr if progress < 1.0 - cfg.final_fraction else cfg.lr_final
        for group in opt.param_groups:
            group["lr"] = lr
        xb, db, fb = mixed_batch(frames, bank, cfg, rng)
        x, d = torch.from_numpy(xb), torch.from_numpy(db)
        loss = total_loss(model.forward_all(x), x, d, cfg, torch.from_numpy(fb))
        opt.zero_grad()
        loss.backward()
        opt.step()
        step += 1
        if step % 25 == 0:
            rec = {"step": step, "minutes": round(elapsed / 60, 2), "lr": lr, "loss": round(loss.item(), 5)}
            if held is not None and step % 250 == 0:
                rec["held_out"] = evaluate_torch(model, held, cfg)
            logf.write(json.dumps(rec) + "\n")
            logf.flush()
            log.info("%s", rec)
        if time.monotonic() - last_ckpt > cfg.checkpoint_minutes * 60:
            _save_checkpoint(ckpt, model, opt, step, elapsed0 + time.monotonic() - t_start)
            last_ckpt = time.monotonic()
    elapsed = elapsed0 + time.monotonic() - t_start
    _save_checkpoint(ckpt, model, opt, step, elapsed)
    return finish(model, cfg, step, elapsed, held)


def finish(model: Monodepth2, cfg: TrainConfig, step: int, elapsed_s: float, held: FrameSet | None) -> Path:
    """Save official-layout checkpoints, export the verified ONNX and write the summary."""
    from companion.depth.training.export import export_onnx

    model.eval()
    out = cfg.out
    torch.save(encoder_state_dict(model, cfg.height, cfg.width), out / "encoder.pth")
    torch.save(model.depth.state_dict(), out / "depth.pth")
    source = cfg.source or (
        f"companion depth train: Monodepth2 ResNet-18 layout at width {cfg.model_width}, "
        f"{len(cfg.recordings)} simulator recordings + {len(cfg.view_seeds)} random-view scenes"
        + (f" + real-photo composites ({cfg.real_fraction:.0%} of each batch, train split of {cfg.real_photos})"
           if cfg.real_photos is not None else "")
        + (f" (windows reflecting the background in {cfg.reflect_windows:.0%}, bright cladding in "
           f"{cfg.bright_walls:.0%})" if cfg.real_photos is not None and (cfg.reflect_windows or cfg.bright_walls)
           else "")
        + (f", near/far mask loss weight {cfg.mask_loss_weight:g} (margin {cfg.mask_margin:g})"
           if cfg.mask_loss_weight > 0 else "")
        + (f", fine-tuned from {Path(cfg.init_from).name}" if cfg.init_from is not None else "")
        + f", {step} steps of batch {cfg.batch}, {elapsed_s / 60:.0f} min CPU"
    )
    licence = REAL_NC_LICENCE if cfg.real_photos is not None else SIM_LICENCE
    report = export_onnx(
        model, out / "model.onnx", height=cfg.height, width=cfg.width, min_depth=cfg.min_depth,
        max_depth=cfg.max_depth, source=source, licence=licence,
        extra_metadata={"metric_depth": "true", "encoder_width": str(cfg.model_width), "train_steps": str(step)},
    )
    summary = {
        "steps": step, "minutes": elapsed_s / 60, "onnx": str(report.path), "onnx_max_abs_diff": report.max_abs_diff
    }
    if held is not None:
        summary["held_out"] = evaluate_torch(model, held, cfg)
    (out / "summary.json").write_text(json.dumps(summary, indent=1))
    log.info("training done: %s", summary)
    return report.path

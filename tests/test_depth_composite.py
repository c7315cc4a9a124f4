"""Real-photo training composites: exact depth on the wall plane, far background, labels that agree with depth,
only the train split loaded; the shipped ONNX model rebuilt as a trainable network; one real training step."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from companion.depth.session import SHIPPED_MODELS
from companion.depth.training.composite import (
    BACKGROUND_M,
    STANDOFF_M,
    BackgroundPhoto,
    CompositeOptions,
    PhotoBank,
    WallPhoto,
    compose,
    load_photo_bank,
)
from companion.depth.training.realdata import list_real_photos
from evaluation.shared_data import shared_data_root

SIM_MODEL = SHIPPED_MODELS["sim"]  # the shipped simulator-only model: where real-photo fine-tunes start

DATA = shared_data_root()
needs_data = pytest.mark.skipif(not (DATA / "real-facades").is_dir(), reason="../shared/data not beside the checkout")
MAX_DEPTH = 100.0


def _synthetic_bank() -> PhotoBank:
    """A wall photo whose top quarter is sky (not facade) and a background photo whose top half is sky."""
    rng = np.random.default_rng(1)
    wall = (rng.random((120, 200, 3)) * 255).astype(np.uint8)
    facade = np.ones((120, 200), bool)
    facade[:30] = False
    bg = np.full((150, 200, 3), 90, np.uint8)
    sky = np.zeros((150, 200), bool)
    sky[:75] = True
    return PhotoBank((WallPhoto(wall, facade, "w"),), (BackgroundPhoto(bg, sky, "b"),))


def _rays(K: np.ndarray, h: int, w: int) -> np.ndarray:
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    return np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], -1)


@pytest.mark.parametrize("seed", range(25))
def test_wall_pixels_lie_on_the_plane_and_background_is_far(seed):
    c = compose(_synthetic_bank(), np.random.default_rng(seed), 192, 640, MAX_DEPTH, background_only=False)
    wall = c.facade > 0
    assert c.image.shape == (192, 640, 3) and c.depth.shape == (192, 640) and c.depth.dtype == np.float32
    if wall.any():
        # back-projected wall pixels satisfy the plane equation: depth is exactly the plane's along each ray
        points = _rays(c.K, 192, 640)[wall] * c.depth[wall][:, None].astype(np.float64)
        np.testing.assert_allclose(points @ c.plane_normal, c.plane_offset, rtol=1e-6)
        assert STANDOFF_M[0] <= c.plane_offset <= STANDOFF_M[1]
        assert c.depth[wall].max() < BACKGROUND_M[0]  # a wall is never read as background
    # labels agree with depth: everything that is not wall is background at >= 20 m, its sky at the clip depth
    assert (c.depth[~wall] >= min(BACKGROUND_M[0], MAX_DEPTH)).all()
    np.testing.assert_array_equal(c.depth[c.sky], MAX_DEPTH)
    assert not (c.sky & wall).any()
    bg = ~wall & ~c.sky
    np.testing.assert_array_equal(c.depth[bg], np.float32(min(c.background_depth_m, MAX_DEPTH)))


def test_views_include_wall_ends_and_full_wall_frames():
    bank, rng = _synthetic_bank(), np.random.default_rng(0)
    shares = [np.count_nonzero(c.facade) / c.facade.size
              for c in (compose(bank, rng, 96, 320, background_only=False) for _ in range(80))]
    assert any(s == 1.0 for s in shares)  # mid-wall frames
    assert sum(0.05 < s < 0.95 for s in shares) >= 10  # the wall's end or top in view


def test_background_only_frame_has_no_wall():
    c = compose(_synthetic_bank(), np.random.default_rng(3), 192, 640, MAX_DEPTH, background_only=True)
    assert not c.facade.any() and c.plane_normal is None
    assert (c.depth >= BACKGROUND_M[0]).all()


def _tiny_root(tmp_path: Path, per_kind: int = 2) -> Path:
    """A copy (symlinks) of a few train-split photos of each source, plus held-out ones that must stay unread."""
    photos = list_real_photos(DATA)
    picks = []
    for source in ("cmp", "labelmefacade", "labelmefacade-bg"):
        for split in ("train", "heldout"):
            picks += [p for p in photos if p.source == source and p.split == split][:per_kind]
    for p in picks:
        for f in (p.image, p.label):
            dst = tmp_path / f.relative_to(DATA)
            dst.parent.mkdir(parents=True, exist_ok=True)
            os.symlink(f, dst)
    return tmp_path


@needs_data
def test_photo_bank_loads_only_the_train_split(tmp_path):
    root = _tiny_root(tmp_path)
    train_names = {p.image.name for p in list_real_photos(root, split="train")}
    held_names = {p.image.name for p in list_real_photos(root, split="heldout")}
    assert held_names
    bank = load_photo_bank(root)
    loaded = {w.name for w in bank.walls} | {b.name for b in bank.backgrounds}
    assert loaded and loaded <= train_names and not loaded & held_names
    for w in bank.walls:
        assert w.image.shape[:2] == w.facade.shape and 0.2 <= w.facade.mean() <= 1.0
        # window glass (CMP class 3, LabelMe 0:0:128) is loaded at the same size and is part of the facade
        assert w.windows is not None and w.windows.shape == w.facade.shape and w.windows.any()
        assert not (w.windows & ~w.facade).any()
    c = compose(bank, np.random.default_rng(0), 192, 640, background_only=False)
    assert c.facade.any()


def test_onnx_model_rebuilds_as_the_same_network():
    import onnxruntime as ort
    import torch

    from companion.depth.training.onnx_weights import model_from_onnx

    calib = torch.rand(3, 3, 96, 320, generator=torch.Generator().manual_seed(0))
    model = model_from_onnx(SIM_MODEL, calib)
    x = torch.rand(1, 3, 192, 640, generator=torch.Generator().manual_seed(1))
    with torch.no_grad():
        ref = model(x).numpy()
    sess = ort.InferenceSession(str(SIM_MODEL), providers=["CPUExecutionProvider"])
    assert np.abs(sess.run(None, {"image": x.numpy()})[0] - ref).max() < 1e-5
    # rebuilt BatchNorm: statistics of the calibration images, so train mode starts close to the shipped model
    with torch.no_grad():
        eval_mode = model(calib).numpy()
        model.train()
        train_mode = model(calib).numpy()
    assert np.abs(train_mode - eval_mode).mean() < 1e-3


@needs_data
def test_real_photo_training_step_exports_a_non_commercial_model(tmp_path):
    import onnx
    import torch

    from companion.depth.training.train import TrainConfig, train

    root = _tiny_root(tmp_path / "data", per_kind=1)
    cfg = TrainConfig(out=tmp_path / "run", recordings=[], view_seeds=[300], views_per_seed=3, batch=2,
                      crop=(64, 160), max_steps=2, max_minutes=10, init_from=SIM_MODEL, real_photos=root,
                      real_fraction=0.5, head_warmup_steps=1, threads=1, mask_loss_weight=2.0)
    torch.manual_seed(0)
    path = train(cfg)
    meta = {p.key: p.value for p in onnx.load(str(path)).metadata_props}
    assert "non-commercial" in meta["licence"] and "real-photo composites" in meta["source"]
    assert "near/far mask loss weight 2" in meta["source"]  # the steps ran with the mask loss
    assert meta["train_steps"] == "2"
    # the run started from the shipped weights and moved away from them
    from companion.depth.training.onnx_weights import model_from_onnx

    start, trained = model_from_onnx(SIM_MODEL), model_from_onnx(path)
    a = start.depth.state_dict()["decoder.0.conv.conv.weight"]
    b = trained.depth.state_dict()["decoder.0.conv.conv.weight"]
    assert 0 < float((a - b).abs().max()) < 0.05


def _bank_with_windows(windows: bool = True) -> PhotoBank:
    """A grey textured wall with two window panes before a saturated green background (top half blue sky)."""
    rng = np.random.default_rng(2)
    wall = np.repeat((100 + rng.random((120, 200, 1)) * 60).astype(np.uint8), 3, axis=2)  # grey: chroma 0
    facade = np.ones((120, 200), bool)
    glass = np.zeros((120, 200), bool)
    glass[30:90, 20:80] = glass[30:90, 120:180] = True
    bg = np.zeros((150, 200, 3), np.uint8)
    bg[:] = (20, 200, 20)  # BGR green: trees
    sky = np.zeros((150, 200), bool)
    sky[:75] = True
    bg[sky] = (230, 180, 120)
    return PhotoBank((WallPhoto(wall, facade, "w", glass if windows else None),), (BackgroundPhoto(bg, sky, "b"),))


def _compose_many(bank: PhotoBank, options: CompositeOptions, seed: int, n: int = 12) -> list:
    """``n`` composites, each from its own generator (an option's extra draws come last in a sample, so sample i
    with and without it is the same view)."""
    return [compose(bank, np.random.default_rng((seed, i)), 96, 320, MAX_DEPTH, options=options) for i in range(n)]


def test_options_off_give_the_samples_of_before():
    """Off draws nothing extra: window labels in the bank and explicit zero options change no bit of a sample
    (checked once against the code before the options: the same SHA-1 over 40 composites and their crops)."""
    for seed in range(3):
        before = _compose_many(_bank_with_windows(windows=False), CompositeOptions(), seed)
        now = _compose_many(_bank_with_windows(), CompositeOptions(reflect_windows=0.0, bright_walls=0.0), seed)
        for a, b in zip(before, now, strict=True):
            for field in ("image", "depth", "facade", "sky"):
                np.testing.assert_array_equal(getattr(a, field), getattr(b, field))


@pytest.mark.parametrize("seed", range(6))
def test_reflecting_windows_turn_toward_the_background_and_keep_the_walls_depth(seed):
    bank = _bank_with_windows()
    off = _compose_many(bank, CompositeOptions(), seed)
    on = _compose_many(bank, CompositeOptions(reflect_windows=1.0), seed)
    moved = 0
    for a, b in zip(off, on, strict=True):
        # the truth is untouched: same depth (the wall plane's on the panes), same facade and sky labels
        np.testing.assert_array_equal(a.depth, b.depth)
        np.testing.assert_array_equal(a.facade, b.facade)
        np.testing.assert_array_equal(a.sky, b.sky)
        changed = np.abs(a.image.astype(int) - b.image.astype(int)).max(axis=2) > 0
        assert not (changed & (a.facade == 0)).any()  # only wall pixels (the panes) change
        if changed.sum() > 50:
            # toward the background's colours: from the grey wall (chroma 0) to green trees or blue sky
            # (chroma 110-180, dimmed to 0.6x at least), at a strength of 0.35 or more (pane edges are partly glass)
            before, after = (float(np.ptp(im[changed].astype(float), axis=1).mean()) for im in (a.image, b.image))
            assert after > before + 8
            moved += 1
    assert moved >= 3


def test_a_wall_without_window_labels_never_reflects():
    bank = _bank_with_windows(windows=False)
    off, on = _compose_many(bank, CompositeOptions(), 4), _compose_many(bank, CompositeOptions(1.0), 4)
    for a, b in zip(off, on, strict=True):
        np.testing.assert_array_equal(a.image, b.image)


@pytest.mark.parametrize("flags", [["--reflect-windows", "1.5"], ["--bright-walls", "-0.1"]])
def test_train_command_refuses_a_share_outside_0_to_1(tmp_path, capsys, flags):
    from companion.cli import main

    rc = main(["depth", "train", "--out", str(tmp_path / "run"), "--view-seeds", "0", *flags])
    assert rc != 0
    assert "between 0 and 1" in capsys.readouterr().err
    assert not (tmp_path / "run").exists()  # refused before anything was written or rendered

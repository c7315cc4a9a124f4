"""Exporter round trip: random Monodepth2 weights in the official key layout -> ONNX -> onnxruntime == torch."""

from __future__ import annotations

import json

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("onnx")

from companion.cli import main  # noqa: E402
from companion.depth.session import DepthSession  # noqa: E402
from companion.depth.training.networks import Monodepth2, encoder_state_dict, load_official  # noqa: E402
from companion.errors import CompanionError  # noqa: E402


def _official_checkpoints(tmp_path, width=1.0):
    torch.manual_seed(0)
    model = Monodepth2(width=width)
    # give the BatchNorm layers non-trivial statistics, as trained weights have
    for m in model.modules():
        if isinstance(m, torch.nn.BatchNorm2d):
            m.running_mean.uniform_(-0.1, 0.1)
            m.running_var.uniform_(0.5, 1.5)
    enc = encoder_state_dict(model, 192, 640)
    c = model.encoder.num_ch_enc[-1]
    enc["encoder.fc.weight"] = torch.randn(1000, c)  # torchvision's classifier is in the official file
    enc["encoder.fc.bias"] = torch.randn(1000)
    torch.save(enc, tmp_path / "encoder.pth")
    torch.save(model.depth.state_dict(), tmp_path / "depth.pth")
    return model.eval()


def test_official_key_layout():
    model = Monodepth2()
    enc_keys = set(model.encoder.state_dict())
    assert {"encoder.conv1.weight", "encoder.bn1.running_var", "encoder.layer1.0.conv1.weight",
            "encoder.layer4.1.bn2.bias", "encoder.layer2.0.downsample.0.weight"} <= enc_keys
    dec_keys = set(model.depth.state_dict())
    # ModuleList order of the original: upconv (4,0),(4,1),...,(0,1) then dispconv 0..3
    assert "decoder.0.conv.conv.weight" in dec_keys and "decoder.9.conv.conv.bias" in dec_keys
    assert "decoder.10.conv.weight" in dec_keys and "decoder.13.conv.weight" in dec_keys
    assert model.depth.state_dict()["decoder.0.conv.conv.weight"].shape == (256, 512, 3, 3)
    assert model.depth.state_dict()["decoder.13.conv.weight"].shape == (1, 128, 3, 3)
    assert sum(p.numel() for p in model.encoder.parameters()) == 11176512  # resnet18 without fc


def test_export_round_trip_cli(tmp_path, capsys):
    model = _official_checkpoints(tmp_path)
    out = tmp_path / "model.onnx"
    code = main(["depth", "export", "--encoder", str(tmp_path / "encoder.pth"), "--decoder",
                 str(tmp_path / "depth.pth"), "--out", str(out), "--size", "96x320"])
    assert code == 0
    printed = capsys.readouterr().out
    diff = float(printed.rsplit("max abs diff", 1)[1])
    assert diff < 1e-4

    sess = DepthSession(out, threads=1)
    assert (sess.info.height, sess.info.width) == (96, 320)
    meta = sess.info.metadata
    assert meta["input_height"] == "96" and meta["input_width"] == "320"
    assert "encoder.pth" in meta["source"] and meta["licence"]
    assert meta["trained_height"] == "192"
    # the runtime path (BGR uint8 -> resize -> RGB [0,1]) agrees with torch on the same preprocessed input
    rng = np.random.default_rng(0)
    image = rng.integers(0, 255, (300, 1000, 3), dtype=np.uint8)
    x = sess.preprocess(image)
    with torch.no_grad():
        ref = model(torch.from_numpy(x)).numpy()[0, 0]
    got = sess.disparity(image)
    assert got.shape == (96, 320)
    assert np.max(np.abs(got - ref)) < 1e-4


def test_reduced_width_checkpoint_loads_with_inferred_width(tmp_path):
    _official_checkpoints(tmp_path, width=0.25)
    model, extras = load_official(tmp_path / "encoder.pth", tmp_path / "depth.pth")
    assert model.width == 0.25 and extras["height"] == 192


def test_bad_checkpoints(tmp_path):
    _official_checkpoints(tmp_path)
    with pytest.raises(CompanionError, match="not found"):
        load_official(tmp_path / "missing.pth", tmp_path / "depth.pth")
    # decoder and encoder swapped: the decoder file has no encoder keys
    with pytest.raises(CompanionError, match="not a Monodepth2 encoder"):
        load_official(tmp_path / "depth.pth", tmp_path / "encoder.pth")
    # a decoder of another width does not fit the encoder
    torch.save(Monodepth2(width=0.5).depth.state_dict(), tmp_path / "other.pth")
    with pytest.raises(CompanionError, match="does not match"):
        load_official(tmp_path / "encoder.pth", tmp_path / "other.pth")
    (tmp_path / "junk.pth").write_bytes(b"not a checkpoint")
    with pytest.raises(CompanionError, match="cannot read"):
        load_official(tmp_path / "junk.pth", tmp_path / "depth.pth")


def test_train_short_run_then_fine_tune_starts_from_its_weights(tmp_path):
    """A few steps of the real training loop on rendered views export a verified ONNX; ``init_from`` carries the
    weights into a new run (zero further steps: the same model), and a wrong ``init_from`` fails before any data."""
    from companion.depth.training.train import TrainConfig, train

    common = dict(recordings=[], view_seeds=[0], views_per_seed=3, crop=(64, 128), batch=2, threads=1)
    first = train(TrainConfig(out=tmp_path / "a", max_steps=3, **common))
    # another torch seed: without init_from its weights would differ
    tuned = train(TrainConfig(out=tmp_path / "b", max_steps=0, init_from=tmp_path / "a", seed=1, **common))
    fresh = train(TrainConfig(out=tmp_path / "d", max_steps=0, seed=1, **common))
    image = np.random.default_rng(0).integers(0, 256, (192, 640, 3), dtype=np.uint8)
    first_disp = DepthSession(first).disparity(image)
    np.testing.assert_allclose(DepthSession(tuned).disparity(image), first_disp, atol=1e-6)
    assert np.abs(DepthSession(fresh).disparity(image) - first_disp).max() > 1e-4
    with pytest.raises(CompanionError, match="no training checkpoint"):
        train(TrainConfig(out=tmp_path / "c", max_steps=1, init_from=tmp_path / "missing", **common))
    assert not (tmp_path / "c" / "data").exists()


def test_average_of_runs_is_the_mean_of_their_weights(tmp_path, capsys):
    """``companion depth average`` writes the verified ONNX of the uniform weight average; runs of another width or
    a single run are refused with the fix."""
    from companion.depth.training.train import TrainConfig, initial_weights, train

    common = dict(recordings=[], view_seeds=[0], views_per_seed=3, crop=(64, 128), batch=2, threads=1)
    train(TrainConfig(out=tmp_path / "base", max_steps=2, eval_view_seeds=[1000], **common))
    train(TrainConfig(out=tmp_path / "tuned", max_steps=2, init_from=tmp_path / "base", seed=1, **common))
    runs = [str(tmp_path / "base"), str(tmp_path / "tuned")]
    assert main(["depth", "average", *runs, "--out", str(tmp_path / "avg")]) == 0
    printed = capsys.readouterr().out
    assert "average of 2 runs" in printed and "held-out scenes: loss" in printed
    held = json.loads((tmp_path / "avg" / "summary.json").read_text())["held_out"]
    assert held["loss"] > 0 and 0 < held["abs_rel_facade_and_near"] < 10

    a, b = initial_weights(tmp_path / "base"), initial_weights(tmp_path / "tuned")
    model = Monodepth2(width=0.25)
    model.load_state_dict({k: (a[k] + b[k]) / 2 if a[k].is_floating_point() else a[k] for k in a})
    model.eval()
    image = np.random.default_rng(3).integers(0, 256, (192, 640, 3), dtype=np.uint8)
    session = DepthSession(tmp_path / "avg" / "model.onnx")
    x = torch.from_numpy(session.preprocess(image))
    with torch.no_grad():
        expected = model(x).numpy()[0, 0]
    np.testing.assert_allclose(session.disparity(image), expected, atol=1e-5)
    assert session.info.metric and "base, tuned" in session.info.metadata["averaged_runs"]
    # the official-layout checkpoints load back to the same network
    reloaded, _ = load_official(tmp_path / "avg" / "encoder.pth", tmp_path / "avg" / "depth.pth")
    assert reloaded.width == 0.25

    train(TrainConfig(out=tmp_path / "wide", max_steps=0, **{**common, "model_width": 0.5}))
    with pytest.raises(CompanionError, match="other settings"):
        from companion.depth.training.average import average_runs

        average_runs([tmp_path / "base", tmp_path / "wide"], tmp_path / "bad")
    assert main(["depth", "average", str(tmp_path / "base"), "--out", str(tmp_path / "one")]) == 2
    assert "at least two runs" in capsys.readouterr().err

"""Runtime without torch: model-file errors, and the shipped model turning TaggedFrames into MaskedFrames."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from companion.depth.masker import Masker
from companion.depth.session import DEFAULT_MODEL, DepthSession
from companion.errors import CompanionError
from companion.records import Frame, MaskedFrame, TaggedFrame

FIXTURES = Path(__file__).parent / "depth_fixtures"


def test_missing_model_names_the_file(tmp_path):
    with pytest.raises(CompanionError) as err:
        DepthSession(tmp_path / "nope.onnx")
    assert "nope.onnx" in str(err.value) and err.value.fix


def test_garbage_file_is_not_a_model(tmp_path):
    bad = tmp_path / "model.onnx"
    bad.write_bytes(b"this is not protobuf" * 10)
    with pytest.raises(CompanionError, match="not a loadable ONNX model"):
        DepthSession(bad)


def test_incompatible_model_is_rejected():
    # a valid ONNX file whose input is one grey channel, not 1x3xHxW RGB
    with pytest.raises(CompanionError, match="not a Monodepth2-style model") as err:
        DepthSession(FIXTURES / "grey_input.onnx")
    assert "1x3xHxW" in err.value.fix


def test_shipped_model_metadata():
    assert DEFAULT_MODEL.is_file(), "the default depth model must ship inside the package"
    assert DEFAULT_MODEL.stat().st_size < 8_000_000
    info = DepthSession(threads=1).info
    assert (info.height, info.width) == (192, 640)
    assert info.metric and info.metadata["licence"].startswith("BSD-3-Clause")
    assert 0 < info.disparity_for_depth(4.0) < 1
    assert info.depth_from_disparity(np.float32(info.disparity_for_depth(4.0))) == pytest.approx(4.0, rel=1e-4)


def test_masker_turns_tagged_frame_into_masked_frame():
    masker = Masker(threads=1)
    rng = np.random.default_rng(0)
    image = rng.integers(0, 255, (360, 640, 3), dtype=np.uint8)
    tagged = TaggedFrame(Frame(index=7, capture_time_s=1.5, image=image), pose=None)
    masked, roi, disparity = masker.mask_measured(tagged)
    assert masker.stats.frames == 1 and len(masker.stats.depth_ms) == 1
    if masked is None:
        assert roi.empty and masker.stats.dropped_empty == 1
    else:
        assert isinstance(masked, MaskedFrame) and masked.tagged is tagged
        assert masked.mask.shape == (360, 640) and masked.mask.dtype == np.uint8
        assert disparity.shape == (192, 640)


def test_masker_rejects_non_image():
    masker = Masker(threads=1)
    with pytest.raises(CompanionError, match="BGR"):
        masker(TaggedFrame(Frame(0, 0.0, np.zeros((10, 10), np.float32)), pose=None))

"""The shipped depth model on held-out simulated frames and on real drone photos of a wall (no torch needed)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from companion.cli import main
from companion.depth.masker import Masker
from companion.records import Frame, TaggedFrame
from evaluation.depth.evaluate import evaluate_recording

FIXTURES = Path(__file__).parent / "depth_fixtures"
MISSION = Path(__file__).parents[1] / "missions" / "demo-facade.yaml"

# Bounds with margin over what the shipped model measured: 2.0 % mean error on the 12 frames below (1.2 % on
# 524 held-out frames, bench/depth_eval.py, docs/BENCHMARKS.md); 89.9 % of both real photos kept (all of the plain
# wall; the window at the right edge, which shows the room behind it and reflects trees and sky, is cut).
MEAN_ERROR_BOUND = 0.05
REAL_WALL_KEPT = 0.85


@pytest.fixture(scope="module")
def masker():
    return Masker(threads=1)


@pytest.fixture(scope="module")
def held_out_recording(tmp_path_factory):
    from sim.camera.recording import generate_recording

    # seed 300 of the demo mission: a scene the model never saw (trained on scene seeds 0-29; 100, 101 and 200 are
    # the benchmark and tuning seeds), frames spread over the whole scan (wall ends, roof line, ground, mid-wall)
    out = tmp_path_factory.mktemp("rec") / "demo_seed300"
    return generate_recording(MISSION, out, seed=300, stride=211, max_frames=12)


def test_shipped_model_on_held_out_simulated_frames(masker, held_out_recording):
    ev = evaluate_recording(held_out_recording, masker)
    s = ev.summary()
    assert s["frames"] >= 8
    assert s["error_mean"] < MEAN_ERROR_BOUND, s
    assert s["dropped_with_facade"] == 0, s  # a frame that shows facade is never lost as "all background"
    # wherever the truth has both facade and background, the model sees the facade nearer
    assert s["true_roi_nearer_fraction"] == 1.0 or np.isnan(s["true_roi_nearer_fraction"])


@pytest.mark.parametrize("name", ["DJI_0977_rgb_640.jpg", "DJI_0981_rgb_640.jpg"])
def test_real_wall_photo_keeps_almost_all_of_the_wall(masker, name):
    image = cv2.imread(str(FIXTURES / name))
    masked, roi = masker.mask(TaggedFrame(Frame(0, 0.0, image), pose=None))
    assert masked is not None and not roi.empty
    assert roi.roi_fraction >= REAL_WALL_KEPT, f"kept only {100 * roi.roi_fraction:.1f} % of a wall photo"
    # the left 80 % of the photo is plain wall (the right edge is a window reflecting trees and sky): all of it is
    # kept (the earlier model cut a featureless, lighter patch near the top as if it were sky)
    w, h = int(0.8 * image.shape[1]), image.shape[0]
    assert np.count_nonzero(masked.mask[:, :w]) >= 0.99 * h * w
    assert masked.mask[h // 2 :, :w].min() == 255


def test_eval_mask_command(held_out_recording, tmp_path, capsys):
    out = tmp_path / "eval.json"
    code = main(["eval", "mask", str(held_out_recording), "--max-frames", "3", "--json", str(out),
                 "--save", str(tmp_path / "pics")])
    assert code == 0
    assert "pixel error ratio mean" in capsys.readouterr().out
    assert out.is_file() and len(list((tmp_path / "pics").glob("*.jpg"))) == 3


def test_eval_mask_command_bad_recording(tmp_path, capsys):
    assert main(["eval", "mask", str(tmp_path / "missing")]) == 2
    assert "recording not found" in capsys.readouterr().err


def test_depth_run_command_writes_pictures(tmp_path, capsys):
    code = main(["depth", "run", str(FIXTURES / "DJI_0981_rgb_640.jpg"), "--out", str(tmp_path)])
    assert code == 0
    assert "ROI" in capsys.readouterr().out
    pic = cv2.imread(str(tmp_path / "DJI_0981_rgb_640.jpg"))
    assert pic is not None and pic.shape[1] == 3 * 640  # frame | disparity | masked frame
    assert main(["depth", "run", str(tmp_path / "nope.jpg"), "--out", str(tmp_path)]) == 2


def test_depth_run_runs_the_network_once_per_image(tmp_path, monkeypatch):
    from companion.depth.session import DepthSession

    calls = []
    original = DepthSession.disparity

    def counted(self, image):
        calls.append(image.shape)
        return original(self, image)

    monkeypatch.setattr(DepthSession, "disparity", counted)
    photo = str(FIXTURES / "DJI_0981_rgb_640.jpg")
    assert main(["depth", "run", photo, photo, "--out", str(tmp_path)]) == 0
    assert len(calls) == 2

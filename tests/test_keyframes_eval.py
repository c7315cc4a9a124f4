"""Gate evaluation: minimum keyframe count from truth, and the report on a small recording-like pass."""

from __future__ import annotations

import numpy as np
import pytest

from companion.cli import main as cli_main
from companion.keyframes import FeatureConfig, GateConfig
from evaluation.keyframes.evaluate import evaluate_gate, format_report, minimum_keyframes, plot_curve
from evaluation.keyframes.synthetic import View, render, textured_wall, true_overlap


def test_minimum_keyframes_on_uniform_steps():
    def overlap(i, j):
        return max(0.0, 1.0 - 0.05 * (j - i))

    assert minimum_keyframes(21, overlap, 0.80) == [0, 4, 8, 12, 16, 20]
    assert minimum_keyframes(1, overlap, 0.80) == [0]


def test_minimum_keyframes_bridges_an_unreachable_frame():
    def overlap(i, j):
        if i <= 5 < j:  # nothing before frame 6 sees frame 6 or later
            return 0.0
        return max(0.0, 1.0 - 0.05 * (j - i))

    path = minimum_keyframes(12, overlap, 0.80)
    assert path[0] == 0 and path[-1] == 11 and 5 in path and 6 in path


class FakeRecording:
    """The duck-typed recording interface over synthetic views (no simulator needed)."""

    def __init__(self, views, tex):
        self.views, self.tex = views, tex
        self.width, self.height = views[0].width, views[0].height

    def __len__(self):
        return len(self.views)

    def image(self, i):
        return render(self.tex, self.views[i])

    def roi_mask(self, i):
        m = np.full((self.height, self.width), 255, np.uint8)
        m[: self.height // 6] = 0  # a strip of "sky" that is not wall
        return m

    def capture_time(self, i):
        return i / 10.0

    def true_overlap(self, i, j):
        return true_overlap(self.views[i], self.views[j])


def test_evaluate_gate_on_known_pass(tmp_path):
    tex = textured_wall(1600, 500, seed=5)
    views = [View(200 + 22.0 * i, 250, 320, 240) for i in range(24)]
    rec = FakeRecording(views, tex)
    cfg = GateConfig(features=FeatureConfig(long_side_px=320, max_features=1200))
    ev = evaluate_gate(rec, cfg, curve_floor=60.0)
    med, p95, n = ev.error_stats()
    assert n >= len(views) - 1 and med < 1.0 and p95 < 2.0
    assert len(ev.keyframes) == len(ev.minimum_keyframes)
    assert min(ev.keyframe_pair_truth) >= 77.0
    assert ev.curve[0][0] == 0 and ev.curve[-1][2] >= 60.0
    report = format_report(ev)
    assert "median" in report and "minimum possible" in report
    png = tmp_path / "fig9.png"
    plot_curve(ev, png)
    assert png.stat().st_size > 1000


def test_eval_gate_command_rejects_missing_recording(tmp_path, capsys):
    assert cli_main(["eval", "gate", str(tmp_path / "nope")]) == 2
    assert "fix:" in capsys.readouterr().err


def test_evaluate_needs_two_frames():
    from companion.errors import CompanionError

    with pytest.raises(CompanionError, match="at least 2"):
        evaluate_gate(FakeRecording([View(200, 250, 320, 240)], textured_wall(600, 500)))

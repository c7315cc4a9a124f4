"""bench/mask_real.py (issue 27 item 5): its table has a row per shipped model and mode, and each row's verdict is the
issue's bars applied to that row's own figures. One small pass, one model: a few seconds."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest

from companion.depth.session import SHIPPED_MODELS

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def bench():
    spec = importlib.util.spec_from_file_location("mask_real", ROOT / "bench" / "mask_real.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules["mask_real"] = module  # its dataclasses look their module up there
    spec.loader.exec_module(module)
    return module


def _row(errors, background, dropped, wall_dropped) -> dict:
    return {"error_mean": dict(enumerate(errors)), "background_frames": background,
            "background_dropped": dropped, "wall_frames_dropped": wall_dropped}


def test_every_shipped_model_is_benched_by_default(bench):
    settings, _ = bench.parse_settings([])
    assert settings.models == tuple(SHIPPED_MODELS)
    assert settings.modes == bench.MODES


@pytest.mark.parametrize(("row", "expected"), [
    (_row([0.05, 0.01], 10, 9, 0), {"error": True, "background": True, "wall": True}),
    (_row([0.0501, 0.01], 10, 9, 0), {"error": False, "background": True, "wall": True}),
    (_row([0.01], 10, 8, 0), {"error": True, "background": False, "wall": True}),
    (_row([0.01], 10, 10, 1), {"error": True, "background": True, "wall": False}),
    (_row([0.01], 0, 0, 0), {"error": True, "background": False, "wall": True}),
])
def test_verdicts_are_the_issues_bars(bench, row, expected):
    """Every pass's mean error <= 5 %, >= 90 % of background-only frames dropped, no frame with wall dropped."""
    assert bench.verdicts(row) == expected
    assert (bench.verdict_text(expected) == "**pass**") == all(expected.values())


def test_table_has_every_mode_and_its_verdict_follows_its_numbers(bench, capsys):
    rows = bench.main(["--passes", "dji-plain-wall", "--models", "sim", "--frames", "8", "--background-frames", "2",
                       "--near-spacing", "1.5", "--far-spacing", "6"])
    printed = capsys.readouterr().out
    settings, _ = bench.parse_settings(["--passes", "dji-plain-wall", "--models", "sim", "--frames", "8",
                                        "--near-spacing", "1.5", "--far-spacing", "6"])
    table_rows = [line for line in printed.splitlines() if line.startswith("| sim |")]
    assert [r["mode"] for r in rows] == list(bench.MODES)
    assert len(table_rows) == len(bench.MODES)
    for row, line in zip(rows, table_rows, strict=True):
        assert bench.mode_label(row["mode"], settings) in line
        assert row["frames"] > 0 and row["background_frames"] == 2
        ok = (all(e <= 0.05 for e in row["error_mean"].values())
              and row["background_dropped"] >= 0.9 * row["background_frames"] and row["wall_frames_dropped"] == 0)
        assert ("**pass**" in line) == ok
        assert ("*" in line.split(" | ")[3]) == any(e > 0.05 for e in row["error_mean"].values())
        assert row["cpu_ms_per_frame"] > 0
    assert "load average" in printed


def test_the_chain_can_be_given_biased_poses_and_its_row_says_so(bench):
    """``--pose-bias`` moves every chain pose (a GNSS bias) and the chain row's label names it; exact by default."""
    exact, _ = bench.parse_settings(["--modes", "chain"])
    biased, _ = bench.parse_settings(["--modes", "chain", "--pose-bias", "1.5,1.5,0.5"])
    assert exact.pose_bias_m == (0.0, 0.0, 0.0) and "exact telemetry" in bench.mode_label("chain", exact)
    assert biased.pose_bias_m == (1.5, 1.5, 0.5)
    assert "biased +1.5 / +1.5 / +0.5 m" in bench.mode_label("chain", biased)
    with pytest.raises(SystemExit):
        bench.parse_settings(["--pose-bias", "1.5,0"])

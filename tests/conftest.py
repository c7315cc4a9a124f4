"""Fixtures more than one test module uses."""

from __future__ import annotations

from pathlib import Path

import pytest

from companion.cli import main

SMALL_WALL = Path(__file__).parent / "data" / "small-wall.yaml"


@pytest.fixture(scope="session")
def small_recording(tmp_path_factory) -> Path:
    """A fast `companion record` of tests/data/small-wall.yaml: 24 frames of 320 px (6 keyframes when culled);
    read-only: a test copies what it damages."""
    rec = tmp_path_factory.mktemp("small_recording") / "rec"
    assert main(["record", str(SMALL_WALL), "--out", str(rec), "--fast", "--width", "320", "--max-frames", "24",
                 "--stride", "8"]) == 0
    return rec

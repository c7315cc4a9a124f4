"""What more than one test module needs: the shared data folder (../shared/data beside the checkout, unless
``$COMPANION_SHARED_DATA`` names another: evaluation/shared_data.py) and one small recording."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from companion.cli import main

os.environ.setdefault("COMPANION_SHARED_DATA", str(Path(__file__).resolve().parents[2] / "shared" / "data"))

SMALL_WALL = Path(__file__).parent / "data" / "small-wall.yaml"


@pytest.fixture(scope="session")
def small_recording(tmp_path_factory) -> Path:
    """A fast `companion record` of tests/data/small-wall.yaml: 24 frames of 320 px (6 keyframes when culled);
    read-only: a test copies what it damages."""
    rec = tmp_path_factory.mktemp("small_recording") / "rec"
    assert main(["record", str(SMALL_WALL), "--out", str(rec), "--fast", "--width", "320", "--max-frames", "24",
                 "--stride", "8"]) == 0
    return rec

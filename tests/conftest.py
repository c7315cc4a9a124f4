"""What more than one test module needs: the shared data folder (../shared/data beside the checkout, unless
``$COMPANION_SHARED_DATA`` names another: evaluation/shared_data.py), one small recording, the hole wall's spool and
maps (tests/hole_wall.py), and a parameter journal (companion/flight/param_journal.py) in a temporary directory,
never in the state directory of the user running the suite: a flight test that ends with its link dead leaves a
journal there, and the next `companion fly` of that user would restore it onto a real vehicle with the same system
id."""

from __future__ import annotations

import atexit
import os
import shutil
import tempfile
from pathlib import Path

import pytest

from companion.cli import main
from companion.flight.param_journal import STATE_DIR_ENV

os.environ.setdefault("COMPANION_SHARED_DATA", str(Path(__file__).resolve().parents[2] / "shared" / "data"))
# Set at import, before any test module builds a subprocess environment from os.environ at its own import.
_SESSION_STATE = tempfile.mkdtemp(prefix="companion-test-state-")
os.environ[STATE_DIR_ENV] = _SESSION_STATE
atexit.register(shutil.rmtree, _SESSION_STATE, True)

SMALL_WALL = Path(__file__).parent / "data" / "small-wall.yaml"


@pytest.fixture(autouse=True)
def _own_state_dir(tmp_path_factory, monkeypatch):
    """Each test its own journal directory (in-process flights and subprocesses started with os.environ)."""
    monkeypatch.setenv(STATE_DIR_ENV, str(tmp_path_factory.mktemp("state")))


@pytest.fixture(scope="session")
def small_recording(tmp_path_factory) -> Path:
    """A fast `companion record` of tests/data/small-wall.yaml: 24 frames of 320 px (6 keyframes when culled);
    read-only: a test copies what it damages."""
    rec = tmp_path_factory.mktemp("small_recording") / "rec"
    assert main(["record", str(SMALL_WALL), "--out", str(rec), "--fast", "--width", "320", "--max-frames", "24",
                 "--stride", "8"]) == 0
    return rec


@pytest.fixture(scope="module")
def site_face(tmp_path_factory):
    """Face 0 of tests/site_spools.py's building (main flight + re-fly spools), built once per test module."""
    from tests.site_spools import make_face

    return make_face(tmp_path_factory.mktemp("spools"), 0)


@pytest.fixture(scope="session")
def hole_wall_spool(tmp_path_factory):
    """(spool folder, truth) of tests/hole_wall.py's wall; read-only: a test copies what it damages."""
    from evaluation.stitch.synthetic import make_spool
    from tests.hole_wall import HOLE, WALL

    d = tmp_path_factory.mktemp("hole_wall_spool")
    return d, make_spool(d, WALL, hole_m=HOLE)


@pytest.fixture(scope="session")
def hole_wall_map(hole_wall_spool, tmp_path_factory):
    """The hole wall's map with the default settings (in memory); read-only: a test that writes into its folder
    takes a copy (tests/hole_wall.py ``map_copy``)."""
    from companion.stitch import load_input, stitch

    return stitch(load_input(hole_wall_spool[0]), tmp_path_factory.mktemp("hole_wall_map"), progress=False)


@pytest.fixture(scope="session")
def hole_wall_tiled(hole_wall_spool, tmp_path_factory):
    """The hole wall's map kept only as 128 px tiles (a 1000 px in-memory limit); read-only, as above."""
    from companion.stitch import StitchConfig, load_input, stitch

    return stitch(load_input(hole_wall_spool[0]), tmp_path_factory.mktemp("hole_wall_tiled"),
                  StitchConfig(tile_px=128, max_in_memory_px=1000), progress=False)


@pytest.fixture(scope="session")
def missing_patch_map(tmp_path_factory):
    """(spool folder, truth, map folder): tests/hole_wall.py's wall flown at 2 m so that no keyframe shows the patch
    ``HOLE`` (small footprints), stitched by `companion stitch` with its defaults; for the stitcher's re-fly areas
    (tests/test_stitch_worker.py) and the re-fly planned from them (tests/test_mission_refly.py). Read-only."""
    from evaluation.stitch.synthetic import make_spool
    from tests.hole_wall import HOLE, WALL

    root = tmp_path_factory.mktemp("missing_patch")
    truth = make_spool(root / "spool", WALL, standoff_m=2.0, missing_m=HOLE)
    assert main(["stitch", str(root / "spool"), "--out", str(root / "map")]) == 0
    return root / "spool", truth, root / "map"

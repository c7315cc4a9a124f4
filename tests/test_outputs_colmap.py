"""COLMAP on a spool of a simulated scan, run as a user runs it (``companion export colmap``: the camera COLMAP reads
from our EXIF, exhaustive matching, incremental mapping): every keyframe registers, at the true focal, where the
telemetry says it was taken.

The spool comes from the simulator's renderer flying the planned scan (``companion record --fast``) culled by
``companion cull``: a level camera translating along a flat wall, the motion under which COLMAP's default focal
refinement drifts (docs/OUTPUTS.md, "COLMAP on a wall"; on the SITL demo spool: 9/29 registered, focal 17x).
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from companion.cli import main
from companion.errors import CompanionError
from companion.export.colmap import REPORT, export_colmap, write_workspace
from companion.spool.layout import MANIFEST

SMALL_WALL = Path(__file__).parent / "data" / "small-wall.yaml"


@pytest.fixture(scope="module")
def spool(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("colmap")
    rec, spool = root / "rec", root / "spool"
    assert main(["record", str(SMALL_WALL), "--out", str(rec), "--fast", "--width", "640",
                 "--max-frames", "50", "--stride", "5"]) == 0
    assert main(["cull", str(rec / "frames"), "--telemetry", str(rec / "telemetry.jsonl"), "--out", str(spool),
                 "--mission", str(SMALL_WALL), "--no-mask"]) == 0
    return spool


def test_colmap_registers_every_keyframe_at_the_exif_focal_where_the_telemetry_says(spool, tmp_path):
    keyframes = len((spool / MANIFEST).read_text().splitlines())
    assert keyframes >= 5
    workspace, result = export_colmap(spool, tmp_path / "colmap")
    assert result.keyframes == keyframes and result.registered == keyframes, result.unregistered
    assert result.models >= 1 and result.cameras == 1
    assert result.exif_prior_focal  # COLMAP's own EXIF reader found the focal: no intrinsics were given to it
    assert result.true_focal_px == pytest.approx(320 / 0.6873, rel=1e-3)  # 640 px, hfov 69 deg
    assert abs(result.focal_error) < 0.01
    # the reconstruction is right, not just complete: camera centres on the telemetry's to a few centimetres
    assert result.centres_within_m == keyframes and not result.misplaced
    assert result.centre_median_m < 0.03
    report = json.loads((workspace.root / REPORT).read_text())
    assert report["registered"] == keyframes
    assert (Path(result.model_dir) / "cameras.bin").exists()  # COLMAP's own model files, for its GUI or CLI


def test_the_workspace_has_colmaps_mask_names_and_leaves_the_spool_alone(spool, tmp_path):
    before = sorted(p.name for p in spool.iterdir())
    workspace = write_workspace(spool, tmp_path / "ws", masks=True)
    assert sorted(p.name for p in workspace.images.iterdir()) == list(workspace.names)
    assert sorted(p.name for p in workspace.masks.iterdir()) == [f"{n}.png" for n in workspace.names]
    assert sorted(p.name for p in spool.iterdir()) == before
    assert main(["export", "colmap", str(spool), "--out", str(tmp_path / "cli"), "--no-run"]) == 0
    assert not (tmp_path / "cli" / "masks").exists() and not (tmp_path / "cli" / REPORT).exists()


def test_a_folder_without_a_spool_or_the_spool_itself_is_refused(spool, tmp_path):
    with pytest.raises(CompanionError, match="no keyframe spool") as exc:
        write_workspace(tmp_path / "empty", tmp_path / "ws")
    assert "spool" in exc.value.fix
    with pytest.raises(CompanionError, match="into the spool itself"):
        write_workspace(spool, spool)
    assert main(["export", "colmap", str(tmp_path / "empty"), "--out", str(tmp_path / "ws")]) == 2

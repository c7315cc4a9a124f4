"""`companion export colmap` with a damaged keyframe names it (the keyframe left out, not an unexplained exit 1);
a failed command takes back what it created in its output folder, and only that (`export colmap`, `cull --out`)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from companion.cli import main
from companion.errors import CompanionError
from companion.export import colmap
from companion.export.colmap import ColmapResult
from companion.files import NewOutput, removed_on_failure
from companion.image_files import TRUNCATED
from companion.records import Frame, Keyframe, Pose
from companion.spool.writer import KeyframeSpool


def _spool(root: Path, n: int = 4, cut: int | None = 2) -> Path:
    """A minimal spool written by the spool writer: ``n`` keyframes; keyframe ``cut``'s JPEG then cut short."""
    rng = np.random.default_rng(5)
    spool = KeyframeSpool(root)
    for i in range(n):
        pose = Pose(float(i), 37.5, 127.0 + i * 1e-6, 30.0, 0.0, 0.0, 0.0, 0.0)
        image = rng.integers(0, 255, (90, 120, 3), dtype=np.uint8)
        spool.append(Keyframe(Frame(i, 1_780_000_000.0 + i, image), pose, np.full((90, 120), 255, np.uint8)))
    if cut is not None:
        data = (root / f"kf_{cut:06d}.jpg").read_bytes()
        (root / f"kf_{cut:06d}.jpg").write_bytes(data[: len(data) // 2])
    return root


def test_export_colmap_leaves_a_damaged_keyframe_out_and_names_it(tmp_path, capsys):
    spool = _spool(tmp_path / "spool")
    assert main(["export", "colmap", str(spool), "--out", str(tmp_path / "ws"), "--no-run"]) == 0
    err = capsys.readouterr().err
    assert f"warning: 1 keyframe(s) left out, their image missing or damaged: kf_000002.jpg: {TRUNCATED}" in err
    assert sorted(p.name for p in (tmp_path / "ws" / "images").iterdir()) == [
        "kf_000000.jpg", "kf_000001.jpg", "kf_000003.jpg"]


def test_export_colmap_of_only_damaged_keyframes_is_an_error_and_writes_nothing(tmp_path, capsys):
    spool = _spool(tmp_path / "spool", n=1, cut=0)
    assert main(["export", "colmap", str(spool), "--out", str(tmp_path / "ws"), "--no-run"]) == 2
    err = capsys.readouterr().err
    assert f"error: none of the 1 keyframe images of {spool} can be read: kf_000000.jpg: {TRUNCATED}" in err
    assert "fix:" in err and not (tmp_path / "ws").exists()


def test_unregistered_keyframes_are_said_with_error_and_fix_lines(tmp_path, capsys, monkeypatch):
    spool = _spool(tmp_path / "spool", cut=None)
    result = ColmapResult(keyframes=4, registered=3, unregistered=("kf_000003.jpg",), models=1, cameras=1,
                          exif_prior_focal=True, focal_px=100.0, true_focal_px=None, focal_error=None,
                          held_intrinsics=True, centre_median_m=None, centres_within_m=0, misplaced=(),
                          model_dir="sparse/0")
    monkeypatch.setattr(colmap, "_pycolmap", lambda: None)
    monkeypatch.setattr(colmap, "reconstruct", lambda workspace, **kw: result)
    assert main(["export", "colmap", str(spool), "--out", str(tmp_path / "ws")]) == 1
    err = capsys.readouterr().err
    assert "error: 1 of 4 keyframes did not register in COLMAP's model: kf_000003.jpg" in err
    assert "\n  fix: check that they overlap their neighbours" in err


def test_a_failed_export_removes_only_what_it_created(tmp_path, monkeypatch):
    spool = _spool(tmp_path / "spool", cut=None)

    def no_model(workspace, **kw):
        raise CompanionError("COLMAP built no model from the 4 keyframes", "check that the keyframes overlap")

    monkeypatch.setattr(colmap, "_pycolmap", lambda: None)
    monkeypatch.setattr(colmap, "reconstruct", no_model)
    assert main(["export", "colmap", str(spool), "--out", str(tmp_path / "new")]) == 2
    assert not (tmp_path / "new").exists()  # made by this run: gone
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("the user's")
    assert main(["export", "colmap", str(spool), "--out", str(mine)]) == 2
    assert sorted(p.name for p in mine.iterdir()) == ["notes.txt"]  # the user's file stays, images/ is gone


def test_removed_on_failure_keeps_the_folder_on_success_and_everything_there_before(tmp_path):
    with removed_on_failure(tmp_path / "out") as out:
        out.mkdir()
        (out / "a").write_text("kept")
    assert (tmp_path / "out" / "a").exists()
    with pytest.raises(KeyboardInterrupt), removed_on_failure(tmp_path / "out") as out:
        (out / "b").mkdir()
        (out / "b" / "c").write_text("half made")
        raise KeyboardInterrupt
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["a"]
    NewOutput(tmp_path / "absent").remove_created()  # nothing there: nothing to do


def test_a_failed_cull_removes_the_spool_folder_it_created(tmp_path, capsys):
    log = tmp_path / "telemetry.jsonl"
    row = {"t_boot_s": 0.0, "lat": 37.56646, "lon": 126.978, "alt_amsl_m": 33.0, "roll_deg": 0.0,
           "pitch_deg": 0.0, "yaw_deg": 0.0}
    log.write_text("".join(json.dumps({**row, "t_boot_s": i / 10}) + "\n" for i in range(5)))
    out = tmp_path / "spool"
    assert main(["cull", str(tmp_path / "missing.mp4"), "--telemetry", str(log), "--out", str(out),
                 "--no-mask", "--no-mission"]) == 2
    assert "missing.mp4" in capsys.readouterr().err
    assert not out.exists()

"""Damaged and malformed inputs through the CLI, as a user's files come (issue 29): each gives one clear error
(`error:` and `fix:` lines, exit 2, nothing left in the output folder) or a named skip (exit 0, the file named),
never a traceback.

One small recording (conftest.py: 320 px, 24 frames) culled once gives the spool (6 keyframes), its first 12
frames the frames to cull, and the telemetry; every case damages its own copy.
"""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import pytest

from companion.cli import main
from companion.spool.layout import MANIFEST, META

SMALL_WALL = Path(__file__).parent / "data" / "small-wall.yaml"


@dataclass(frozen=True)
class Inputs:
    """The good inputs every case starts from (copied before it damages anything)."""

    frames: Path  # frames/ with times.csv, outside its recording (so only --mission names the wall)
    telemetry: Path
    spool: Path


@pytest.fixture(scope="module")
def good(tmp_path_factory, small_recording) -> Inputs:
    root = tmp_path_factory.mktemp("damaged")
    rec = small_recording
    assert main(["cull", str(rec / "frames"), "--telemetry", str(rec / "telemetry.jsonl"), "--out",
                 str(root / "spool"), "--mission", str(SMALL_WALL), "--no-mask"]) == 0
    frames = root / "frames"  # the first 12 frames are enough to cull (and cheaper)
    frames.mkdir()
    times = (rec / "frames" / "times.csv").read_text().splitlines()[:12]
    (frames / "times.csv").write_text("\n".join(times) + "\n")
    for line in times:
        shutil.copy(rec / "frames" / line.split(",")[0], frames)
    return Inputs(frames, rec / "telemetry.jsonl", root / "spool")


@dataclass(frozen=True)
class Case:
    """``make(tmp, good)`` damages copies in ``tmp`` and returns the command line (its output folder tmp/out);
    ``says``: text the output must hold (the damaged file, or what is wrong); ``skip``: the command goes on."""

    make: Callable[[Path, Inputs], list[str]]
    says: str
    skip: bool = False


def _frames(tmp: Path, good: Inputs, damage: Callable[[Path], None] = lambda d: None) -> Path:
    frames = tmp / "frames"
    shutil.copytree(good.frames, frames)
    damage(frames)
    return frames


def _cull(tmp: Path, good: Inputs, *, frames: Path | None = None, telemetry: Path | None = None,
          mission: Path = SMALL_WALL) -> list[str]:
    return ["cull", str(frames or _frames(tmp, good)), "--telemetry", str(telemetry or good.telemetry),
            "--out", str(tmp / "out"), "--mission", str(mission), "--no-mask"]


def _cut(path: Path) -> None:
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])


def _empty(path: Path) -> None:
    path.write_bytes(b"")


def _telemetry(tmp: Path, good: Inputs, edit: Callable[[list[str]], list[str] | str]) -> Path:
    lines = good.telemetry.read_text().splitlines()
    edited = edit(lines)
    path = tmp / "telemetry.jsonl"
    path.write_text(edited if isinstance(edited, str) else "\n".join(edited) + "\n")
    return path


def _mission(tmp: Path, old: str, new: str) -> Path:
    text = SMALL_WALL.read_text()
    assert old in text
    path = tmp / "mission.yaml"
    path.write_text(text.replace(old, new))
    return path


def _spool(tmp: Path, good: Inputs, damage: Callable[[Path, list[dict]], None] = lambda d, kfs: None) -> Path:
    spool = tmp / "spool"
    shutil.copytree(good.spool, spool)
    damage(spool, [json.loads(x) for x in (spool / MANIFEST).read_text().splitlines()])
    return spool


def _stitch(tmp: Path, good: Inputs, damage: Callable[[Path, list[dict]], None]) -> list[str]:
    return ["stitch", str(_spool(tmp, good, damage)), "--out", str(tmp / "out"), "--quiet"]


def _lat_as_text(lines: list[str]) -> list[str]:
    row = json.loads(lines[0])
    return [json.dumps({**row, "lat": "north"}), *lines[1:]]


def _bad_manifest_line(spool: Path, kfs: list[dict]) -> None:
    lines = (spool / MANIFEST).read_text().splitlines()
    lines[2] = lines[2][:15] + "\x00\x00" + lines[2][17:]  # a bad sector mid-file, not a torn last line
    (spool / MANIFEST).write_text("\n".join(lines) + "\n")


def _wrong_size_mask(spool: Path, kfs: list[dict]) -> None:
    cv2.imwrite(str(spool / kfs[3]["mask"]), np.full((45, 80), 255, np.uint8))


CASES = {
    # culling a recorded flight: frames, telemetry, mission
    "cull: a JPEG cut short": Case(lambda t, g: _cull(t, g, frames=_frames(t, g, lambda d: _cut(d / "000005.jpg"))),
                                   "000005.jpg", skip=True),
    "cull: a zero-byte JPEG": Case(lambda t, g: _cull(t, g, frames=_frames(t, g, lambda d: _empty(d / "000010.jpg"))),
                                   "000010.jpg", skip=True),
    "cull: every JPEG zero bytes": Case(
        lambda t, g: _cull(t, g, frames=_frames(t, g, lambda d: [_empty(p) for p in d.glob("*.jpg")])),
        "kept no keyframe"),
    "cull: a folder without images": Case(lambda t, g: _cull(t, g, frames=(t / "none").resolve()), "none"),
    "cull: an empty image folder": Case(
        lambda t, g: _cull(t, g, frames=_frames(t, g, lambda d: [p.unlink() for p in d.iterdir()])), "frames"),
    "cull: a video that is not there": Case(lambda t, g: _cull(t, g, frames=t / "flight.mp4"), "flight.mp4"),
    "cull: telemetry pretty-printed JSON": Case(
        lambda t, g: _cull(t, g, telemetry=_telemetry(t, g, lambda ls: json.dumps([json.loads(x) for x in ls],
                                                                                   indent=2))), "telemetry.jsonl"),
    "cull: a telemetry line of garbage": Case(
        lambda t, g: _cull(t, g, telemetry=_telemetry(t, g, lambda ls: [*ls[:5], "#!garbage", *ls[5:]])), "line 6"),
    "cull: a telemetry value of the wrong type": Case(
        lambda t, g: _cull(t, g, telemetry=_telemetry(t, g, _lat_as_text)), "line 1: lat is 'north'"),
    "cull: zero-byte telemetry": Case(lambda t, g: _cull(t, g, telemetry=_telemetry(t, g, lambda ls: "")), "empty"),
    "cull: telemetry that is not there": Case(lambda t, g: _cull(t, g, telemetry=t / "flight.jsonl"), "flight.jsonl"),
    "cull: a mission with a word for a number": Case(
        lambda t, g: _cull(t, g, mission=_mission(t, "standoff_m: 4.0", "standoff_m: far")),
        "fix: write 'standoff_m' as a number"),
    # planning from a mission file
    "plan: a mission with a list for a number": Case(
        lambda t, g: ["plan", str(_mission(t, "standoff_m: 4.0", "standoff_m: [4, 5]")), "--out", str(t / "out")],
        "fix: write 'standoff_m' as a number"),
    "plan: a mission that is not YAML": Case(
        lambda t, g: ["plan", str(_mission(t, "standoff_m: 4.0", "standoff_m: {4.0")), "--out", str(t / "out")],
        "not valid YAML"),
    # stitching a spool
    "stitch: a missing manifest": Case(
        lambda t, g: _stitch(t, g, lambda d, kfs: (d / MANIFEST).unlink()), MANIFEST),
    "stitch: a keyframe cut short": Case(
        lambda t, g: _stitch(t, g, lambda d, kfs: _cut(d / kfs[2]["image"])), "skipped", skip=True),
    "stitch: a zero-byte keyframe": Case(
        lambda t, g: _stitch(t, g, lambda d, kfs: _empty(d / kfs[4]["image"])), "an empty file (0 bytes", skip=True),
    "stitch: a mask of the wrong size": Case(lambda t, g: _stitch(t, g, _wrong_size_mask), "mask", skip=True),
    "stitch: a manifest line of garbage": Case(lambda t, g: _stitch(t, g, _bad_manifest_line), "manifest.jsonl:3",
                                              skip=True),
    "stitch: spool.json cut short": Case(
        lambda t, g: _stitch(t, g, lambda d, kfs: _cut(d / META)), META),
    "stitch: every keyframe zero bytes": Case(
        lambda t, g: _stitch(t, g, lambda d, kfs: [_empty(d / k["image"]) for k in kfs]), "keyframe"),
    # the other commands that read a spool or a map
    "export colmap: a spool without manifest": Case(
        lambda t, g: ["export", "colmap", str(_spool(t, g, lambda d, kfs: (d / MANIFEST).unlink())), "--out",
                      str(t / "out"), "--no-run"], MANIFEST),
    "mask: a zero-byte photo": Case(lambda t, g: ["mask", str(_zero_byte_photo(t)), "--out", str(t / "out")],
                                    "empty.jpg: an empty file (0 bytes"),
    "plan --refly: a report that is not JSON": Case(
        lambda t, g: ["plan", str(SMALL_WALL), "--refly", str(_report(t)), "--out", str(t / "out")], "report.json"),
}


def _zero_byte_photo(tmp: Path) -> Path:
    folder = tmp / "photos"
    folder.mkdir()
    _empty(folder / "empty.jpg")
    return folder


def _report(tmp: Path) -> Path:
    folder = tmp / "map"
    folder.mkdir()
    (folder / "report.json").write_text('{"coverage_fraction": 0.9, "uncov')
    return folder


@pytest.mark.parametrize("name", list(CASES))
def test_a_damaged_input_gives_one_clear_error_or_a_named_skip(name, good, tmp_path, capsys):
    case = CASES[name]
    argv = case.make(tmp_path, good)
    code = main(argv)
    out, err = capsys.readouterr()
    said = out + err
    assert "Traceback" not in said
    assert case.says in said, said
    if case.skip:
        assert code == 0, said
        return
    assert code == 2, said
    assert err.count("error: ") == 1 and "\n  fix: " in err, err
    assert not (tmp_path / "out").exists(), sorted(p.name for p in (tmp_path / "out").iterdir())

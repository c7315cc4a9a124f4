"""docs/ARCHITECTURE.md's path of one frame from camera to map names real code: every `file.py:Name` hop exists.

A reader follows a frame hop by hop; a renamed function or a moved module must fail here, not mislead them."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _frame_path_section() -> str:
    text = (ROOT / "docs" / "ARCHITECTURE.md").read_text()
    start = text.index("## One frame, from camera to map")
    return text[start:text.index("\n## ", start + 1)]


def test_every_hop_of_the_frame_path_names_existing_code():
    hops = re.findall(r"([a-z_/]+\.py):([A-Za-z_][A-Za-z_.]*)", _frame_path_section())
    assert len(hops) >= 20, hops  # the picture covers capture, tagging, mask, gate, spool, stitch stages
    missing = []
    for file, name in hops:
        path = ROOT / file if file.startswith("sim/") else ROOT / "companion" / file
        if not path.exists():
            missing.append(f"{file} (no such file)")
            continue
        source = path.read_text()
        for part in filter(None, name.split(".")):
            if not re.search(rf"\b(def|class) {re.escape(part)}\b", source):
                missing.append(f"{file}:{part}")
    assert not missing, missing


def test_every_stitcher_stage_in_the_picture_is_a_method_of_the_stitcher():
    import inspect

    from companion.stitch.worker import Stitcher

    stages = re.findall(r"^\s+\.(\w+)\s+->", _frame_path_section(), flags=re.M)
    # the stages Stitcher.stitch runs, in its order: the picture lists the same ones in the same order
    run = re.findall(r"self\.([a-z]\w*)\(", inspect.getsource(Stitcher.stitch))  # _helpers are not stages
    assert run[:2] == ["features", "priors"] and run[-1] == "report", run
    assert stages == run, (stages, run)
    assert all(callable(getattr(Stitcher, s)) for s in stages)

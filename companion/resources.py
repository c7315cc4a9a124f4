"""Data shipped inside the package (depth models, example missions), found through ``importlib.resources`` so an
installed wheel finds them exactly as a source checkout does (never through the checkout's directory layout)."""

from __future__ import annotations

import argparse
from importlib.resources import files
from pathlib import Path

from companion.errors import CompanionError

# Depth models selectable by name (mission ``depth_model``, ``--model``). "sim": trained on our simulator only
# (BSD-3-Clause). "real-nc": fine-tuned on real facade photos whose licences are research / non-commercial, so the
# model is too (README.md, docs/DEPTH.md).
SHIPPED_MODEL_FILES = {
    "sim": "monodepth2-sim-r18w025.onnx",
    "real-nc": "monodepth2-real-nc-r18w025.onnx",
}
DEFAULT_MODEL_NAME = "sim"
# The mission `companion demo` flies; `missions/` at the checkout's root is a link to the same folder.
DEMO_MISSION_NAME = "demo-facade"


def packaged_path(*parts: str) -> Path:
    """The file system path of ``companion/<parts...>`` wherever the package is installed.

    A wheel installs unzipped, so the resource is a real file; mission files must be (their relative references,
    e.g. ``camera.calibration``, resolve against the file's folder)."""
    resource = files("companion").joinpath(*parts)
    path = Path(str(resource))
    if not path.exists():
        raise CompanionError(
            f"the package's data file companion/{'/'.join(parts)} is missing (looked for {path})",
            "reinstall companion (pip install --force-reinstall companion, or pip install -e . in a checkout)",
        )
    return path


def shipped_model(name: str) -> Path:
    return packaged_path("models", SHIPPED_MODEL_FILES[name])


def shipped_missions() -> dict[str, Path]:
    """The example missions in the package, by name (file stem)."""
    folder = packaged_path("missions")
    return {p.stem: p for p in sorted(folder.glob("*.yaml"))}


def demo_mission() -> Path:
    return packaged_path("missions", f"{DEMO_MISSION_NAME}.yaml")


def mission_argument(text: str) -> Path:
    """A command's mission: a YAML file, or the name of a mission shipped in the package (``demo-facade``), so an
    installed companion can plan its example missions without a checkout."""
    path = Path(text)
    if path.exists() or path.suffix:
        return path
    shipped = shipped_missions()
    if text in shipped:
        return shipped[text]
    error = CompanionError(f"mission {text!r} is neither a file nor a shipped mission",
                           f"give a mission YAML path or one of the shipped missions: {', '.join(shipped)}")
    raise argparse.ArgumentTypeError(str(error))  # argparse prints it with the usage and exits 2

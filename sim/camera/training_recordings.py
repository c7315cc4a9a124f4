"""Simulator recordings for ``companion depth train`` and evaluation: generated once per seed, reused on resume."""

from __future__ import annotations

import logging
from pathlib import Path

from companion.errors import CompanionError
from companion.mission import load_mission
from sim.camera.recording import generate_recording

log = logging.getLogger(__name__)


def ensure_recordings(
    mission_path: str | Path, seeds: list[int], data_dir: Path, *, width_px: int = 640, stride: int = 1
) -> list[Path]:
    """Paths of ``data_dir/seed_NNNN`` recordings of ``mission_path``, generating the missing ones."""
    if not Path(mission_path).is_file():
        raise CompanionError(f"mission file not found: {mission_path}", "pass --mission missions/demo-facade.yaml")
    mission = load_mission(mission_path)
    paths = []
    for seed in seeds:
        out = Path(data_dir) / f"seed_{seed:04d}_w{width_px}_s{stride}"
        if not (out / "meta.json").is_file():
            log.info("generating recording seed %d -> %s", seed, out)
            generate_recording(mission, out, seed=seed, width_px=width_px, stride=stride)
        paths.append(out)
    return paths

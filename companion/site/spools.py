"""Which spools are which wall: a site's spools grouped into faces before anything is stitched.

Why group by the wall in spool.json rather than by name or folder: the main flight and a re-fly of one face are
different missions (``companion plan --refly`` names its own) in different folders, but both copy the face's wall
ends from the mission, so the wall is what they share. A spool the stitcher cannot read (no manifest, a broken
spool.json) is set aside here, named with its problem and fix, so the faces of every other spool still go ahead.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass
from pathlib import Path

from companion.errors import CompanionError
from companion.spool.layout import MANIFEST, META
from companion.spool.reader import FacadeGeometry, read_spool_meta
from companion.stitch.merge import same_wall


@dataclass(frozen=True)
class BadSpool:
    """A spool left out of the site: which, what is wrong and what to do."""

    path: Path
    problem: str
    fix: str

    def as_dict(self) -> dict:
        return {"spool": str(self.path), "problem": self.problem, "fix": self.fix}


@dataclass(frozen=True)
class FacadeJob:
    """One face of the site: its name (the output folder's), and its spools, main flight first."""

    name: str
    spools: tuple[Path, ...]


@dataclass(frozen=True)
class SitePlan:
    facades: tuple[FacadeJob, ...]
    bad_spools: tuple[BadSpool, ...]


@dataclass(frozen=True)
class _Spool:
    path: Path
    facade: FacadeGeometry | None
    mission: str | None


def _read(path: Path) -> _Spool | BadSpool:
    if not path.is_dir():
        return BadSpool(path, "is not a directory", "give the keyframe spool directories (each has manifest.jsonl)")
    if not (path / MANIFEST).is_file():
        return BadSpool(path, f"has no {MANIFEST}: not a keyframe spool",
                        "point at the spool folder `companion fly --capture`/`cull` wrote, or leave it out")
    try:
        _, facade, _ = read_spool_meta(path)
        meta = json.loads((path / META).read_text()) if (path / META).is_file() else {}
    except CompanionError as exc:
        return BadSpool(path, exc.problem, exc.fix or "fix or remove the spool")
    except (OSError, ValueError) as exc:
        return BadSpool(path, f"{META} cannot be read ({exc})", f"rewrite {META} from the mission, or leave it out")
    return _Spool(path, facade, meta.get("mission") if isinstance(meta, dict) else None)


def _slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "-", text).strip("-.") or "facade"


def _names(groups: list[list[_Spool]]) -> list[str]:
    """Each face's folder name: its first spool's mission (a re-fly's ``-refly`` suffix dropped), else the first
    spool's folder name; made unique with ``-2``, ``-3``... in the order given."""
    names, seen = [], set()
    for group in groups:
        first = group[0]
        base = _slug(re.sub(r"-refly$", "", first.mission) if first.mission else first.path.name)
        name, k = base, 2
        while name in seen:
            name, k = f"{base}-{k}", k + 1
        seen.add(name)
        names.append(name)
    return names


def plan_site(paths: list[str | Path]) -> SitePlan:
    """The site's faces (spools of one wall together, in the order given: list a face's main flight before its
    re-flies) and the spools left out. A spool without a wall in spool.json is a face of its own."""
    groups: list[list[_Spool]] = []
    bad: list[BadSpool] = []
    seen: set[Path] = set()
    for raw in paths:
        path = Path(raw)
        if path.resolve() in seen:
            continue
        seen.add(path.resolve())
        spool = _read(path)
        if isinstance(spool, BadSpool):
            bad.append(spool)
            continue
        home = next((g for g in groups if same_wall(g[0].facade, spool.facade)), None)
        if home is None:
            groups.append([spool])
        else:
            home.append(spool)
    facades = tuple(
        FacadeJob(name, tuple(s.path for s in group)) for name, group in zip(_names(groups), groups, strict=True)
    )
    return SitePlan(facades, tuple(bad))

"""Small synthetic sites for the site tests and bench/site_scale.py: the faces of one building, each a main flight
with a hole and a re-fly that flies only the hole (``evaluation.stitch.synthetic.make_spool`` moved onto each face).

make_spool flies one wall at a fixed place; a face here is that spool moved onto another wall: spool.json gets the
face's ends and every pose is carried from the fixed wall's frame into the face's (same along/out/up, the yaw
turned by the walls' difference), so the images stay exact views of the face.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import pymap3d

from companion.geo import FacadeFrame, GeoPoint
from companion.spool.layout import MANIFEST, META
from evaluation.stitch.synthetic import SyntheticWall, make_spool

CORNER = GeoPoint(37.56650, 126.97800, 30.0)  # the building's south-west corner, ground level


@dataclass(frozen=True)
class SiteShape:
    length_m: float = 3.0
    height_m: float = 1.6
    width: int = 320
    height: int = 240
    standoff_m: float = 1.2  # 12 keyframes a face, 4 of them (the upper right) only in the re-fly
    hole_m: tuple[float, float, float, float] = (2.3, 2.5, 1.3, 1.5)  # the main flight misses this


def _face_frame(k: int, shape: SiteShape) -> FacadeFrame:
    """Face ``k`` of a square building walked clockwise from its corner (each face flown from outside)."""
    start_e = start_n = 0.0
    bearing = 90.0
    for _ in range(k):  # east along the south face, then north, west, south
        start_e += shape.length_m * math.sin(math.radians(bearing))
        start_n += shape.length_m * math.cos(math.radians(bearing))
        bearing -= 90.0
    end_e = start_e + shape.length_m * math.sin(math.radians(bearing))
    end_n = start_n + shape.length_m * math.cos(math.radians(bearing))
    geo = [pymap3d.enu2geodetic(e, n, 0.0, CORNER.lat, CORNER.lon, CORNER.alt_amsl_m)
           for e, n in ((start_e, start_n), (end_e, end_n))]
    return FacadeFrame.from_wall(*(GeoPoint(float(la), float(lo), CORNER.alt_amsl_m) for la, lo, _ in geo))


def _move(spool: Path, old: FacadeFrame, new: FacadeFrame, mission: str, keep) -> None:
    meta = json.loads((spool / META).read_text())
    end = new.facade_to_geodetic(new.length_m, 0.0, 0.0)
    meta["facade"]["start"] = {"lat": new.origin.lat, "lon": new.origin.lon}
    meta["facade"]["end"] = {"lat": float(end[0]), "lon": float(end[1])}
    meta["mission"] = mission
    (spool / META).write_text(json.dumps(meta, indent=1))
    lines = []
    for k, line in enumerate((spool / MANIFEST).read_text().splitlines()):
        if not keep(k):
            continue
        rec = json.loads(line)
        p = rec["pose"]
        a, o, u = old.geodetic_to_facade(p["lat"], p["lon"], p["alt_amsl_m"])
        lat, lon, alt = new.facade_to_geodetic(a, o, u)
        turn = new.yaw_facing_wall_deg - old.yaw_facing_wall_deg
        rec["pose"] = {**p, "lat": float(lat), "lon": float(lon), "alt_amsl_m": float(alt),
                       "yaw_deg": (p["yaw_deg"] + turn) % 360.0}
        lines.append(json.dumps(rec))
    (spool / MANIFEST).write_text("\n".join(lines) + "\n")


def _reaches(view: dict, rect, fw: float, fh: float) -> bool:
    a0, a1, u0, u1 = rect
    return view["along_m"] - fw / 2 < a1 and view["along_m"] + fw / 2 > a0 and \
        view["up_m"] - fh / 2 < u1 and view["up_m"] + fh / 2 > u0


def make_face(root: Path, k: int, shape: SiteShape = SiteShape()) -> tuple[Path, Path]:
    """Face ``k``'s main flight (missing ``shape.hole_m``) and its re-fly (only the keyframes that see the hole),
    as two spools under ``root``."""
    wall = SyntheticWall(length_m=shape.length_m, height_m=shape.height_m, seed=10 + k)
    frame = _face_frame(k, shape)
    common = dict(width=shape.width, height=shape.height, standoff_m=shape.standoff_m, overlap=0.6,
                  pose_noise_m=0.05, yaw_noise_deg=0.3)
    main, refly = root / f"face{k}-main", root / f"face{k}-refly"
    truth = make_spool(main, wall, missing_m=shape.hole_m, seed=k, **common)
    _move(main, truth["frame"], frame, f"face{k}", lambda _: True)
    again = make_spool(refly, wall, seed=100 + k, **common)
    cam = again["camera"]
    fw, fh = shape.standoff_m * shape.width / cam.focal_px, shape.standoff_m * shape.height / cam.focal_px
    views = again["views"]
    _move(refly, again["frame"], frame, f"face{k}-refly", lambda i: _reaches(views[i], shape.hole_m, fw, fh))
    return main, refly


def make_site(root: Path, faces: int = 4, shape: SiteShape = SiteShape()) -> list[Path]:
    """Every face's spools, main flights first then re-flies (the order `companion site` is given them)."""
    pairs = [make_face(root, k, shape) for k in range(faces)]
    return [m for m, _ in pairs] + [r for _, r in pairs]

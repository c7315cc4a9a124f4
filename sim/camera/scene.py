"""The world around the target facade, in facade coordinates (along_m, out_m, up_m; see companion.geo).

The target building is a box behind the wall: along 0..L, out -depth..0, up 0..H. Its front face (out = 0) is
the target facade (the ROI); its side walls and roof are edges a drone sees near the wall's ends and top. The
background sits at realistic distances: ground plane, trees (8-60 m), far buildings (30-300 m), sky at infinity.
Nothing is placed in front of the wall, where the drone flies.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from sim.camera.textures import FacadeStyle, FacadeTexture


@dataclass(frozen=True)
class Box:
    """Axis-aligned box in facade coordinates; ``kind`` is 'building' or 'trunk'."""

    lo: tuple[float, float, float]
    hi: tuple[float, float, float]
    bgr: tuple[float, float, float]
    kind: str = "building"


@dataclass(frozen=True)
class Tree:
    """A tree crown (ellipsoid with radii r, r, r * squash) on a trunk (a thin box)."""

    centre: tuple[float, float, float]
    radius: float
    squash: float
    bgr: tuple[float, float, float]


@dataclass
class Scene:
    length_m: float
    height_m: float
    depth_m: float
    seed: int
    style: FacadeStyle
    boxes: list[Box] = field(default_factory=list)
    trees: list[Tree] = field(default_factory=list)
    sun_dir: np.ndarray = field(default_factory=lambda: np.array([0.3, 0.6, 0.74]))  # (along, out, up), unit
    light: float = 1.0
    sky_zenith: tuple[float, float, float] = (0.78, 0.52, 0.32)
    sky_horizon: tuple[float, float, float] = (0.92, 0.84, 0.78)
    cloud_cover: float = 0.4
    texture: FacadeTexture = field(init=False)
    side_texture: FacadeTexture = field(init=False)

    def __post_init__(self):
        self.texture = FacadeTexture(self.style)
        side_style = replace(self.style, length_m=self.depth_m, cracks=[], seed=self.style.seed + 1000)
        margin = 1.0
        usable = max(self.depth_m - 2 * margin, 0.5)
        n_bays = max(1, int(round(usable / 3.0)))
        side_style.grid = replace(self.style.grid, n_bays=n_bays, bay_w=usable / n_bays,
                                  win_w=min(self.style.grid.win_w, 0.7 * usable / n_bays))
        self.side_texture = FacadeTexture(side_style)

    @classmethod
    def build(cls, length_m: float, height_m: float, seed: int = 0, n_cracks: int | None = None) -> Scene:
        """A seeded scene around a wall of the given size (what the mission defines)."""
        rng = np.random.default_rng([seed, 7])
        style = FacadeStyle.from_seed(seed, length_m, height_m, n_cracks=n_cracks)
        depth = float(rng.uniform(10.0, 20.0))
        L, H = length_m, height_m
        boxes: list[Box] = []
        tries = 0
        while len([b for b in boxes if b.kind == "building"]) < 28 and tries < 500:
            tries += 1
            dist = float(rng.uniform(30.0, 300.0))
            ang = float(rng.uniform(-math.pi, math.pi))
            ca, co = L / 2 + dist * math.cos(ang), dist * math.sin(ang)
            w, d = float(rng.uniform(10, 40)), float(rng.uniform(10, 40))
            lo = (ca - w / 2, co - d / 2)
            hi = (ca + w / 2, co + d / 2)
            in_front = hi[1] > -2.0 and lo[0] < L + 25 and hi[0] > -25
            if in_front or (hi[1] > 0 and dist < 60):
                continue
            h = float(rng.uniform(8, 60))
            g = float(rng.uniform(0.35, 0.8))
            tint = rng.uniform(0.85, 1.1, 3) * g
            boxes.append(Box((lo[0], lo[1], 0.0), (hi[0], hi[1], h), tuple(float(v) for v in tint)))
        trees: list[Tree] = []
        tries = 0
        while len(trees) < 16 and tries < 500:
            tries += 1
            a = float(rng.uniform(-60, L + 60))
            o = float(rng.uniform(-70, 6))
            r = float(rng.uniform(1.8, 4.0))
            behind = o + r < -depth - 1 or (o + r < -1 and (a < -r - 2 or a > L + r + 2))
            side_far = (a < -12 - r or a > L + 12 + r) and o < 6
            near_building = (-r - 1 < a < L + r + 1) and (o + r > -depth - 1)
            if not (behind or side_far) or near_building:
                continue
            dist = math.hypot(a - L / 2, o)
            if dist < 8 or dist > 70:
                continue
            trunk_h = float(rng.uniform(1.5, 4.0))
            green = tuple(float(v) for v in rng.uniform([0.08, 0.25, 0.1], [0.18, 0.45, 0.25]))
            trees.append(Tree((a, o, trunk_h + r * 0.8), r, float(rng.uniform(0.9, 1.4)), green))
            boxes.append(Box((a - 0.15, o - 0.15, 0.0), (a + 0.15, o + 0.15, trunk_h + r * 0.5),
                             (0.12, 0.17, 0.22), kind="trunk"))
        az = float(rng.uniform(-1.2, 1.2))
        el = float(rng.uniform(0.4, 1.0))
        sun = np.array([math.sin(az) * math.cos(el), math.cos(az) * math.cos(el), math.sin(el)])
        return cls(
            length_m=L,
            height_m=H,
            depth_m=depth,
            seed=seed,
            style=style,
            boxes=boxes,
            trees=trees,
            sun_dir=sun,
            light=float(rng.uniform(0.85, 1.15)),
            sky_zenith=tuple(float(v) for v in rng.uniform([0.7, 0.45, 0.25], [0.85, 0.6, 0.4])),
            cloud_cover=float(rng.uniform(0.2, 0.7)),
        )

    def truth_json(self) -> dict:
        """What the recording's meta.json says about the scene (cracks, windows, building, background)."""
        return {
            "seed": self.seed,
            "wall_length_m": self.length_m,
            "wall_height_m": self.height_m,
            "building_depth_m": self.depth_m,
            "facade": self.style.to_json(),
            "far_buildings": [{"lo": list(b.lo), "hi": list(b.hi)} for b in self.boxes if b.kind == "building"],
            "trees": [{"centre": list(t.centre), "radius": t.radius} for t in self.trees],
        }

"""Where the map sits on the wall: the wall's own ends and roof line, where the keyframes see them.

Why: the images hold the map together and measure its scale (``wall_distance.py``), but where the whole map sits
along the wall and up it comes from GNSS absolute position, which a non-RTK receiver has wrong by a metre or two
for minutes (issue 26): the map of a wall is then drawn a metre along from where the wall is, and the re-fly
areas with it. The wall's ends and its roof line are in the mission (the facade's start and end, its height) and,
at the strips' ends and tops, in the keyframes: the ROI mask stops where the wall stops and the background
begins. Where the masks agree on such an edge, its place on the map against the mission's says how far the map is
off, to a few centimetres.

How: on every placed keyframe's mask (the wall check's, so background the depth mask kept past the wall's end is
already cut) each row's first and last wall pixel, and each column's first, are the mask's edges; those inside
the frame (not the frame's own border) are carried onto the plane by the keyframe's aligned homography. An end of
the wall is where many such edge points of several keyframes fall on one line across it, within the GNSS error of
the mission's end; its offset from the mission's is the map's offset along (the two ends together also measure
the wall's length: a check of the scale); the roof line likewise up. Without such an edge the placement is
GNSS's, and its uncertainty says so (``gnss_sigma_m``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import cv2
import numpy as np

from companion.stitch.align import AlignedKeyframes
from companion.stitch.features import load_mask
from companion.stitch.geometry import apply_h
from companion.stitch.inputs import StitchInput

WORK_WIDTH_PX = 320  # masks are searched for edges at this width (an edge to 1/320 of a footprint: ~2 cm at 4 m)
BORDER_PX = 3  # an edge this near the frame's own border is the frame's, not the wall's (work pixels)
BIN_M = 0.02  # edge points are voted on this grid across the edge
WINDOW_M = 0.06  # the edge is the median of the points this near the vote's peak
MIN_KEYFRAMES = 2  # an edge seen by fewer keyframes is not trusted
MIN_SPAN_FRACTION = 0.2  # nor one covering less of the wall's height (ends) or length (roof line)
MIN_SHARE = 0.35  # nor one holding less of the candidate points near the mission's edge (a clutter of edges)


@dataclass(frozen=True)
class WallEdge:
    """One of the wall's own edges found in the keyframes: where the aligned map puts it (``found_m``), where the
    mission says it is (``expected_m``), how well the edge is located, and its support."""

    name: str  # "start", "end" (along the wall) or "roof" (up)
    expected_m: float
    found_m: float
    sigma_m: float
    keyframes: int
    points: int

    @property
    def offset_m(self) -> float:
        """How far the aligned map has the edge from where the wall has it (map minus wall)."""
        return self.found_m - self.expected_m

    def summary(self) -> dict:
        return {"edge": self.name, "expected_m": round(self.expected_m, 3), "found_m": round(self.found_m, 3),
                "offset_m": round(self.offset_m, 3), "sigma_m": round(self.sigma_m, 3), "keyframes": self.keyframes,
                "points": self.points}


@dataclass(frozen=True)
class WallPlacement:
    """What was done to the aligned map to put it on the wall's own edges, and how well the map's place and
    scale are known afterwards: an anchored axis to its edges' sigma (plus the scale's, away from them), an
    unanchored one to GNSS's absolute sigma."""

    shift_m: tuple[float, float]  # (along, up) added to every keyframe's plane position (after the scaling)
    scale_factor: float  # the map scaled by this about the wall's base start (1: not scaled)
    sigma_m: tuple[float, float]  # (along, up) standard uncertainty of the map's place at its centre
    scale_sigma: float | None  # relative standard uncertainty of the map's scale afterwards (None: unknown)
    edges: tuple[WallEdge, ...]  # as found on the aligned map, before the scaling and shift
    length_m: float | None  # the wall's length between the two ends found, when both were
    expected_length_m: float
    warnings: tuple[str, ...] = ()

    @property
    def anchored_by(self) -> tuple[str, ...]:
        return tuple(e.name for e in self.edges)

    def summary(self) -> dict:
        return {
            "shift_m": [round(v, 3) for v in self.shift_m],
            "scale_factor": round(self.scale_factor, 5),
            "sigma_along_m": round(self.sigma_m[0], 3),
            "sigma_up_m": round(self.sigma_m[1], 3),
            "scale_sigma_percent": None if self.scale_sigma is None else round(100 * self.scale_sigma, 2),
            "anchored_by": list(self.anchored_by),
            "edges": [e.summary() for e in self.edges],
            "wall_length_m": None if self.length_m is None else round(self.length_m, 3),
            "expected_length_m": round(self.expected_length_m, 3),
            "warnings": list(self.warnings),
            "meaning": "the map moved (and, with both ends in view, scaled) onto the wall's own ends and roof line "
            "as the keyframes' masks show them; without an edge on an axis its place is GNSS's (sigma: gnss_sigma_m)",
        }


UNKNOWN_SCALE_SIGMA = 0.05  # a map whose scale nothing measured: the telemetry's distance, a few percent
# how well a mission knows where its wall ends and where its roof line is (from a map or a plan, not a survey):
# an edge the masks show to a centimetre still places the map only as well as the mission says where it is
MISSION_SIGMA_M = 0.1
# and how far a depth mask's edge may lie from the wall's true end: the network and the parallax cut a little wall
# or keep a little background there (the demo flown at 2.5 m: its end found 0.13 m inside the wall's end, the
# simulator's roof line 6 mm off; truth masks: 1 cm)
MASK_EDGE_SIGMA_M = 0.15


def place_on_wall(inp: StitchInput, aligned: AlignedKeyframes, *, gnss_sigma_m: float, search_m: float,
                  scale_sigma: float | None, internal_m: float = 0.0,
                  mission_sigma_m: float = MISSION_SIGMA_M) -> tuple[AlignedKeyframes, WallPlacement]:
    """``aligned`` moved onto the wall's own edges where the keyframes show them (see the module docstring);
    ``search_m``: how far from the mission's edge an edge is looked for (the GNSS error it can correct);
    ``scale_sigma``: the map's relative scale uncertainty so far (``WallDistance.scale_sigma``);
    ``internal_m``: how far the map's keyframes may sit off each other inside it (the images against the
    telemetry, ``Anchoring.placement_sigma_m``): the ends fix the map's length, not its inside, so over half the
    wall this bounds how well the scale is known anywhere on it; ``mission_sigma_m``: how well the mission knows
    where its wall ends and its roof line are (each edge is that uncertain however sharply the masks show it)."""
    length, height = inp.facade.frame.length_m, inp.facade.height_m
    starts, ends, roofs = _edge_points(inp, aligned)
    found = [
        _edge("start", 0.0, starts, 0, (0.0, height), search_m, MIN_SPAN_FRACTION * height),
        _edge("end", length, ends, 0, (0.0, height), search_m, MIN_SPAN_FRACTION * height),
        _edge("roof", height, roofs, 1, (0.0, length), search_m, MIN_SPAN_FRACTION * length),
    ]
    edges = tuple(replace(e, sigma_m=math.sqrt(e.sigma_m**2 + mission_sigma_m**2 + MASK_EDGE_SIGMA_M**2))
                  for e in found if e is not None)
    by_name = {e.name: e for e in edges}
    s_sigma = UNKNOWN_SCALE_SIGMA if scale_sigma is None else scale_sigma
    factor, s_sigma, measured_length, warnings = _scale_from_ends(by_name, length, s_sigma)
    if warnings:  # the two ends contradict the mission's length: neither is trusted to place the map
        by_name = {n: e for n, e in by_name.items() if n == "roof"}
    s_sigma = max(s_sigma, internal_m / (length / 2.0))
    shift_a, sigma_a = _along(by_name, factor, s_sigma, length, gnss_sigma_m)
    shift_u, sigma_u = _up(by_name, factor, s_sigma, height, gnss_sigma_m)
    placement = WallPlacement((shift_a, shift_u), factor, (sigma_a, sigma_u),
                              s_sigma if (scale_sigma is not None or factor != 1.0) else None, edges,
                              measured_length, length, warnings)
    if shift_a == 0.0 and shift_u == 0.0 and factor == 1.0:
        return aligned, placement
    T = np.array([[factor, 0.0, shift_a], [0.0, factor, shift_u], [0.0, 0.0, 1.0]])
    G = [None if g is None else (T @ g) / (T @ g)[2, 2] for g in aligned.alignment.G]
    return replace(aligned, alignment=replace(aligned.alignment, G=G)), placement


def _scale_from_ends(by_name: dict[str, WallEdge], length: float,
                     scale_sigma: float) -> tuple[float, float, float | None, tuple[str, ...]]:
    """With both ends in view, the wall's length on the map against the mission's measures the map's scale
    error to a fraction of a percent: (factor to apply, scale sigma afterwards, length found, warnings). The
    two are combined by their uncertainties; a length that contradicts the images' scale beyond three sigmas
    is reported, not applied (the mission's ends may be wrong: they are someone's plan, not a survey)."""
    if "start" not in by_name or "end" not in by_name:
        return 1.0, scale_sigma, None, ()
    found = by_name["end"].found_m - by_name["start"].found_m
    error = found / length - 1.0
    sigma_len = math.hypot(by_name["start"].sigma_m, by_name["end"].sigma_m) / length
    if abs(error) > 3.0 * math.hypot(scale_sigma, sigma_len):
        return 1.0, scale_sigma, found, (
            f"the wall's ends are {found:.2f} m apart on the map, the mission says {length:.2f} m "
            f"({100 * error:+.1f} %, the scale is known to {100 * scale_sigma:.1f} %): the mission's start and end "
            "are not where the wall ends (or something else ends there); the map keeps the scale the images "
            "measured and GNSS's place along the wall",)
    gain = scale_sigma**2 / (scale_sigma**2 + sigma_len**2)
    combined = 1.0 / math.sqrt(1.0 / scale_sigma**2 + 1.0 / sigma_len**2)
    return 1.0 / (1.0 + gain * error), combined, found, ()


def _along(by_name: dict[str, WallEdge], factor: float, scale_sigma: float, length: float,
           gnss_sigma_m: float) -> tuple[float, float]:
    """The shift along that puts the (scaled) map on the ends it shows, and the map's place sigma at its
    centre: both ends split the difference; one end fixes its side, the scale's error grows away from it."""
    ends = [by_name[n] for n in ("start", "end") if n in by_name]
    if not ends:
        return 0.0, gnss_sigma_m
    offsets = [factor * e.found_m - e.expected_m for e in ends]
    if len(ends) == 2:
        return -float(np.mean(offsets)), math.hypot(*(e.sigma_m for e in ends)) / 2.0
    e = ends[0]
    return -offsets[0], math.hypot(e.sigma_m, scale_sigma * length / 2.0)


def _up(by_name: dict[str, WallEdge], factor: float, scale_sigma: float, height: float,
        gnss_sigma_m: float) -> tuple[float, float]:
    """The shift up that puts the (scaled) map's roof line on the wall's, and the place sigma at mid-height."""
    roof = by_name.get("roof")
    if roof is None:
        return 0.0, gnss_sigma_m
    return -(factor * roof.found_m - roof.expected_m), math.hypot(roof.sigma_m, scale_sigma * height / 2.0)


def _edge_points(inp: StitchInput, aligned: AlignedKeyframes):
    """Plane points of the masks' left, right and top edges inside the frames, each tagged with its keyframe:
    three (N, 3) arrays (along, up, keyframe position)."""
    cam = inp.camera
    to_norm = np.linalg.inv(cam.K)
    scale = WORK_WIDTH_PX / cam.width
    work = (WORK_WIDTH_PX, max(2, int(round(cam.height * scale))))
    found: list[list[np.ndarray]] = [[], [], []]
    for k in aligned.placed:
        kf = inp.keyframes[k]
        if kf.mask_path is None:
            continue
        mask = cv2.resize(load_mask(kf, (cam.width, cam.height)), work, interpolation=cv2.INTER_AREA) > 127
        to_plane = aligned.alignment.G[k] @ to_norm
        for side, px in enumerate(_mask_edges(mask)):
            if len(px):
                plane = apply_h(to_plane, (px + 0.5) / scale)
                found[side].append(np.column_stack((plane, np.full(len(plane), k))))
    return tuple(np.vstack(f) if f else np.zeros((0, 3)) for f in found)


def _mask_edges(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Work pixels (x, y) of each row's first and last wall pixel and each column's first, where they lie
    inside the frame: the wall's left end, right end and top as this frame sees them."""
    h, w = mask.shape
    rows = np.flatnonzero(mask.any(axis=1))
    cols = np.flatnonzero(mask.any(axis=0))
    left = mask[rows].argmax(axis=1)
    right = w - 1 - mask[rows, ::-1].argmax(axis=1)
    top = mask[:, cols].argmax(axis=0)
    inside_l = left >= BORDER_PX
    inside_r = right <= w - 1 - BORDER_PX
    inside_t = top >= BORDER_PX
    return (np.column_stack((left[inside_l] - 0.5, rows[inside_l])).astype(float),
            np.column_stack((right[inside_r] + 0.5, rows[inside_r])).astype(float),
            np.column_stack((cols[inside_t], top[inside_t] - 0.5)).astype(float))


def _edge(name: str, expected: float, pts: np.ndarray, axis: int, extent: tuple[float, float], search_m: float,
          min_span_m: float) -> WallEdge | None:
    """The edge across ``axis`` (0: along, 1: up) nearest ``expected`` that the points vote for, or None when
    the vote is weak (few keyframes, a short edge, or no dominant line among the candidates)."""
    if len(pts) == 0:
        return None
    across, length = pts[:, axis], pts[:, 1 - axis]
    near = (np.abs(across - expected) <= search_m) & (length >= extent[0] - 0.5) & (length <= extent[1] + 0.5)
    if near.sum() < 10:
        return None
    across, length, keys = across[near], length[near], pts[near, 2]
    bins = np.arange(expected - search_m, expected + search_m + BIN_M, BIN_M)
    votes, _ = np.histogram(across, bins)
    votes = np.convolve(votes, np.ones(3), mode="same")
    peak = float(bins[int(np.argmax(votes))] + BIN_M / 2)
    on = np.abs(across - peak) <= WINDOW_M
    if on.sum() < MIN_SHARE * len(across):
        return None
    keyframes = len(np.unique(keys[on]))
    span = float(np.ptp(length[on])) if on.sum() > 1 else 0.0
    if keyframes < MIN_KEYFRAMES or span < min_span_m:
        return None
    found = float(np.median(across[on]))
    # per keyframe: the median of its points, then their spread over the keyframes (each keyframe's mask and
    # pose err on its own; points of one keyframe do not)
    per_kf = np.array([np.median(across[on][keys[on] == k]) for k in np.unique(keys[on])])
    spread = 1.4826 * float(np.median(np.abs(per_kf - found))) if keyframes > 2 else float(np.ptp(per_kf))
    sigma = math.hypot(spread * 1.2533 / math.sqrt(keyframes), BIN_M / 2)
    return WallEdge(name, expected, found, sigma, keyframes, int(on.sum()))

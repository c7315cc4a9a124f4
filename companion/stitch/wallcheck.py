"""Pixels a keyframe's mask keeps that are not on the wall: cut before the map is drawn (issue 15 items 2, 4).

The depth mask is a network's guess: on real facades it keeps some background (trees and houses seen through a
gap in the wall, beside its end, above the roof line), and raw input may have no mask at all. The pairs stage
rejects far scenery in the *matches* (a second, slower plane), but a region seen near the frame edge as the
camera moves on is matched in no pair, and the map would draw it. What the images say about such a pixel: the
wall's homography of an accepted pair carries it into the neighbouring keyframe, and there it lands on something
else (the wall that hid it, or other background), because it is not on the wall plane. Two tests, per pair:

* the wall hypothesis fails: the pixel differs from its wall point in the neighbour by more than
  ``grey_tolerance`` grey levels after smoothing and the pair's exposure ratio;
* a far hypothesis explains it better: carried by the homography of a plane far behind the wall (the pair's
  rotation alone, from the wall homography's decomposition, and planes at ``far_depth_ratios`` of the wall's
  inverse depth: 20 m and more at a 4 m standoff), it differs by ``far_margin`` grey levels less than on the
  wall. Low-contrast scenery (haze, foliage in shade, a street in the distance) often stays within the
  tolerance on the wall hypothesis alone; against its own motion it agrees to a few levels.

A pixel is cut when it fails in most of the neighbours that see the same wall point. The neighbour's own mask
does not matter: what it shows at that point is the evidence, and a neighbour whose mask already cut the region
(the depth network was sure there) is the best witness. Wall pixels agree to a few levels on the wall (the pairs
are registered to a fraction of a pixel) and a far plane does not explain them; parallax too small to measure
(hover, the wall motion below a few RANSAC thresholds) decides nothing, and neither does a uniform region (sky,
plain render) that every hypothesis explains equally.

The same evidence gives back wall the mask cut (a roof or a dormer the network read as far, cut in every
keyframe, would be a hole in the map): a cut pixel is restored when at least ``min_witnesses`` neighbours, and
most of those that decide, find it on its wall point (within ``wall_agreement``) and no far plane near it
(every far plane at least ``far_margin`` worse), it has texture of its own (local contrast of at least
``min_texture`` grey levels), it lies ``restore_edge_px`` clear of the kept mask (on an edge the smoothed
comparison straddles both sides: a hole in the wall whose rim is on the wall plane would read as wall) and in
a region, not a speck. A uniform region (sky) carries no evidence: beside the wall's edge a far plane
lands on the wall that hides it, and that must not read as proof that the sky is wall.
"""

from __future__ import annotations

import hashlib
import os
import threading
from concurrent.futures import Executor, ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from pathlib import Path

import cv2
import numpy as np

from companion.files import atomic_path
from companion.stitch.features import load_image_and_mask, load_mask
from companion.stitch.geometry import apply_h
from companion.stitch.inputs import StitchInput
from companion.stitch.pairs import PairResult


@dataclass(frozen=True)
class WallCheck:
    """What the check changed: per keyframe position, the share of its mask found off the wall plane, and the
    pixels it restored as a share of the mask's cut pixels."""

    input: StitchInput  # keyframes whose mask changed point at the checked mask
    cut_share: dict[int, float]
    restored_share: dict[int, float] = field(default_factory=dict)


@dataclass(frozen=True)
class WallCheckSettings:
    grey_tolerance: float = 25.0  # mean grey difference (after smoothing) above which a pixel is not the wall
    wall_agreement: float = 10.0  # ... and below which it is; between the two a neighbour decides nothing
    far_margin: float = 5.0  # a far plane must explain the pixel this many grey levels better than the wall
    # far planes tried, as fractions of the wall's inverse depth (0: infinity; 0.2: five standoffs behind)
    far_depth_ratios: tuple[float, ...] = (0.0, 0.05, 0.1, 0.2)
    min_motion_px: float = 8.0  # the wall must move this much between the two keyframes (parallax measurable)
    work_width: int = 960  # the check runs on copies this wide
    min_region_px: int = 5  # opening: specks smaller than this (work px) are noise
    restore: bool = True  # give back cut pixels the neighbours confirm as wall
    min_witnesses: int = 2  # neighbours that must confirm a cut pixel as wall (and most of those that decide)
    # restored pixels keep this far (work px) from the kept mask: the smoothed comparison straddles the mask's edge,
    # and where that edge lies on the wall (a window, a hole in the wall) its blur reads as wall
    restore_edge_px: float = 8.0
    restore_region_px: int = 15  # opening of the restored pixels: only regions (a roof), never specks
    min_texture: float = 4.0  # grey levels of local contrast (std, 9 px) a pixel needs to be confirmed as wall
    fill_px: int = 12  # gaps (work px) between confirmed textured wall and the kept mask that plain wall fills


def check_wall(
    inp: StitchInput,
    pairs: list[PairResult],
    cache_dir: Path,
    settings: WallCheckSettings | None = None,
    *,
    workers: int = 0,
) -> WallCheck:
    """Cuts off-plane pixels from the masks of the keyframes in accepted ``pairs`` (H: pixels of i -> pixels
    of j); checked masks are written to ``cache_dir``. Keyframes in no pair are left as they are. ``workers``:
    threads (0: one per CPU core); the result does not depend on it."""
    s = settings or WallCheckSettings()
    involved = sorted({k for r in pairs for k in (r.i, r.j)})
    if not involved:
        return WallCheck(inp, {})
    # decoding and every pair direction run in OpenCV without the GIL: one keyframe or direction per thread
    with ThreadPoolExecutor(workers or max(1, len(os.sched_getaffinity(0)))) as pool:
        grey, masks, sizes, scale = _load(inp, involved, s.work_width, pool)
        S = np.diag([scale, scale, 1.0])
        K = S @ _intrinsics(inp, sizes[involved[0]])
        votes = {k: np.zeros(grey[k].shape, np.float32) for k in involved}
        checks = {k: np.zeros(grey[k].shape, np.float32) for k in involved}
        confirms = {k: np.zeros(grey[k].shape, np.float32) for k in involved}
        # once per keyframe, not per pair direction
        contrast = dict(zip(involved, pool.map(_local_contrast, [grey[k] for k in involved]), strict=True))
        directions = []
        for r in pairs:
            Hw = S @ r.H @ np.linalg.inv(S)
            gain = float(np.exp(r.lum_ratio)) if r.lum_ratio is not None else 1.0
            # lum_ratio = log(grey_i / grey_j): j's grey times the gain reads as i's, i's over it as j's
            both = ((r.i, r.j, Hw, gain, r.pts_i), (r.j, r.i, np.linalg.inv(Hw), 1.0 / gain, r.pts_j))
            for a, b, H, g, pts in both:
                if r.pts_i is None or _motion(H, pts * scale) < s.min_motion_px * scale:
                    continue
                directions.append((a, b, H, g))
        lock = threading.Lock()

        def witness(direction) -> None:
            a, b, H, g = direction
            # 0.5: twice the standoff; -0.5: as far beyond the far planes (the same shift the other way)
            planes = _far_homographies(H, K, s, (*s.far_depth_ratios, 0.5, -0.5))
            off, decided, wall = _witness(grey[a], grey[b], H, planes[:-2], g, s, midway=planes[-2:])
            with lock:  # sums of 0/1 maps: exact in float32 whatever the order the threads finish in
                votes[a] += off
                checks[a] += decided
                confirms[a] += wall

        list(pool.map(witness, directions))  # each direction's maps are added as they are made: memory stays flat
    cache_dir.mkdir(parents=True, exist_ok=True)
    kfs = list(inp.keyframes)
    cut_share, restored_share = {}, {}
    opening = np.ones((s.min_region_px, s.min_region_px), np.uint8)
    for k in involved:
        share = np.where(checks[k] > 0, votes[k] / np.maximum(checks[k], 1.0), 0.0)
        kept = masks[k] > 0
        off = ((share > 0.5) & kept).astype(np.uint8) * 255
        off = cv2.morphologyEx(off, cv2.MORPH_OPEN, opening)
        back = np.zeros_like(off)
        if s.restore:
            confirmed = (confirms[k] >= s.min_witnesses) & (confirms[k] > 0.5 * checks[k]) & ~kept
            # on its wall point in enough neighbours and off in none of most: consistent with the wall, though
            # a plain patch proves nothing by itself (every plane explains it)
            consistent = (checks[k] - votes[k] >= s.min_witnesses) & (share <= 0.5) & ~kept
            back = _restored(confirmed, consistent, kept, contrast[k], s)
        if not off.any() and not back.any():
            continue
        full_mask = load_mask(kfs[k], sizes[k])  # read again only where something changes
        off_full = cv2.resize(off, sizes[k], interpolation=cv2.INTER_NEAREST)
        back_full = cv2.resize(back, sizes[k], interpolation=cv2.INTER_NEAREST)
        checked = cv2.bitwise_or(cv2.bitwise_and(full_mask, cv2.bitwise_not(off_full)),
                                 cv2.bitwise_and(back_full, cv2.bitwise_not(full_mask)))
        n_kept = int(np.count_nonzero(full_mask))
        cut_share[k] = int(np.count_nonzero(cv2.bitwise_and(full_mask, off_full))) / max(1, n_kept)
        restored = int(np.count_nonzero(cv2.bitwise_and(back_full, cv2.bitwise_not(full_mask))))
        restored_share[k] = restored / max(1, full_mask.size - n_kept)
        kfs[k] = replace(kfs[k], mask_path=_write_mask(cache_dir, kfs[k], checked))
    return WallCheck(replace(inp, keyframes=kfs), cut_share, restored_share)


def _restored(confirmed: np.ndarray, consistent: np.ndarray, kept: np.ndarray, contrast: np.ndarray,
              s: WallCheckSettings) -> np.ndarray:
    """The cut pixels given back (0/255). The neighbours' confirmation is evidence where the pixel has texture
    of its own (``min_texture``) and lies clear of the kept mask's edge. A wall's plain patches between its
    features (render between window frames, a cornice's flat band) and the band along the kept mask's edge carry
    no evidence themselves: there a pixel ``consistent`` with the wall is given back when it lies in a gap between
    the evidence and the kept mask (a closing of ``fill_px``) and its region holds evidence. The restore fills
    in; it never grows out past the evidence (sky beyond a roof's edge) nor into a hole that only the kept mask
    surrounds (a window onto the sky)."""
    textured = confirmed & (contrast >= s.min_texture)
    textured &= cv2.distanceTransform((~kept).astype(np.uint8), cv2.DIST_L2, 5) >= s.restore_edge_px
    evidence = cv2.morphologyEx(textured.astype(np.uint8), cv2.MORPH_OPEN, np.ones((s.min_region_px,) * 2, np.uint8))
    if not evidence.any():
        return np.zeros(kept.shape, np.uint8)
    disk = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * s.fill_px + 1,) * 2)
    # the frame's edge bounds a gap as the kept mask does (a band between the kept wall and the frame's bottom)
    closed = cv2.morphologyEx(((evidence > 0) | kept).astype(np.uint8), cv2.MORPH_CLOSE, disk,
                              borderType=cv2.BORDER_CONSTANT, borderValue=1)
    filled = ((closed > 0) & (consistent | confirmed)) | (evidence > 0)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(filled.astype(np.uint8), connectivity=8)
    holds = np.zeros(n, bool)
    holds[np.unique(labels[evidence > 0])] = True
    holds &= stats[:, cv2.CC_STAT_AREA] >= s.restore_region_px**2
    holds[0] = False
    return holds[labels].astype(np.uint8) * 255


def _load(inp: StitchInput, positions: list[int], work_width: int, pool: Executor):
    """Smoothed grey and mask copies at the working width, and each frame's (width, height): only the small copies
    stay in memory, so a long spool of 4K keyframes costs what its 960 px copies cost. Decoded on ``pool``'s
    threads, at most a few full-size frames at a time."""

    def small_copies(k: int):
        img, mask = load_image_and_mask(inp.keyframes[k])
        scale = min(1.0, work_width / img.shape[1])
        size = (round(img.shape[1] * scale), round(img.shape[0] * scale))
        g = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
        g = cv2.resize(g, size, interpolation=cv2.INTER_AREA) if scale < 1.0 else g
        m = cv2.resize(mask, size, interpolation=cv2.INTER_NEAREST) if scale < 1.0 else mask
        return cv2.GaussianBlur(g.astype(np.float32), (0, 0), 1.5), m, (img.shape[1], img.shape[0]), scale

    grey, masks, sizes = {}, {}, {}
    copies = list(pool.map(small_copies, positions))
    for k, (g, m, size, _) in zip(positions, copies, strict=True):
        grey[k], masks[k], sizes[k] = g, m, size
    return grey, masks, sizes, copies[-1][3] if copies else 1.0


def _local_contrast(grey: np.ndarray, size: int = 9) -> np.ndarray:
    """Standard deviation of the grey levels in a ``size`` window around each pixel."""
    mean = cv2.blur(grey, (size, size))
    return np.sqrt(np.maximum(cv2.blur(grey * grey, (size, size)) - mean * mean, 0.0))


def _contrast_along(grey: np.ndarray, direction: np.ndarray, size: int = 9) -> np.ndarray:
    """Standard deviation of the grey levels on a ``size`` px line along ``direction`` (unit vector) through each
    pixel: an edge along the direction has none, however sharp across it."""
    kernel = np.zeros((size, size), np.float32)
    c = size // 2
    end = np.round(np.asarray(direction, float) * c).astype(int)
    cv2.line(kernel, (int(c - end[0]), int(c - end[1])), (int(c + end[0]), int(c + end[1])), 1.0, 1)
    kernel /= kernel.sum()
    mean = cv2.filter2D(grey, -1, kernel)
    return np.sqrt(np.maximum(cv2.filter2D(grey * grey, -1, kernel) - mean * mean, 0.0))


def _motion_direction(H: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """The unit direction in which H moves the frame's centre (``size``: width, height)."""
    centre = np.array([[size[0] / 2.0, size[1] / 2.0]])
    d = (apply_h(H, centre) - centre)[0]
    n = float(np.linalg.norm(d))
    return d / n if n > 1e-9 else np.array([1.0, 0.0])


def _motion(H: np.ndarray, pts: np.ndarray) -> float:
    return float(np.median(np.linalg.norm(apply_h(H, pts) - pts, axis=1)))


def _intrinsics(inp: StitchInput, size: tuple[int, int]) -> np.ndarray:
    """The keyframes' camera matrix in full-resolution pixels; without one (a spool with no camera), a 53 degree
    lens: the far planes only need the pair's rotation roughly (a degree is a few pixels of a blurred image)."""
    if inp.camera is not None:
        return np.asarray(inp.camera.K, float)
    w, h = size
    return np.array([[float(w), 0.0, w / 2.0], [0.0, float(w), h / 2.0], [0.0, 0.0, 1.0]])


def _far_homographies(H: np.ndarray, K: np.ndarray, s: WallCheckSettings, ratios: tuple[float, ...] | None = None
                      ) -> list[np.ndarray]:
    """Homographies (pixels of a -> pixels of b) of planes parallel to the wall, far behind it: the wall's
    H = K (R - t n^T / d) K^-1 decomposed, the plane at inverse depth ``r / d`` is K (R - r t n^T / d) K^-1. The
    decomposition's solution with the normal closest to the optical axis is the wall's (the camera faces it).
    Empty where H does not decompose (a degenerate fit: no far test)."""
    Kinv = np.linalg.inv(K)
    G = Kinv @ H @ K
    sv = np.linalg.svd(G, compute_uv=False)
    if not np.all(np.isfinite(sv)) or sv[1] <= 1e-9:
        return []
    G = G / sv[1] * np.sign(np.linalg.det(G))  # the scale and sign at which G = R - t n^T / d
    n, rotations, _, normals = cv2.decomposeHomographyMat(H, K)
    if n == 0:
        return []
    R = rotations[max(range(n), key=lambda q: abs(float(normals[q][2, 0])))]
    return [K @ ((1.0 - r) * R + r * G) @ Kinv for r in (s.far_depth_ratios if ratios is None else ratios)]


def _witness(ga, gb, H, far: list[np.ndarray], gain: float, s: WallCheckSettings, midway: list[np.ndarray] = ()):
    """What keyframe b says about each pixel of a (b sampled at H(x), away from b's frame edge), as three 0/1
    maps: off the wall (its wall point in b shows something else, beyond ``grey_tolerance``, or a far plane
    explains it better by ``far_margin``); decided (off, or on its wall point within ``wall_agreement``; in
    between, a middling difference no far plane explains, such as the far plane's point in b hidden behind the
    wall, b abstains); confirmed wall (on its wall point and every far plane worse by ``far_margin``).

    Past b's frame edge on the wall (the outer side of a strip's first or last keyframe, which no other keyframe
    sees on the wall) a far scene is still in b's view: it moves a fraction of the wall's motion. There a
    pixel textured along the motion that a far plane explains within ``wall_agreement`` is off, provided the
    explanation is distinctive: each plane of ``midway`` (twice the standoff; and as far beyond the far planes, the
    same shift the other way) whose point b shows does worse by twice ``far_margin``, and b shows at least one. A
    plain wall, and the wall's edge along the motion (its end in a vertical strip, a roof line in a horizontal
    one: contrast across the motion only), look alike under every shift along the motion and are never cut this
    way. A point past b's frame edge is no evidence: b reads black there, which made any explanation look
    distinctive and, with the edge's contrast taken for texture, cut a sliver of wall along the wall's end (5-10 cm
    at the synthetic wall's left end, tests/test_stitch_worker.py::test_outputs_on_disk)."""
    h, w = ga.shape
    valid = _seen(H, gb.shape, (w, h))
    on_wall = _difference(ga, gb, H, gain)
    off = on_wall > s.grey_tolerance
    agrees = on_wall <= s.wall_agreement
    confirmed = np.zeros_like(agrees)
    far_only = np.zeros_like(agrees)
    if far:
        best_far = np.minimum.reduce([_difference(ga, gb, Hf, gain) for Hf in far])
        off |= best_far + s.far_margin < on_wall
        confirmed = agrees & (best_far > on_wall + s.far_margin)
        far_seen = _seen(far[0], gb.shape, (w, h))
        # with no wall evidence to weigh it against, the far explanation must be twice as tight and as distinctive
        textured = _contrast_along(ga, _motion_direction(H, (w, h))) >= 2 * s.min_texture
        far_only = far_seen & ~valid & (best_far <= s.wall_agreement / 2) & textured
        seen_by_any = np.zeros_like(far_only)
        for Hm in midway:
            seen = _seen(Hm, gb.shape, (w, h))
            far_only &= ~seen | (_difference(ga, gb, Hm, gain) > best_far + 2 * s.far_margin)
            seen_by_any |= seen
        far_only &= seen_by_any
    decided = off | agrees
    return (((valid & off) | far_only).astype(np.float32), ((valid & decided) | far_only).astype(np.float32),
            (valid & confirmed).astype(np.float32))


def _seen(H: np.ndarray, b_shape: tuple[int, int], size: tuple[int, int]) -> np.ndarray:
    """Where a's pixels (``size``: width, height) carried by H land inside b's frame, 4 px clear of its edge."""
    ones = np.full(b_shape, 255, np.uint8)
    warped = cv2.warpPerspective(ones, H, size, flags=cv2.INTER_NEAREST | cv2.WARP_INVERSE_MAP)
    return cv2.erode(warped, np.ones((9, 9), np.uint8)) > 0


def _difference(ga, gb, H, gain: float) -> np.ndarray:
    """|a - b carried by H| (b's grey times ``gain``), smoothed: a registration off by a pixel reads small."""
    h, w = ga.shape
    gb_at = cv2.warpPerspective(gb, H, (w, h), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP)
    if gain != 1.0:
        gb_at *= gain
    return cv2.GaussianBlur(cv2.absdiff(ga, gb_at), (0, 0), 3.0)


def _write_mask(cache_dir: Path, kf, mask: np.ndarray) -> Path:
    ok, png = cv2.imencode(".png", mask)
    tag = hashlib.sha1(png.tobytes()).hexdigest()[:12]
    path = cache_dir / f"{kf.index:06d}-{tag}.png"
    if not path.exists():
        with atomic_path(path) as tmp:
            Path(tmp).write_bytes(png.tobytes())
    return path

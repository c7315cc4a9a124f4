"""Background the mask kept, beside the wall's end or through a gap in it, is cut before the map is drawn.

Measured on the real-texture pass cmp-balconies with the shipped real-nc mask (docs/BENCHMARKS.md): trees and houses
120 m behind, seen through the gap at the wall photo's right edge, were drawn into the map (125 RANSAC inliers
against the background photo, 14 for the truth-masked map). Such a region is seen only near the frame edge as the
camera moves on, so no pair matches it; the wall's homography carries it into the neighbour, where it lands on
the wall that hid it.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from companion.spool.reader import CameraModel, KeyframeInput, StitchInput
from companion.stitch.pairs import PairResult
from companion.stitch.wallcheck import check_wall

W, H, STEP = 320, 200, 100  # frame size, wall motion per keyframe (px)
GAP = (520, 640)  # a gap in the wall (wall px, along): the far scene shows through it


def _texture(seed: int, width: int, contrast: float = 1.0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    noise = rng.integers(0, 255, (H // 4, width // 4), dtype=np.uint8)
    tex = cv2.resize(noise, (width, H), interpolation=cv2.INTER_CUBIC).astype(np.float32)
    return np.clip(128.0 + contrast * (tex - 128.0), 0, 255).astype(np.uint8)


def _plain_with_spots(tex: np.ndarray, seed: int, spot: int = 8, share: float = 0.3) -> np.ndarray:
    """``tex`` made plain grey except on random ``spot`` px squares (about ``share`` of the area): a wall whose
    features are sparse (ornaments on flat render), plain patches between them."""
    rng = np.random.default_rng(seed)
    cells = rng.random((tex.shape[0] // spot + 1, tex.shape[1] // spot + 1)) < share
    spots = np.kron(cells, np.ones((spot, spot), bool))[: tex.shape[0], : tex.shape[1]]
    return np.where(spots, tex, 128).astype(np.uint8)


def _spool(tmp: Path, n: int, *, far_contrast: float = 1.0, masks_cut_from: int | None = None,
           gap: tuple[int, int] = GAP, roof_rows: int = 0, plain_roof: bool = False
           ) -> tuple[StitchInput, list[PairResult], list[np.ndarray]]:
    """n keyframes of a textured wall moving STEP px left per keyframe, with a gap through which a far scene is
    seen (it does not move in the image); every mask is the whole frame (the mask kept the far scene), except
    that from keyframe ``masks_cut_from`` on the masks cut the far scene (the network was sure there). Returns
    the input, the neighbours' pairs (the wall's homographies) and where each frame shows the far scene (through
    ``gap``: wall px along; open at the right, it is the scene beyond the wall's end)."""
    wall, far = _texture(1, STEP * n + W), _texture(2, W, far_contrast)
    if plain_roof:
        wall[:roof_rows] = _plain_with_spots(wall[:roof_rows], 3)
    kfs, far_px = [], []
    for k in range(n):
        img = wall[:, STEP * k : STEP * k + W].copy()
        u = STEP * k + np.arange(W)
        through = (u >= gap[0]) & (u < gap[1])
        img[:, through] = far[:, through]
        far_px.append(through)
        path, mask = tmp / f"{k}.png", tmp / f"{k}_mask.png"
        cv2.imwrite(str(path), cv2.cvtColor(img, cv2.COLOR_GRAY2BGR))
        roi = np.full((H, W), 255, np.uint8)
        if masks_cut_from is not None and k >= masks_cut_from:
            roi[:, through] = 0
        roi[:roof_rows, :] = 0  # wall the network read as far (a roof): cut in every keyframe
        cv2.imwrite(str(mask), roi)
        kfs.append(KeyframeInput(k, path, mask, None))
    pairs = []
    grid = np.array([(x, y) for x in range(0, W, 20) for y in range(10, H, 20)], float)
    for i in range(n):
        for j in range(i + 1, min(n, i + 3)):
            shift = STEP * (j - i)
            Hij = np.array([[1.0, 0.0, -shift], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
            u = STEP * i + grid[:, 0]
            pts_i = grid[(grid[:, 0] >= shift) & ((u < gap[0]) | (u >= gap[1]))]
            pairs.append(PairResult(i, j, True, "homography", "", len(pts_i), len(pts_i), 0.1, Hij, pts_i,
                                    pts_i - [shift, 0.0], 0.0))
    cam = CameraModel(np.array([[300.0, 0, W / 2], [0, 300.0, H / 2], [0, 0, 1]]), W, H)
    return StitchInput(kfs, cam, None, None, "spool"), pairs, far_px


def test_background_kept_by_the_mask_is_cut_and_the_wall_is_kept(tmp_path):
    inp, pairs, far_px = _spool(tmp_path, 5)
    checked = check_wall(inp, pairs, tmp_path / "masks")
    masks = [cv2.imread(str(kf.mask_path), cv2.IMREAD_GRAYSCALE) for kf in checked.input.keyframes]
    far_kept = sum(np.count_nonzero(m[:, f]) for m, f in zip(masks, far_px, strict=True))
    far_total = sum(H * np.count_nonzero(f) for f in far_px)
    assert far_total > 0 and far_kept < 0.15 * far_total  # the gap's far scene is cut (all but a frame edge)
    wall_cut = sum(np.count_nonzero(m[:, ~f] == 0) for m, f in zip(masks, far_px, strict=True))
    assert wall_cut < 0.01 * sum(H * np.count_nonzero(~f) for f in far_px)  # the wall is kept
    assert inp.keyframes[3].mask_path != checked.input.keyframes[3].mask_path  # the spool's own mask untouched
    assert cv2.imread(str(inp.keyframes[3].mask_path), cv2.IMREAD_GRAYSCALE).min() == 255


def test_no_parallax_no_cut(tmp_path):
    """A hover (the wall does not move between keyframes) says nothing about depth: nothing is cut."""
    inp, pairs, _ = _spool(tmp_path, 3)
    still = [PairResult(r.i, r.j, True, "homography", "", 10, 10, 0.1, np.eye(3), r.pts_i, r.pts_i, 0.0)
             for r in pairs]
    checked = check_wall(inp, still, tmp_path / "masks")
    assert checked.cut_share == {} and checked.input.keyframes == inp.keyframes


def _far_kept(checked, far_px, upto: int) -> float:
    masks = [cv2.imread(str(kf.mask_path), cv2.IMREAD_GRAYSCALE) for kf in checked.input.keyframes[:upto]]
    kept = sum(np.count_nonzero(m[:, f]) for m, f in zip(masks, far_px, strict=False))
    return kept / max(1, sum(H * np.count_nonzero(f) for f in far_px[:upto]))


def test_low_contrast_far_scene_is_cut(tmp_path):
    """A hazy far scene beyond the wall's end (a quarter of the wall's contrast) stays within the grey tolerance
    on the wall's homography, but its own motion (none: it is far) explains it to the grey level: cut. (The
    check before the far hypothesis kept all of it.) The last keyframe's far scene, seen by no later keyframe, has
    no witness that the far plane explains it: it is left out of the count."""
    inp, pairs, far_px = _spool(tmp_path, 6, far_contrast=0.25, gap=(560, 10**6))
    checked = check_wall(inp, pairs, tmp_path / "masks")
    assert _far_kept(checked, far_px, 5) < 0.15
    masks = [cv2.imread(str(kf.mask_path), cv2.IMREAD_GRAYSCALE) for kf in checked.input.keyframes]
    wall_cut = sum(np.count_nonzero(m[:, ~f] == 0) for m, f in zip(masks, far_px, strict=True))
    assert wall_cut < 0.01 * sum(H * np.count_nonzero(~f) for f in far_px)


def test_neighbours_whose_mask_cut_the_background_still_testify(tmp_path):
    """The first keyframes' masks keep the far scene, the later ones' cut it (the depth network was sure there,
    as the real-nc mask is on frames that show more background): what those later keyframes SHOW at the wall
    point is the evidence, so the early keyframes' far scene is cut too. (The check before required the
    neighbour's mask to keep the point too and left it.)"""
    inp, pairs, far_px = _spool(tmp_path, 6, masks_cut_from=4)
    checked = check_wall(inp, pairs, tmp_path / "masks")
    assert _far_kept(checked, far_px, 4) < 0.15


def test_wall_every_mask_cut_is_restored_and_the_far_scene_stays_cut(tmp_path):
    """Every keyframe's mask cut the top 60 rows of the wall (a roof the network read as far) and the far scene
    (right); the neighbours find the roof on its wall point and no far plane explains it: restored, so the map
    has no hole there. The far scene, whether textured (the gap) or uniform (sky: every plane explains it
    equally), stays cut. (The check before could only cut: the roof stayed a hole.) The wall behind the gap is
    restored too where a neighbour sees it."""
    inp, pairs, far_px = _spool(tmp_path, 6, masks_cut_from=0, roof_rows=60)
    checked = check_wall(inp, pairs, tmp_path / "masks")
    masks = [cv2.imread(str(kf.mask_path), cv2.IMREAD_GRAYSCALE) for kf in checked.input.keyframes]
    roof_seen = np.zeros(STEP * 6 + W, bool)  # wall columns whose roof some keyframe draws
    for k, m in enumerate(masks):
        # the roof's 8 px next to the kept wall stay cut (the restore keeps clear of the mask's edge)
        roof_seen[STEP * k + np.flatnonzero((m[:50] > 0).mean(axis=0) > 0.9)] = True
    u = np.arange(STEP * 6 + W)
    # wall columns three keyframes see (two witnesses: the first and the last keyframes' outer 2 STEP px have
    # fewer)
    witnessed = (u >= 2 * STEP) & (u < STEP * 5 + W - 2 * STEP) & ((u < GAP[0]) | (u >= GAP[1]))
    assert roof_seen[witnessed].mean() > 0.95
    assert _far_kept(checked, far_px, 6) < 0.02
    assert max(checked.restored_share.values()) > 0.5


def test_plain_wall_between_features_every_mask_cut_is_restored(tmp_path):
    """Every keyframe's mask cut the top 60 rows of a wall that is plain render with sparse ornaments (the sim
    depth model on cmp-balconies: 19 % of the wall cut, flat bands and balconies, docs/BENCHMARKS.md). The
    ornaments are confirmed wall; the plain render between them and the band along the kept wall agree with
    their wall points and no neighbour finds them off: given back as well, so the map has no hole there. (The
    restore before gave back only textured pixels 8 px clear of the kept mask, in 15 px squares: the plain
    patches and the band stayed holes.) The far scene through the gap stays cut."""
    inp, pairs, far_px = _spool(tmp_path, 6, masks_cut_from=0, roof_rows=60, plain_roof=True)
    checked = check_wall(inp, pairs, tmp_path / "masks")
    masks = [cv2.imread(str(kf.mask_path), cv2.IMREAD_GRAYSCALE) for kf in checked.input.keyframes]
    u = np.arange(STEP * 6 + W)
    witnessed = (u >= 2 * STEP) & (u < STEP * 5 + W - 2 * STEP) & ((u < GAP[0] - 10) | (u >= GAP[1] + 10))
    drawn = np.zeros((60, STEP * 6 + W), bool)  # roof pixels (wall px) some keyframe's mask keeps
    for k, m in enumerate(masks):
        drawn[:, STEP * k : STEP * k + W] |= m[:60] > 0
    assert drawn[:, witnessed].mean() > 0.97
    assert _far_kept(checked, far_px, 6) < 0.02


def test_uniform_sky_the_mask_cut_is_not_restored(tmp_path):
    """A uniform far region (sky beyond the wall's end) agrees with its wall point in every neighbour, but a far
    plane explains it as well: nothing confirms it is wall, so it stays cut."""
    inp, pairs, far_px = _spool(tmp_path, 6, far_contrast=0.0, gap=(560, 10**6), masks_cut_from=0)
    checked = check_wall(inp, pairs, tmp_path / "masks")
    assert _far_kept(checked, far_px, 6) < 0.02


def test_far_scene_only_the_last_keyframe_shows_on_the_wall_is_cut(tmp_path):
    """The last keyframe's outer side (the far scene beyond the wall's end) is seen on the wall by no other
    keyframe, but the far scene itself is still in the neighbours' view (it does not move): there it agrees
    with a far plane, so it is cut too. (Before, that part of the last keyframe had no witness and was drawn:
    cmp-roofline-40m with the real-nc mask, the background at the strip's end.)"""
    inp, pairs, far_px = _spool(tmp_path, 6, gap=(560, 10**6))
    checked = check_wall(inp, pairs, tmp_path / "masks")
    assert _far_kept(checked, far_px, 6) < 0.05
    masks = [cv2.imread(str(kf.mask_path), cv2.IMREAD_GRAYSCALE) for kf in checked.input.keyframes]
    wall_cut = sum(np.count_nonzero(m[:, ~f] == 0) for m, f in zip(masks, far_px, strict=True))
    assert wall_cut < 0.01 * sum(H * np.count_nonzero(~f) for f in far_px)


def test_the_walls_edge_along_the_motion_is_not_cut_past_the_neighbours_frame(tmp_path):
    """The wall's edge along the camera's motion (its end in a vertical strip, a roof line in a horizontal one)
    looks the same under every shift along it: past the neighbour's frame edge a far plane 'explains' the pixels
    beside it as well as anything, and the plane halfway to the wall, out past that frame too, read black there,
    so the explanation looked distinctive and a sliver of wall along the edge was cut. It made a 5-10 cm re-fly area at
    the synthetic wall's left end (tests/test_stitch_worker.py::test_outputs_on_disk). Here: a roof line along a
    horizontal pass, sky above (cut by the mask), a plain band of wall below it, then textured wall: nothing cut."""
    n, roof, band = 6, 60, 12
    wall = _texture(1, STEP * n + W)
    wall[:roof] = 200  # sky
    wall[roof : roof + band] = 100  # plain render along the roof line
    kfs = []
    for k in range(n):
        img = wall[:, STEP * k : STEP * k + W]
        path, mask = tmp_path / f"{k}.png", tmp_path / f"{k}_mask.png"
        cv2.imwrite(str(path), cv2.cvtColor(img, cv2.COLOR_GRAY2BGR))
        roi = np.full((H, W), 255, np.uint8)
        roi[:roof] = 0
        cv2.imwrite(str(mask), roi)
        kfs.append(KeyframeInput(k, path, mask, None))
    grid = np.array([(x, y) for x in range(0, W, 20) for y in range(roof + 10, H, 20)], float)
    pairs = []
    for i in range(n):
        for j in range(i + 1, min(n, i + 3)):
            shift = STEP * (j - i)
            pts_i = grid[grid[:, 0] >= shift]
            Hij = np.array([[1.0, 0.0, -shift], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
            pairs.append(PairResult(i, j, True, "homography", "", len(pts_i), len(pts_i), 0.1, Hij, pts_i,
                                    pts_i - [shift, 0.0], 0.0))
    cam = CameraModel(np.array([[300.0, 0, W / 2], [0, 300.0, H / 2], [0, 0, 1]]), W, H)
    checked = check_wall(StitchInput(kfs, cam, None, None, "spool"), pairs, tmp_path / "masks")
    masks = [cv2.imread(str(kf.mask_path), cv2.IMREAD_GRAYSCALE) for kf in checked.input.keyframes]
    cut = [int(np.count_nonzero(m[roof:] == 0)) for m in masks]
    assert cut == [0] * n, (cut, checked.cut_share)

"""The stitcher's speed work keeps its results: features found on a JPEG decoded at a reduced size land where the
full decode puts them, and features and pairs computed in threads are those of one thread."""

from __future__ import annotations

import threading
from dataclasses import replace

import cv2
import numpy as np
import pytest

from companion.stitch import StitchConfig, Stitcher, load_input
from companion.stitch.config import STITCH_FEATURES
from companion.stitch.features import detect, load_image_and_mask, load_working_copy
from companion.stitch.inputs import KeyframeInput
from evaluation.stitch.synthetic import SyntheticWall, make_spool


@pytest.fixture(scope="module")
def spool(tmp_path_factory):
    d = tmp_path_factory.mktemp("spool")
    make_spool(d, SyntheticWall(length_m=6.0, height_m=3.0, seed=4), pose_noise_m=0.1, seed=4)
    return d


def test_features_of_the_reduced_decode_land_where_the_full_decode_puts_them(tmp_path):
    rng = np.random.default_rng(3)
    texture = cv2.resize(rng.integers(0, 255, (135, 240), np.uint8), (1920, 1080), interpolation=cv2.INTER_CUBIC)
    image = cv2.merge((texture, cv2.GaussianBlur(texture, (0, 0), 2), texture))
    mask = np.full((1080, 1920), 255, np.uint8)
    mask[:, 1500:] = 0  # background on the right: no feature may come from there
    cv2.imwrite(str(tmp_path / "k.jpg"), image, [cv2.IMWRITE_JPEG_QUALITY, 95])
    cv2.imwrite(str(tmp_path / "k.png"), mask)
    kf = KeyframeInput(0, tmp_path / "k.jpg", tmp_path / "k.png", None)

    grey, small_mask, size = load_working_copy(kf, 800)
    assert size == (1920, 1080) and grey.shape == (540, 960) and small_mask.shape == grey.shape  # decoded at 1/2
    features = replace(STITCH_FEATURES, long_side_px=800, max_features=1500)
    reduced = detect(grey, small_mask, features, full_size=size)
    full = detect(*load_image_and_mask(kf), features)
    assert reduced.image_size == full.image_size == (1920, 1080)
    assert len(reduced.keypoints) > 500 and reduced.keypoints[:, 0].max() < 1500
    # the same wall points: mutual nearest descriptors, compared in full-resolution pixels
    bf = cv2.BFMatcher(cv2.NORM_L2, crossCheck=True)
    m = bf.match(reduced.descriptors, full.descriptors)
    d = np.array([np.linalg.norm(reduced.keypoints[x.queryIdx] - full.keypoints[x.trainIdx]) for x in m])
    assert len(m) > 0.5 * len(reduced.keypoints)
    assert np.median(d) < 0.6  # full-resolution pixels (one working pixel is 2.4)

    # a PNG keyframe of odd size (no reduced decode in the codec): the full decode, still the right size
    cv2.imwrite(str(tmp_path / "odd.png"), image[:1079, :1919])
    cv2.imwrite(str(tmp_path / "odd_mask.png"), mask[:1079, :1919])
    grey, small_mask, size = load_working_copy(
        KeyframeInput(1, tmp_path / "odd.png", tmp_path / "odd_mask.png", None), 800
    )
    assert size == (1919, 1079) and small_mask.shape == grey.shape and grey.shape[0] in (539, 1079)


def test_threads_find_the_features_and_pairs_of_one_thread(spool, tmp_path):
    inp = load_input(spool)
    runs = []
    for workers in (1, 3):
        st = Stitcher(StitchConfig(cells=(8, 4), workers=workers), progress=False)
        found = st.features(inp, tmp_path / f"w{workers}")
        priors = st.priors(found)
        runs.append((found, st.pairs(found, priors, tmp_path / f"w{workers}")))
    (f1, p1), (f3, p3) = runs
    for a, b in zip(f1.features, f3.features, strict=True):
        assert np.array_equal(a.keypoints, b.keypoints) and np.array_equal(a.descriptors, b.descriptors)
    assert len(p1.results) == len(p3.results) > len(inp.keyframes)
    assert sum(r.accepted for r in p1.results) > len(inp.keyframes)
    for a, b in zip(p1.results, p3.results, strict=True):
        assert (a.i, a.j, a.accepted, a.inliers) == (b.i, b.j, b.accepted, b.inliers)
        if a.accepted:
            assert np.array_equal(a.H, b.H) and np.array_equal(a.pts_i, b.pts_i)


def test_pairs_matched_against_a_shared_keyframe_index_are_those_of_their_own_index(spool, tmp_path):
    """Every pair (i, j) queries keyframe j's index, built once (seeded by j): the same result as ``match_pair``
    building its own, whichever pairs share it and whichever thread built it."""
    from companion.stitch.pairs import PairSettings, keyframe_index, match_pair

    found = Stitcher(StitchConfig(cells=(8, 4)), progress=False).features(load_input(spool), tmp_path)
    f, settings = found.features, PairSettings()
    shared = keyframe_index(3, f[3], settings)
    for i in (0, 1, 2):
        alone = match_pair(i, 3, f[i], f[3], settings=settings)
        with_index = match_pair(i, 3, f[i], f[3], settings=settings, index_j=shared)
        assert alone.accepted and with_index.accepted and alone.inliers == with_index.inliers
        assert np.array_equal(alone.H, with_index.H) and np.array_equal(alone.pts_i, with_index.pts_i)
    built = []
    thread = threading.Thread(target=lambda: built.append(keyframe_index(3, f[3], settings)))
    thread.start()
    thread.join()
    from_thread, here = built[0].match(f[0].descriptors), shared.match(f[0].descriptors)
    assert len(here) > 100
    assert np.array_equal(from_thread.query, here.query) and np.array_equal(from_thread.indexed, here.indexed)


def test_a_mask_read_again_is_the_decoded_mask_and_a_rewritten_one_is_decoded_anew(tmp_path):
    """Masks decoded once are kept as bits: a second read gives the same 0/255 pixels without decoding the PNG;
    a mask written again (the wall check's, a resumed spool's) is read from the file, and a wrong size is still
    refused with its fix."""
    from companion.errors import CompanionError
    from companion.stitch.features import DecodedMasks, load_mask

    rng = np.random.default_rng(2)
    first = np.where(rng.random((37, 53)) < 0.6, 200, 30).astype(np.uint8)  # thresholded at 127 when read
    cv2.imwrite(str(tmp_path / "m.png"), first)
    kf = KeyframeInput(0, tmp_path / "k.jpg", tmp_path / "m.png", None)
    a = load_mask(kf, (53, 37))
    assert a.dtype == np.uint8 and set(np.unique(a)) == {0, 255} and np.array_equal(a > 0, first > 127)
    b = load_mask(kf, (53, 37))
    assert np.array_equal(a, b) and b is not a
    b[:] = 0  # a caller's changes stay its own
    assert np.array_equal(load_mask(kf, (53, 37)), a)
    cv2.imwrite(str(tmp_path / "next.png"), 255 - first)
    (tmp_path / "next.png").replace(tmp_path / "m.png")  # rewritten as the spool does: a new file in its place
    assert np.array_equal(load_mask(kf, (53, 37)), np.where(first > 127, 0, 255))
    with pytest.raises(CompanionError, match="full frame resolution"):
        load_mask(kf, (54, 37))
    small = DecodedMasks(max_bytes=600)  # bounded: 249 bytes a mask here, the least recently used dropped
    for k in range(4):
        small.put(("m", k), a)
    assert small.get(("m", 0), a.shape) is None and np.array_equal(small.get(("m", 3), a.shape), a)


def test_the_wall_check_in_threads_cuts_and_restores_what_one_thread_does(tmp_path):
    """Pair directions witnessed side by side (their votes summed under a lock, in whatever order the threads
    finish) give the masks of one thread, pixel for pixel: cut far scene and given-back roof alike."""
    from companion.stitch.wallcheck import check_wall
    from tests.test_stitch_wallcheck import _spool

    inp, pairs, _ = _spool(tmp_path, 6, roof_rows=40)
    runs = [check_wall(inp, pairs, tmp_path / f"masks{workers}", workers=workers) for workers in (1, 4)]
    one, many = ([cv2.imread(str(kf.mask_path), cv2.IMREAD_GRAYSCALE) for kf in r.input.keyframes] for r in runs)
    assert runs[0].cut_share == runs[1].cut_share and runs[0].restored_share == runs[1].restored_share
    assert sum(runs[0].cut_share.values()) > 0 and sum(runs[0].restored_share.values()) > 0  # both at work
    assert all(np.array_equal(a, b) for a, b in zip(one, many, strict=True))


def test_the_cache_decodes_ahead_the_same_keyframes_in_the_same_order():
    from concurrent.futures import ThreadPoolExecutor

    from companion.stitch.render import SourceCache
    from companion.stitch.render_plan import requests

    needs = {(x, 0): {x // 100, x // 100 + 1, (x // 100 + 5) % 9} for x in range(0, 900, 100)}
    schedule = requests(sorted(needs), needs)
    runs = []
    for ahead in (None, ThreadPoolExecutor(1)):
        loads = []

        def load(k, loads=loads):
            loads.append((k, threading.current_thread() is threading.main_thread()))
            mask = np.full((4, 4), 255, np.uint8)
            return np.full((4, 4, 3), k, np.uint8), mask

        cache = SourceCache(load, size=3, schedule=schedule, prefetch=ahead)
        got = [int(cache.get(k)[0][0, 0, 0]) for k in schedule]
        runs.append((loads, got, cache.decoded))
    (plain, got_plain, n_plain), (fetched, got_fetched, n_fetched) = runs
    assert got_plain == got_fetched == schedule
    assert [k for k, _ in plain] == [k for k, _ in fetched] and n_plain == n_fetched == len(plain) > 9
    assert all(on_main for _, on_main in plain)
    assert sum(not on_main for _, on_main in fetched) >= len(fetched) - 1  # all but the first, decoded ahead


def test_candidate_pairs_follow_the_path_and_its_revisits_not_every_keyframe_in_view():
    from companion.stitch.pairs import candidate_pairs

    # two vertical scan legs 2.1 m apart (62 % side overlap), down then up, a keyframe every 0.5 m (85 %)
    ups = [10.0 - 0.5 * k for k in range(21)]
    centres = [(0.0, u) for u in ups] + [(2.1, u) for u in reversed(ups)]
    priors = [np.array([[5.5, 0.0, x], [0.0, 5.5, y], [0.0, 0.0, 1.0]]) for x, y in centres]
    corners = np.array([[-0.5, -0.3], [0.5, -0.3], [0.5, 0.3], [-0.5, 0.3]])  # 5.5 x 3.3 m footprints
    pairs = candidate_pairs(len(priors), priors, corners, neighbours=2)
    assert {(i, i + 1) for i in range(41)} | {(i, i + 2) for i in range(40)} <= set(pairs)
    along = [(i, j) for i, j in pairs if j - i > 2 and (j < 21) == (i < 21)]
    assert along == []  # along a leg, only the sequence neighbours (was up to 6 more per keyframe)
    across = [(i, j) for i, j in pairs if i < 21 <= j]
    for i, j in across:  # the leg back passes the same place: matched where the footprints overlap
        assert abs(centres[i][1] - centres[j][1]) < 3.3
    assert {i for i, _ in across} == set(range(21)) and len(pairs) < 41 * 8
    # each keyframe tied to the leg back by its two nearest keyframes there (the demo matched 6: half its pairs)
    assert all((i, 41 - i) in pairs for i in range(18))  # (the last ones are sequence neighbours of the turn)
    assert max(sum(1 for a, _ in across if a == i) for i in range(21)) == 2
    # without telemetry: the path alone
    assert candidate_pairs(4, [None] * 4, corners) == [(0, 1), (0, 2), (1, 2), (1, 3), (2, 3)]


def test_block_bounds_in_two_passes_are_the_max_and_min_of_every_block():
    from companion.stitch.render_plan import _block_bounds

    rng = np.random.default_rng(5)
    for shape, block in (((2160, 3840), 8), ((361, 643), 7), ((50, 33), 5), ((16, 16), 1)):
        weight = rng.uniform(0, 500, shape).astype(np.float32)
        hi, lo = _block_bounds(weight, block)
        ph, pw = -(-shape[0] // block) * block, -(-shape[1] // block) * block
        padded = np.zeros((ph, pw), np.float32)  # edge blocks padded with 0, as the plan's bound needs
        padded[: shape[0], : shape[1]] = weight
        blocks = padded.reshape(ph // block, block, pw // block, block)
        assert np.array_equal(hi, blocks.max(axis=(1, 3))) and np.array_equal(lo, blocks.min(axis=(1, 3)))


def test_alignment_jacobian_is_the_derivative_of_the_transfer():
    """The alignment's analytic Jacobian (it replaced 16 numerical transfers per pair direction) is the
    derivative of the transfer it linearises, for both keyframes' parameters."""
    from companion.stitch.align import _Problem, _to_params

    rng = np.random.default_rng(7)
    problem = _Problem(col={0: 0, 1: 1}, obs=[], anchors=[], sigma_match=0.004)
    for _ in range(5):
        Gs, Gt = (np.eye(3) + rng.normal(0, 0.05, (3, 3)) for _ in range(2))
        ps, pt = _to_params(Gs), _to_params(Gt)
        xs = rng.uniform(-0.5, 0.5, (40, 2))
        u, J = problem._pair_terms(ps, pt, xs, True)
        assert np.allclose(u, problem._pair_terms(ps, pt, xs, False)[0])
        for q in range(16):
            e = 1e-6
            plus, minus = np.concatenate((ps, pt)), np.concatenate((ps, pt))
            plus[q] += e
            minus[q] -= e
            numeric = (problem._pair_terms(plus[:8], plus[8:], xs, False)[0]
                       - problem._pair_terms(minus[:8], minus[8:], xs, False)[0]) / (2 * e)
            assert np.allclose(J[:, :, q], numeric, rtol=1e-5, atol=1e-4 * np.abs(numeric).max())


@pytest.mark.parametrize("size", [(700, 450), (90, 60)])
def test_the_pyramid_cut_in_blocks_is_the_pyramid_halved_level_by_level_from_disk(tmp_path, monkeypatch, size):
    """Levels made in memory from each 4 x 4 tile block are the tiles that halving the level above, read back
    from its PNGs, gives: every tile of every level, at the map's ragged right and bottom edges, in blank areas
    and along the coverage's edge (the alpha-weighted halving)."""
    from companion.viewer import tiles as pyramid

    w, h = size
    rng = np.random.default_rng(8)
    bgra = np.dstack((rng.integers(0, 255, (h, w, 3), dtype=np.uint8), np.full((h, w), 255, np.uint8)))
    bgra[: h // 3, : w // 2] = 0  # not covered
    bgra[h // 2 :, w // 3 : w // 3 + 7, 3] = 128  # a partly covered band
    written = {}
    for levels in (0, pyramid.BLOCK_LEVELS):  # 0: every level below full resolution halved from disk
        monkeypatch.setattr(pyramid, "BLOCK_LEVELS", levels)
        out = tmp_path / f"levels{levels}"
        info = pyramid.write_pyramid(pyramid.MapReader(w, h, image=bgra), out, url_prefix="", tile_px=32)
        written[levels] = (info, {p.relative_to(out): cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
                                  for p in sorted(out.rglob("*.png"))})
    (info_disk, disk), (info_blocks, blocks) = written[0], written[pyramid.BLOCK_LEVELS]
    assert info_disk == info_blocks and info_blocks.tiles_written == len(blocks) == len(disk)
    assert set(disk) == set(blocks) and all(np.array_equal(disk[k], blocks[k]) for k in disk)
    assert info_blocks.max_zoom == (5 if w == 700 else 2)


def test_the_pairs_stage_registers_the_pairs_opencvs_per_pair_flann_matcher_registers(spool, tmp_path, monkeypatch):
    """The stitcher matches through companion.matching's index with its named settings (STITCH_MATCHING): every
    candidate pair of a small spool gets the matches, inliers and model that OpenCV's FlannBasedMatcher finds
    over keyframe j's descriptors with the same trees, checks, ratio and seed (the path before the index)."""
    from companion.matching import Matches
    from companion.stitch import pairs as pairs_module

    class OpenCVFlannMatcher:
        def __init__(self, j, fj, settings):
            self.descriptors, self.matching, self.seed = fj.descriptors, settings.matching, 7919 * j + 17

        def match(self, query):
            s = self.matching
            cv2.setRNGSeed(self.seed)
            m = cv2.FlannBasedMatcher({"algorithm": 1, "trees": s.trees}, {"checks": s.checks})
            knn = m.knnMatch(query, self.descriptors, k=2)
            good = sorted((a.queryIdx, a.trainIdx) for a, *b in knn if b and a.distance < s.ratio * b[0].distance)
            return Matches(np.array([g[0] for g in good], np.intp), np.array([g[1] for g in good], np.intp))

    st = Stitcher(StitchConfig(cells=(8, 4)), progress=False)
    found = st.features(load_input(spool), tmp_path / "index")
    priors = st.priors(found)
    ours = st.pairs(found, priors, tmp_path / "index")
    monkeypatch.setattr(pairs_module, "keyframe_index", OpenCVFlannMatcher)
    theirs = st.pairs(found, priors, tmp_path / "opencv")
    assert len(ours.results) == len(theirs.results) > len(found.features)
    assert sum(r.accepted for r in ours.results) > len(found.features)
    for a, b in zip(ours.results, theirs.results, strict=True):
        assert (a.i, a.j, a.accepted, a.matches, a.inliers) == (b.i, b.j, b.accepted, b.matches, b.inliers)
        if a.accepted:
            assert np.array_equal(a.H, b.H)

"""Tracked selection (companion.onboard.tracked) on views with known overlap: the same keyframes as the gate that
measures every frame (the paper's rule on measured R), with about two measurements per keyframe; dropped frames
cost frames, never a keyframe below Rth; a wall the tracker cannot follow is measured frame by frame."""

import numpy as np
import pytest

from companion.errors import CompanionError
from companion.keyframes.gate import KeyframeGate
from companion.onboard.tracked import MeasureSchedule, TrackedSelection
from evaluation.keyframes.synthetic import masked_frame, render, sweep, textured_wall, true_overlap

W, H = 480, 270


@pytest.fixture(scope="module")
def scan():
    texture = textured_wall(2400, 600, seed=3)
    views = sweep(texture, 49, 7.0, W, H)  # 7 px per frame: 13.7 frames from 100 % to 80 % overlap
    return views, [masked_frame(i, render(texture, v)) for i, v in enumerate(views)]


def _select(frames, keep=lambda i: True):
    gate = KeyframeGate()
    by_tagged = {id(f.tagged): f for f in frames}
    masked_calls = []

    def mask(tagged):
        masked_calls.append(tagged.frame.index)
        return by_tagged[id(tagged)]

    selection = TrackedSelection(gate, mask)
    keyframes = []
    for f in frames:
        if keep(f.tagged.frame.index):
            keyframes += selection.offer(f.tagged)
    keyframes += selection.finish() + gate.flush()
    return [k.index for k in keyframes], selection, masked_calls


def test_same_keyframes_as_measuring_every_frame_with_few_measurements(scan):
    views, frames = scan
    plain = [k.index for k in KeyframeGate().run(frames)]
    tracked, selection, masked_calls = _select(frames)
    assert tracked == plain
    assert plain[-1] == 48  # the wall's last view ends the map
    counts = selection.counts
    assert counts.tracked == 48 and counts.lost == 0
    assert counts.measured == len(masked_calls) <= 2 * len(plain) + 2  # against 49 for the plain gate
    for a, b in zip(tracked, tracked[1:], strict=False):  # the last frame still >= 80 %: the next one is below
        assert true_overlap(views[a], views[b]) >= 0.80 - 0.005
        if b != 48:
            assert true_overlap(views[a], views[b + 1]) < 0.80 + 0.005


def test_dropped_frames_cost_frames_never_a_keyframe_below_rth(scan):
    views, frames = scan
    tracked, _, _ = _select(frames, keep=lambda i: i % 3 == 0)  # two of three frames dropped under load
    assert all(i % 3 == 0 for i in tracked)
    for a, b in zip(tracked, tracked[1:], strict=False):
        assert true_overlap(views[a], views[b]) >= 0.80 - 0.005
    assert len(tracked) <= 6


def test_a_track_that_jumps_across_the_band_still_keeps_a_frame_above_rth(scan):
    views, frames = scan
    tracked, _, _ = _select(frames, keep=lambda i: i % 8 == 0)  # 56 px = 11.7 points of overlap per frame kept
    assert tracked == [0, 8, 16, 24, 32, 40, 48]  # each the last kept frame still >= 80 %
    for a, b in zip(tracked, tracked[1:], strict=False):
        assert true_overlap(views[a], views[b]) >= 0.80


def test_untrackable_frames_are_measured_one_by_one():
    blank = [masked_frame(i, np.full((H, W, 3), 120, np.uint8)) for i in range(6)]
    _, selection, masked_calls = _select(blank)
    assert selection.counts.lost == 5
    assert masked_calls == [0, 1, 2, 3, 4, 5]  # no texture to track: every frame goes to the gate, as before


def test_schedule_rejects_bands_that_cannot_work():
    with pytest.raises(CompanionError, match="hold_above"):
        MeasureSchedule(hold_above=0.0)
    with pytest.raises(CompanionError, match="max_held"):
        MeasureSchedule(max_held=1)


@pytest.fixture(scope="module")
def posed_scan():
    """A 30 fps pass at 1 m/s, 4 m from a textured wall, with exact telemetry poses: 26 frames per keyframe."""
    from companion.keyframes.motion import WallMotionPredictor
    from evaluation.keyframes.synthetic import WallCamera, WallScene

    scene = WallScene(textured_wall(3000, 1000, seed=4), textured_wall(800, 300, seed=6), 12.0, 6.0,
                      width_px=W, height_px=H)
    cams = [WallCamera(3.0 + i / 30.0, 4.0, 3.0) for i in range(150)]
    frames = [scene.masked_frame(i, c, t_s=i / 30.0, pose=scene.pose(c, i / 30.0)) for i, c in enumerate(cams)]
    return scene, cams, frames, WallMotionPredictor(scene.frame, scene.hfov_deg, standoff_m=4.0)


def _select_posed(frames, predictor, schedule):
    gate = KeyframeGate(predictor=predictor)
    by_index = {f.index: f for f in frames}
    selection = TrackedSelection(gate, lambda t: by_index[t.frame.index], predictor, schedule)
    keyframes, skipped = [], []
    for f in frames:
        if selection.skips(f.tagged):
            skipped.append(f.index)
            continue
        keyframes += selection.offer(f.tagged)
    keyframes += selection.finish() + gate.flush()
    return [(k.index, round(k.overlap_to_previous or 100.0, 6)) for k in keyframes], skipped, selection.counts


def test_frames_far_above_the_band_are_skipped_without_moving_a_keyframe(posed_scan):
    """Issue 17: a frame the telemetry and the tracker put more than skip_above points above the hold band cannot
    be the keyframe nor its neighbour, so only every skip_stride-th such frame is decoded and tracked."""
    scene, cams, frames, predictor = posed_scan
    every, none_skipped, _ = _select_posed(frames, predictor, MeasureSchedule(skip_above=None))
    kept, skipped, counts = _select_posed(frames, predictor, MeasureSchedule())
    assert none_skipped == []
    assert [k for k, _ in kept] == [k for k, _ in every]  # the same keyframes
    # at the same measured R (RANSAC's random samples depend on OpenCV's generator, which the calls before move)
    assert all(abs(a - b) < 0.05 for (_, a), (_, b) in zip(kept, every, strict=True))
    assert len(every) >= 5 and len(skipped) >= 0.15 * len(frames) and counts.skipped_far == len(skipped)
    keys = [k for k, _ in kept]
    schedule = MeasureSchedule()
    floor = 80.0 + schedule.hold_above + schedule.skip_above
    for i in skipped:  # each skipped frame truly far above Rth from the keyframe before it
        key = max(k for k in keys if k < i)
        assert 100.0 * scene.true_overlap(cams[key], cams[i]) > floor - 1.0
    runs = np.split(np.array(skipped), np.where(np.diff(skipped) != 1)[0] + 1)
    assert max(len(r) for r in runs) <= MeasureSchedule().skip_stride - 1  # every skip_stride-th frame still tracked
    with pytest.raises(CompanionError, match="skip_stride"):
        MeasureSchedule(skip_stride=0)

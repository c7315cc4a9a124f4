"""The wall tracker against views with known motion (evaluation.keyframes.synthetic): its Eq. 2 overlap with the
anchor follows the true overlap frame by frame, survives dropped frames with a telemetry prior, re-anchors on a
tracked frame and takes a measurement's correction."""

import numpy as np
import pytest

from companion.errors import CompanionError
from companion.keyframes.motion import WallMotion
from companion.keyframes.overlap import eq2_overlap
from companion.keyframes.tracker import TrackerConfig, TrackSource, WallTracker
from evaluation.keyframes.synthetic import render, sweep, textured_wall, true_overlap

W, H = 640, 360


@pytest.fixture(scope="module")
def texture():
    return textured_wall(2400, 800, seed=3)


def _shift_prior(dx: float, dy: float = 0.0) -> WallMotion:
    """A telemetry prior that says the wall moved by (dx, dy) px (image content shift)."""
    H_ = np.array([[1.0, 0.0, dx], [0.0, 1.0, dy], [0.0, 0.0, 1.0]])
    return WallMotion(H_, eq2_overlap(dx, dy, W, H), dx, dy, 0.0)


def test_overlap_follows_truth_every_frame(texture):
    views = sweep(texture, 40, 6.0, W, H)  # 6 px per frame: 1.9 % of the width
    tracker = WallTracker()
    tracker.anchor(0, render(texture, views[0]))
    errors = []
    for i, view in enumerate(views[1:], start=1):
        track = tracker.track(i, render(texture, view))
        assert track.source == TrackSource.FLOW and track.anchor_index == 0
        errors.append(abs(track.overlap_percent - 100.0 * true_overlap(views[0], view)))
        # the camera moves right: the wall's content moves left in the image
        assert track.dx == pytest.approx(-6.0 * i, abs=0.02 * 6.0 * i + 1.0)
    assert max(errors) < 0.8, errors  # percentage points, after 39 frames of summed flow


def test_dropped_frames_are_bridged_by_the_telemetry_prior(texture):
    views = sweep(texture, 41, 8.0, W, H)
    kept = [0, 20, 40]  # 19 frames dropped twice: 160 px jumps, beyond the flow's reach without a guess
    for prior in (True, False):
        tracker = WallTracker()
        tracker.anchor(0, render(texture, views[0]))
        for a, b in zip(kept, kept[1:], strict=False):
            step = _shift_prior(-8.0 * (b - a)) if prior else None
            track = tracker.track(b, render(texture, views[b]), step_prior=step)
        if prior:
            assert track.source == TrackSource.FLOW
            assert track.overlap_percent == pytest.approx(100.0 * true_overlap(views[0], views[40]), abs=0.5)
        else:
            assert track.source == TrackSource.LOST


def test_reanchor_and_correction_shift_later_frames(texture):
    views = sweep(texture, 12, 6.0, W, H)
    tracker = WallTracker()
    tracker.anchor(0, render(texture, views[0]))
    for i in range(1, 12):
        tracker.track(i, render(texture, views[i]))
    assert tracker.reanchor(5)
    assert tracker.anchor_index == 5
    assert tracker.predicted(11) == pytest.approx(100.0 * true_overlap(views[5], views[11]), abs=0.5)
    assert tracker.predicted(3) is None  # before the new anchor: forgotten
    before = tracker.predicted(11)
    tracker.correct(8, -30.0, 0.0)  # a measurement says frame 8 is 30 px from the anchor, the flow said ~18
    assert tracker.predicted(8) == pytest.approx(100.0 * (W - 30.0) / W)
    assert tracker.predicted(11) < before - 1.0
    assert not tracker.reanchor(99)


def test_textureless_wall_falls_back_to_telemetry_then_lost():
    blank = np.full((H, W, 3), 128, np.uint8)
    tracker = WallTracker()
    tracker.anchor(0, blank)
    track = tracker.track(1, blank, anchor_prior=_shift_prior(-64.0))
    assert track.source == TrackSource.TELEMETRY and track.overlap_percent == pytest.approx(90.0)
    lost = tracker.track(2, blank)
    assert lost.source == TrackSource.LOST and lost.overlap_percent is None and not lost.known


def test_points_are_picked_inside_the_mask_only(texture):
    image = render(texture, sweep(texture, 1, 1.0, W, H)[0])
    mask = np.zeros((H, W), np.uint8)
    mask[:, : W // 2] = 255
    tracker = WallTracker()
    tracker.anchor(0, image, mask)
    pts = tracker._points.reshape(-1, 2) / tracker._scale
    assert len(pts) >= 12 and pts[:, 0].max() < W // 2 + 2


def test_bad_config_and_missing_anchor_name_the_fix():
    with pytest.raises(CompanionError, match="work_width_px"):
        TrackerConfig(work_width_px=10)
    with pytest.raises(CompanionError, match="anchor"):
        WallTracker().track(0, np.zeros((H, W, 3), np.uint8))


def test_flow_that_contradicts_the_telemetry_gives_way_to_it(texture):
    """A static texture (a far background) does not move, but the telemetry says the wall moved a fifth of the
    frame: the flow is not following the wall, so the telemetry's overlap stands in."""
    image = render(texture, sweep(texture, 1, 1.0, W, H)[0])
    tracker = WallTracker()
    tracker.anchor(0, image)
    agree = tracker.track(1, image, anchor_prior=_shift_prior(-3.2))  # within the tolerance: the flow decides
    assert agree.source == TrackSource.FLOW and agree.overlap_percent == pytest.approx(100.0, abs=0.1)
    track = tracker.track(2, image, anchor_prior=_shift_prior(-128.0))
    assert track.source == TrackSource.TELEMETRY and track.overlap_percent == pytest.approx(80.0)

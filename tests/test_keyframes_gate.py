"""Streaming gate on synthetic passes with known overlap: paper's selection rule, edge cases, bounded memory."""

from __future__ import annotations

import gc
import weakref

import numpy as np
import pytest

from companion.errors import CompanionError
from companion.keyframes import FeatureConfig, GateConfig, GateEventKind, KeyframeGate, StepRole
from companion.records import GateReason
from evaluation.keyframes.synthetic import View, masked_frame, render, sweep, textured_wall, true_overlap

W, H = 480, 360


@pytest.fixture(scope="module")
def tex():
    return textured_wall(3200, 900, seed=2)


def _gate(**kw) -> KeyframeGate:
    return KeyframeGate(GateConfig(features=FeatureConfig(long_side_px=360, max_features=1500), **kw))


def _run(gate, tex, views, blur=None):
    blur = blur or {}
    kfs = []
    for i, v in enumerate(views):
        kfs += gate.push(masked_frame(i, render(tex, v, blur_sigma=blur.get(i, 0.0))))
    kfs += gate.flush()
    return kfs


def _indices(kfs):
    return [k.index for k in kfs]


def _truth_rule(views, rth):
    """Paper's rule on true overlap: from keyframe p, the next is the last q with overlap(p, q) >= rth."""
    keys, p = [0], 0
    for q in range(1, len(views)):
        if true_overlap(views[p], views[q]) < rth:
            p = q - 1 if q - 1 > p else q
            keys.append(p)
    if keys[-1] != len(views) - 1:
        keys.append(len(views) - 1)
    return keys


def test_paper_example_keeps_i4_and_rejects_i5(tex):
    """R(I1,I4) = 82.9 %, R(I1,I5) = 77.2 % -> I4 is the next keyframe (0-based index 3)."""
    shifts = [0.0, 0.06, 0.12, 0.171, 0.228, 0.26]  # share of the width moved since I1
    views = [View(400 + s * W, 450, W, H) for s in shifts]
    kfs = _run(_gate(), tex, views)
    assert _indices(kfs)[:2] == [0, 3]
    assert kfs[1].overlap_to_previous == pytest.approx(82.9, abs=0.5)
    assert kfs[0].overlap_to_previous is None and kfs[0].decision.reason == GateReason.FIRST


@pytest.mark.parametrize("step", [14.0, 23.0, 31.0])
def test_sweep_matches_truth_rule_and_keeps_threshold(tex, step):
    views = sweep(tex, 36, step, W, H, start_x=300, jitter_px=1.0, seed=3)
    kfs = _run(_gate(), tex, views)
    got = _indices(kfs)
    assert got == _truth_rule(views, 0.80)
    for a, b in zip(got, got[1:], strict=False):
        assert true_overlap(views[a], views[b]) >= 0.80 - 0.03
    for k in kfs[1:]:
        assert k.overlap_to_previous >= 80.0
        assert not k.gap_before


def test_hovering_makes_no_new_keyframes_and_holds_two_frames(tex):
    views = sweep(tex, 25, 0.0, W, H, start_x=900, jitter_px=2.0, seed=4)
    gate = _gate()
    for i, v in enumerate(views):
        assert gate.push(masked_frame(i, render(tex, v))) == [] or i == 0
        assert gate.held_frames() <= 2
    assert _indices(gate.flush()) == [24]
    assert gate.keyframes_out == 2


def test_memory_is_bounded_to_keyframe_and_candidate(tex):
    # gc.freeze: the collections below walk only what this test made, not the whole session's heap (in the full
    # suite a collection per frame cost 0.5 s, 15 s for the 30 frames); frozen objects all predate the frames, so
    # nothing frozen can be the cycle that keeps a frame alive
    gc.collect()
    gc.freeze()
    try:
        gate = _gate()
        alive = []
        for i, v in enumerate(sweep(tex, 30, 20.0, W, H, start_x=300)):
            mf = masked_frame(i, render(tex, v))
            alive.append(weakref.ref(mf))
            gate.push(mf)
            del mf  # the caller forgets the frame; returned keyframes are dropped too
            gc.collect()
            assert sum(r() is not None for r in alive) <= 2
            assert gate.held_frames() <= 2
    finally:
        gc.unfreeze()


def test_tracking_lost_starts_new_segment_and_flags_gap(tex):
    views = sweep(tex, 8, 20.0, W, H, start_x=300) + sweep(tex, 6, 20.0, W, H, start_x=2500, y=300)
    gate = _gate()
    kfs = _run(gate, tex, views)
    got = _indices(kfs)
    assert 7 in got  # the last frame of the first segment is kept, not lost
    gap = [k for k in kfs if k.gap_before]
    assert _indices(gap) == [8] and gap[0].overlap_to_previous is None
    assert gap[0].decision.segment == 1
    kinds = [e.kind for e in gate.pop_events()]
    assert GateEventKind.GAP in kinds


def test_black_frame_is_skipped_without_gap(tex):
    views = sweep(tex, 12, 20.0, W, H, start_x=300)
    gate = _gate()
    kfs = []
    for i, v in enumerate(views):
        img = np.zeros((H, W, 3), np.uint8) if i == 5 else render(tex, v)
        kfs += gate.push(masked_frame(i, img))
        if i == 5:
            assert gate.last_step.role == StepRole.UNUSABLE
    kfs += gate.flush()
    assert 5 not in _indices(kfs)
    assert not any(k.gap_before for k in kfs)
    assert any(e.kind == GateEventKind.UNUSABLE_FRAME and e.frame_index == 5 for e in gate.pop_events())


def test_blurred_candidate_is_swapped_for_sharper_neighbour(tex):
    views = sweep(tex, 12, 20.0, W, H, start_x=300)  # 480 px wide: frames 1..4 >= 80 %, frame 5 below
    assert true_overlap(views[0], views[4]) >= 0.8 > true_overlap(views[0], views[5])
    kfs = _run(_gate(), tex, views, blur={4: 3.0})
    got = _indices(kfs)
    assert got[1] == 3  # frame 4 (blurred) passed over for frame 3, still above Rth
    assert kfs[1].overlap_to_previous >= 80.0
    sharp = _run(_gate(), tex, views)
    assert _indices(sharp)[1] == 4


def test_sudden_jump_raises_overlap_warning_and_low_overlap_keyframe(tex):
    xs = [300, 315, 330, 470, 485]  # 140 px jump at frame 3: R falls from ~94 % to ~65 %
    views = [View(x, 450, W, H) for x in xs]
    gate = _gate()
    warned = []
    kfs = []
    for i, v in enumerate(views):
        kfs += gate.push(masked_frame(i, render(tex, v)))
        warned.append(gate.last_step.overlap_warning)
    kfs += gate.flush()
    assert warned == [False, False, False, True, False]
    events = gate.pop_events()
    assert any(e.kind == GateEventKind.OVERLAP_WARNING and "slow down" in e.message for e in events)
    low = [k for k in kfs if k.decision.low_overlap]
    assert _indices(low) == [3]
    assert 2 in _indices(kfs)  # the last frame >= Rth before the jump is kept


def test_direction_reversal_keeps_coverage(tex):
    xs = list(np.arange(300, 700, 25)) + list(np.arange(700, 200, -25))
    views = [View(float(x), 450, W, H) for x in xs]
    kfs = _run(_gate(), tex, views)
    got = _indices(kfs)
    for a, b in zip(got, got[1:], strict=False):
        assert true_overlap(views[a], views[b]) >= 0.80 - 0.03
    assert got[-1] == len(views) - 1


def test_vertical_strips_with_turn(tex):
    """Up a strip, a sideways step at the top, down the next strip (the vertical pattern)."""
    ups = [View(500, y, W, H) for y in np.arange(650, 250, -25)]
    side = [View(x, 250, W, H) for x in np.arange(525, 800, 25)]
    downs = [View(800, y, W, H) for y in np.arange(275, 650, 25)]
    views = ups + side + downs
    kfs = _run(_gate(), tex, views)
    got = _indices(kfs)
    assert got == _truth_rule(views, 0.80)


def test_config_errors_name_the_fix():
    with pytest.raises(CompanionError, match="0.80"):
        GateConfig(rth=80)
    with pytest.raises(CompanionError, match="MaskedFrame"):
        KeyframeGate().push(np.zeros((10, 10, 3), np.uint8))


def test_rth_from_mission():
    class M:
        overlap = 0.7

    assert GateConfig.for_mission(M()).rth == 0.7
    assert GateConfig.for_mission(object()).rth == 0.80


def test_one_feature_extraction_per_frame(tex):
    """Keyframe and candidate features are cached: a promotion re-matches but never re-extracts."""
    gate = _gate()
    calls = []
    real = gate._extractor.extract
    gate._extractor.extract = lambda image, mask=None: calls.append(1) or real(image, mask)
    views = sweep(tex, 14, 30.0, W, H, start_x=300)
    kfs = _run(gate, tex, views)
    assert len(kfs) >= 3  # promotions happened
    assert len(calls) == len(views)


def _with_mask(mf, mask):
    from companion.records import MaskedFrame

    return MaskedFrame(mf.tagged, mask)


def _block_mask(x0, y0, x1, y1):
    mask = np.zeros((H, W), np.uint8)
    mask[y0:y1, x0:x1] = 255
    return mask


def test_a_last_candidate_whose_roi_holds_next_to_no_wall_is_not_kept(tex):
    """Issue 15, plain wall: at the end of the stream the camera has left the wall and the mask keeps a sliver
    (1.5 % of the frame there). The image still matches it to the keyframe, so it is the candidate; the flush used
    to make it the last keyframe, which the stitcher cannot place by images. Now it is dropped and said."""
    views = [View(400 + 12 * i, 450, W, H) for i in range(4)]  # R stays >= 90 %: every frame a candidate
    frames = [masked_frame(i, render(tex, v)) for i, v in enumerate(views)]
    sliver = _block_mask(0, 150, 80, 210)  # 80 x 60 px: 2.8 % of the frame, textured enough to match
    gate = _gate()
    kfs = []
    for i, mf in enumerate(frames):
        kfs += gate.push(_with_mask(mf, sliver) if i == 3 else mf)
    assert gate.candidate_index == 3 and gate.last_step.role == StepRole.CANDIDATE  # the image did match it
    kfs += gate.flush()
    assert _indices(kfs) == [0]
    assert gate.last_dropped == 1 and gate.keyframe_index is None
    dropped = [e for e in gate.pop_events() if e.kind == GateEventKind.LAST_DROPPED]
    assert len(dropped) == 1 and dropped[0].frame_index == 3 and "next to no wall" in dropped[0].message

    control = _gate()  # the same stream with the frame's whole ROI: the last view is kept as before
    assert _indices(_run(control, tex, views)) == [0, 3] and control.last_dropped == 0


def test_a_last_candidate_that_adds_nothing_of_the_wall_is_not_kept(tex):
    """Moving right, the last frame's ROI is only the part the keyframe already showed (the wall ended at its
    left): the pair adds nothing of the wall, so no last keyframe. With its ROI reaching the new strip, it stays."""
    views = [View(400 + 15 * i, 450, W, H) for i in range(5)]
    seen = _block_mask(0, 0, W - 80, H)  # the 60 px it moved are outside its ROI
    for mask, kept in ((seen, [0]), (None, [0, 4])):
        gate = _gate()
        kfs = []
        for i, v in enumerate(views):
            mf = masked_frame(i, render(tex, v))
            kfs += gate.push(_with_mask(mf, mask) if i == 4 and mask is not None else mf)
        kfs += gate.flush()
        assert _indices(kfs) == kept
        events = [e for e in gate.pop_events() if e.kind == GateEventKind.LAST_DROPPED]
        assert len(events) == (mask is not None)
        assert all("nothing of the wall" in e.message for e in events)


def test_a_segment_ending_on_an_unusable_frame_is_a_gap_only_when_that_frame_shows_wall(tex):
    """The judged 1280 px demo flagged "1 gap": the scan's last frame, leaving the wall, held a sliver of ROI with
    too few features to measure. No wall was lost there. A last frame that shows wall and cannot be measured
    (a black frame over the wall) is still a gap."""
    views = [View(400 + 12 * i, 450, W, H) for i in range(2)]  # the keyframe, then the last frame: no candidate
    sliver = _block_mask(0, 150, 30, 180)  # 30 x 30 px of a plain corner: < 3 % of the frame, too few features
    for last, gap in ((sliver, False), (None, True)):
        gate = _gate()
        kfs = []
        for i, v in enumerate(views):
            mf = masked_frame(i, render(tex, v))
            if i == 1:
                mf = _with_mask(mf, sliver) if last is not None else masked_frame(i, np.zeros((H, W, 3), np.uint8))
            kfs += gate.push(mf)
        assert gate.last_step.role == StepRole.UNUSABLE
        kfs += gate.end_segment()
        events = gate.pop_events()
        gaps = [e for e in events if e.kind == GateEventKind.GAP]
        assert len(gaps) == int(gap), [e.message for e in events]
        if not gap:
            said = [e.message for e in events if e.kind == GateEventKind.BARE_END]
            assert len(said) == 1 and "no gap" in said[0]


def test_a_segment_ended_by_leaving_the_scan_restarts_fresh(tex):
    """The chain ends a segment where the scan is left; the next frame opens a new one: not a pair below target,
    not a lost track, and the old segment's last view is kept."""
    first = [View(300 + 20 * i, 450, W, H) for i in range(6)]
    later = [View(2200 + 20 * i, 300, W, H) for i in range(3)]  # elsewhere on the wall: 0 % with the old ones
    gate = _gate()
    kfs = []
    for i, v in enumerate(first):
        kfs += gate.push(masked_frame(i, render(tex, v)))
    kfs += gate.end_segment()
    assert _indices(kfs)[-1] == 5 and kfs[-1].decision.reason == GateReason.END_OF_SEGMENT
    for i, v in enumerate(later, start=len(first)):
        kfs += gate.push(masked_frame(i, render(tex, v)))
    kfs += gate.flush()
    opened = next(k for k in kfs if k.index == len(first))
    assert opened.decision.reason == GateReason.NEW_SEGMENT and opened.gap_before and opened.decision.segment == 1
    assert opened.overlap_to_previous is None and opened.decision.previous_index is None
    assert not any(k.decision.low_overlap for k in kfs)
    kinds = [e.kind for e in gate.pop_events()]
    assert GateEventKind.SEGMENT in kinds
    assert GateEventKind.LOW_OVERLAP not in kinds and GateEventKind.GAP not in kinds


def test_last_keyframe_thresholds_are_checked():
    with pytest.raises(CompanionError, match="shares of the frame"):
        GateConfig(min_last_roi=3.0)

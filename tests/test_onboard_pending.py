"""The chain's frames awaiting a decision have one owner (``PendingFrames``) and its figures one writer
(``ChainRecorder``), apart from the decisions (issue 30 item 5)."""

from __future__ import annotations

import ast
import logging
import time
from pathlib import Path

import numpy as np
import pytest

from companion.keyframes.gate import GateEvent, GateEventKind, KeyframeGate
from companion.onboard.chain_stats import ChainRecorder, FrameDone, FrameFate, FrameStart
from companion.onboard.pending import LaterVerdict, PendingFrames
from companion.onboard.working import WorkingCopy
from companion.records import Frame, GateDecision, Keyframe, TaggedFrame

ROOT = Path(__file__).resolve().parents[1]


class _Hold:
    def __init__(self, *indices: int):
        self.indices = list(indices)

    def held_indices(self) -> list[int]:
        return list(self.indices)


def _keep(pending: PendingFrames, index: int) -> Frame:
    """A 1280 px frame kept at full resolution, decided on its 640 px copy."""
    full = Frame(index, index / 10.0, np.zeros((720, 1280, 3), np.uint8))
    work = WorkingCopy(640).of(full)
    pending.keep(full, work)
    return work


def test_full_resolution_copies_go_once_no_hold_keeps_a_frame_as_old():
    tracked, gate = _Hold(3, 4), _Hold(5)
    pending = PendingFrames((tracked, gate))
    for i in range(7):
        _keep(pending, i)
    assert pending.oldest_undecided(6) == 3
    pending.release_decided(6)
    assert pending.full_resolution_held == 4  # 3, 4, 5 held; 6 is the newest
    tracked.indices, gate.indices = [], []
    assert pending.oldest_undecided(6) == 6
    pending.release_decided(6)
    assert pending.full_resolution_held == 1
    pending.release_decided(None)  # the stream ended: nothing is undecided
    assert pending.full_resolution_held == 0


def test_the_gate_holds_its_candidate_only():
    gate = KeyframeGate()
    assert gate.held_indices() == []
    assert PendingFrames((gate,)).oldest_undecided(9) == 9


def test_without_a_later_reference_the_keyframes_go_as_decided_and_restored_at_full_resolution():
    pending = PendingFrames(())
    work = _keep(pending, 2)
    kf = Keyframe(work, None, np.full((360, 640), 255, np.uint8), GateDecision(overlap_to_previous=80.0))
    order = pending.spool_order([kf], TaggedFrame(work, None))
    assert order.keyframes == (kf,) and order.judged_later == ()
    assert pending.restore(kf).image.shape == (720, 1280, 3)


def test_the_frame_skipped_last_is_offered_once_and_forgotten_once_a_later_one_is_offered():
    pending = PendingFrames(())
    frame = Frame(4, 0.4, np.zeros((8, 8, 3), np.uint8))
    pending.skip(frame, TaggedFrame(frame, None))
    taken = pending.take_skipped()
    assert taken is not None and taken.frame is frame and pending.take_skipped() is None
    pending.skip(frame, TaggedFrame(frame, None))
    pending.forget_skipped()
    assert pending.take_skipped() is None


# fate -> (processed, before_telemetry, off_scan, undecodable, stale counted, busy time, cpu time)
FATES = {
    FrameFate.BEFORE_TELEMETRY: (1, 1, 0, 0, 0, False, False),
    FrameFate.OFF_SCAN: (1, 0, 1, 0, 1, True, True),
    FrameFate.SKIPPED_FAR: (1, 0, 0, 0, 0, True, True),
    FrameFate.UNDECODABLE: (0, 0, 0, 1, 0, False, True),
    FrameFate.OFFERED: (1, 0, 0, 0, 1, True, True),
}


@pytest.mark.parametrize("fate", list(FATES))
def test_each_frame_fate_joins_the_counters_the_cull_report_has_always_had(fate):
    record = ChainRecorder(lambda msg: None, logging.getLogger(__name__))
    started = FrameStart(time.monotonic() - 1.0, time.thread_time() - 0.5)
    record.frame(FrameDone(fate, True, started))
    st = record.stats
    processed, before, off, undecodable, stale, busy, cpu = FATES[fate]
    assert (st.frames_processed, st.before_telemetry, st.off_scan, st.undecodable, st.stale_pose) == \
        (processed, before, off, undecodable, stale)
    assert (st.busy_s >= 1.0) == busy and (st.busy_s == 0.0) != busy
    assert (st.cpu_s >= 0.5) == cpu and (st.cpu_s == 0.0) != cpu
    assert (st.first_frame_wall_s == started.wall_s) == bool(processed)


def test_gate_events_and_later_verdicts_become_counters_warnings_and_notes():
    said = []
    record = ChainRecorder(said.append, logging.getLogger(__name__))
    record.gate_events([GateEvent(GateEventKind.GAP, 7, "lost"), GateEvent(GateEventKind.LAST_DROPPED, 9, "no wall"),
                        GateEvent(GateEventKind.KEYFRAME, 9, "kept")])
    record.judged_later([LaterVerdict(0, 3, False), LaterVerdict(12, 15, True)])
    st = record.stats
    counts = (st.gaps, st.last_candidates_dropped, st.keyframes_judged_later, st.keyframes_later_background)
    assert counts == (1, 1, 2, 1)
    assert said == st.warnings == ["possible gap in coverage at frame 7: lost"]
    assert st.notes == ["no wall", "keyframe 12 not spooled: the parallax against frame 15 shows only background "
                                   "(the network alone kept it)"]


def test_no_function_of_the_onboard_chain_is_over_80_lines():
    """A function a reader cannot take in at once hides what it decides; the chain reads as named steps."""
    files = [*(ROOT / "companion" / "onboard").glob("*.py"), ROOT / "companion" / "keyframes" / "gate.py",
             ROOT / "companion" / "depth" / "masker.py"]
    long = [f"{path.relative_to(ROOT)}:{node.name} ({node.end_lineno - node.lineno + 1} lines)"
            for path in files for node in ast.walk(ast.parse(path.read_text()))
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef) and node.end_lineno - node.lineno >= 80]
    assert not long, long

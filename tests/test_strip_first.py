"""Issue 15: the first keyframe of a pass is judged by the parallax of the frames after it before it is spooled.

A real-texture pass (``sim/camera/photo_passes.py``: a held-out facade photo on the wall at 4 m, a held-out street
photo 120 m behind) flown through the onboard chain with the shipped ``sim`` model and parallax. Its first frame has
no frame behind it, so the masker's network alone decides, and the network reads the top of this real wall farther
than the background: it cuts it. The chain now holds that keyframe until the next frame lies far enough along the
baseline and masks it again against it (``companion.depth.parallax_first``).
"""

from __future__ import annotations

import json
from dataclasses import replace

import cv2
import numpy as np
import pytest

from companion.capture.tagging import FrameTagger
from companion.capture.telemetry import ClockMap, TelemetryBuffer
from companion.depth.masker import Masker
from companion.depth.parallax import SequenceParallax
from companion.depth.parallax_first import (
    Baseline,
    LaterReference,
    baseline_between,
    first_look,
    judge_with_later,
)
from companion.keyframes.gate import GateConfig, KeyframeGate
from companion.onboard.chain import CullChain
from companion.onboard.tracked import MeasureSchedule
from companion.records import Frame, Pose, TaggedFrame
from companion.spool import KeyframeSpool
from companion.spool.layout import CLOSED, MANIFEST
from evaluation.stitch.synthetic import SyntheticWall, TelemetryErrors, reported_pose, wall_frame

STANDOFF_M = 4.0


@pytest.fixture(scope="module")
def ornate():
    """The first frames of the ornate-entry pass as bench/stitch_eval.py renders it (80 frames, 640 px: 16.5 cm
    apart, inside the parallax's 8-60 cm baseline), with their exact relative telemetry."""
    pytest.importorskip("sim.camera.photo_scene")
    from sim.camera.model import CameraModel
    from sim.camera.photo_passes import RECIPES, build_pass
    from sim.camera.photo_scene import PhotoPassRenderer

    spec = build_pass(RECIPES["ornate-entry"], frames=80, background_frames=7)
    cam = spec.camera
    spec = replace(spec, camera=CameraModel(640, round(cam.height * 640 / cam.width), cam.hfov_deg))
    renderer = PhotoPassRenderer(spec)
    facade = wall_frame(SyntheticWall(length_m=spec.wall.width_m, height_m=spec.wall.height_m))
    renders, poses = [], []
    for i in range(8):
        f = renderer.render(i)
        renders.append(f)
        poses.append(reported_pose(None, facade, (f.along_m, STANDOFF_M, f.up_m, 0.0, 0.0), TelemetryErrors(), i,
                                   time_s=i / 10.0))
    return spec, renders, poses


def _masker(spec) -> Masker:
    return Masker("sim", parallax=SequenceParallax(spec.camera.hfov_deg, standoff_m=STANDOFF_M))


def _tagged(ornate, i: int, pose: Pose | None = None) -> TaggedFrame:
    _, renders, poses = ornate
    return TaggedFrame(Frame(i, i / 10.0, renders[i].image), pose or poses[i])


def _top_wall_kept(truth: np.ndarray, mask: np.ndarray) -> float:
    """Share of the true wall in the frame's top fifth that the mask keeps."""
    top = np.zeros_like(truth)
    top[: truth.shape[0] // 5] = True
    return float((truth & top & (mask > 0)).sum()) / max(1, int((truth & top).sum()))


def _chain(spec, out, poses: list[Pose]) -> CullChain:
    buf = TelemetryBuffer()
    for pose in poses:
        buf.add(pose)
    last = poses[-1]
    buf.add(replace(last, time_s=last.time_s + 0.1))  # telemetry runs past the newest frame, as in flight
    return CullChain(FrameTagger(buf, ClockMap(0.0)), _masker(spec), KeyframeGate(GateConfig(rth=0.80)),
                     KeyframeSpool(out), track=MeasureSchedule())


def _spooled(out) -> list[dict]:
    return [json.loads(line) for line in (out / MANIFEST).read_text().splitlines()]


def _mask_of(out, entry: dict) -> np.ndarray:
    return cv2.imread(str(out / entry["mask"]), cv2.IMREAD_GRAYSCALE)


def test_the_masker_alone_cuts_the_first_frames_wall_top_and_a_later_frame_gives_it_back(ornate):
    spec, renders, _ = ornate
    masker = _masker(spec)
    look = first_look(masker, _tagged(ornate, 0))
    network = look.masked
    truth = renders[0].roi_mask > 0
    assert look.alone  # no frame behind the pass's first: the network alone decided
    assert _top_wall_kept(truth, network.mask) < 0.1  # it reads this real wall's top as far
    assert baseline_between(masker, *(p for p in ornate[2][:2])) == Baseline.USABLE
    judged = judge_with_later(masker, _tagged(ornate, 0), _tagged(ornate, 1))
    assert judged.parallax is not None and judged.later_index == 1
    assert _top_wall_kept(truth, judged.masked.mask) > 0.6
    assert float((truth & (judged.masked.mask > 0)).mean()) > float((truth & (network.mask > 0)).mean()) + 0.2
    # the next frame has the first behind it: the masker judges it by parallax, not alone
    assert not first_look(masker, _tagged(ornate, 1)).alone


def test_the_chain_spools_a_passs_first_keyframe_with_the_wall_top_main_cut(ornate, tmp_path):
    spec, renders, poses = ornate
    chain = _chain(spec, tmp_path, poses)
    assert chain.process(Frame(0, 0.0, renders[0].image)) == []  # the first keyframe is held: no later frame yet
    assert chain.stats.keyframes == 0 and not (tmp_path / MANIFEST).exists()
    spooled_at = []
    for i in range(1, len(renders)):
        spooled_at += [i] * len(chain.process(Frame(i, i / 10.0, renders[i].image)))
    chain.finish()
    entries = _spooled(tmp_path)
    assert entries[0]["index"] == 0 and spooled_at[0] == 1  # spooled once frame 1 (16.5 cm on) judged it
    assert [e["index"] for e in entries] == sorted(e["index"] for e in entries)
    assert chain.stats.keyframes_judged_later == 1 and chain.stats.keyframes_later_background == 0
    truth = renders[0].roi_mask > 0
    main_mask = Masker("sim", parallax=SequenceParallax(spec.camera.hfov_deg, standoff_m=STANDOFF_M))(
        _tagged(ornate, 0)).mask  # what main spooled: the network alone
    assert _top_wall_kept(truth, main_mask) < 0.1
    assert _top_wall_kept(truth, _mask_of(tmp_path, entries[0])) > 0.6


def test_a_flight_that_ends_after_the_first_keyframe_spools_it_with_the_network_mask(ornate, tmp_path):
    spec, renders, poses = ornate
    chain = _chain(spec, tmp_path, poses[:1])
    assert chain.process(Frame(0, 0.0, renders[0].image)) == []
    assert len(chain.finish()) == 1
    entries = _spooled(tmp_path)
    assert [e["index"] for e in entries] == [0] and (tmp_path / CLOSED).exists()
    network = _masker(spec)(_tagged(ornate, 0)).mask
    assert np.array_equal(_mask_of(tmp_path, entries[0]) > 0, network > 0)
    assert chain.stats.keyframes_judged_later == 0 and chain.full_resolution_held == 0


def test_a_newer_keyframe_never_overtakes_a_held_one(ornate, tmp_path):
    """Telemetry that never moves (a hover the camera's images contradict): no later frame lies far enough along
    the baseline, so when the gate decides the next keyframe the held one is spooled first, with its network mask."""
    spec, renders, poses = ornate
    still = [replace(poses[0], time_s=i / 10.0) for i in range(len(renders))]
    chain = _chain(spec, tmp_path, still)
    for i, f in enumerate(renders):
        chain.process(Frame(i, i / 10.0, f.image))
    chain.finish()
    idx = [e["index"] for e in _spooled(tmp_path)]
    assert idx[0] == 0 and len(idx) >= 2 and idx == sorted(idx)
    assert chain.stats.keyframes_judged_later == 0


def test_held_frames_resolve_in_order_and_only_from_later_frames(ornate):
    spec, _, poses = ornate
    masker = _masker(spec)
    later = LaterReference(masker)
    first = first_look(masker, _tagged(ornate, 0)).masked
    later.hold(_tagged(ornate, 0), first, "kf0")
    assert later.offer(_tagged(ornate, 0)) == []  # itself: not later
    assert later.offer(_tagged(ornate, 2, replace(poses[0], time_s=0.2))) == []  # no baseline yet: waits
    far = replace(poses[1], lat=poses[1].lat + 1e-5)  # about a metre on: beyond the flow's reach
    (resolved,) = later.offer(_tagged(ornate, 3, far))
    assert resolved.item == "kf0" and resolved.judgement is None and resolved.masked is first
    assert later.held_indices() == [] and later.unjudged == 1
    with pytest.raises(ValueError):
        LaterReference(Masker("sim"))

"""The chain decides on a working copy and spools full-resolution keyframes (issue 17: cost independent of the
camera's resolution)."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from companion.capture.tagging import FrameTagger
from companion.capture.telemetry import ClockMap, TelemetryBuffer
from companion.onboard.setup import build_chain
from companion.onboard.working import FullResolution, WorkingCopy, decode_full
from companion.records import EncodedFrame, Frame, GateDecision, Keyframe, Pose
from companion.spool.layout import MANIFEST
from evaluation.keyframes.synthetic import render, sweep, textured_wall, true_overlap


def _buffer(n, fps=10.0):
    buf = TelemetryBuffer()
    for i in range(n + 2):
        buf.add(Pose(i / fps, 37.0 + i * 1e-6, 127.0, 40.0, 10.0, 0.0, 0.0, 0.0))
    return buf


def test_working_copy_resizes_large_frames_once_and_leaves_small_ones():
    work = WorkingCopy(640)
    small = Frame(3, 0.3, np.zeros((360, 640, 3), np.uint8))
    assert work.of(small) is small
    big = Frame(4, 0.4, np.full((720, 1280, 3), 77, np.uint8))
    copy = work.of(big)
    assert copy.image.shape == (360, 640, 3) and (copy.index, copy.capture_time_s) == (4, 0.4)
    assert int(copy.image[100, 100, 0]) == 77
    assert WorkingCopy(0).of(big) is big


def test_restore_gives_a_keyframe_its_full_resolution_image_mask_and_pixel_shifts():
    full = Frame(7, 0.7, np.zeros((720, 1280, 3), np.uint8))
    work = WorkingCopy(640).of(full)
    mask = np.zeros((360, 640), np.uint8)
    mask[:, 320:] = 255
    kf = Keyframe(work, None, mask,
                  GateDecision(overlap_to_previous=81.0, dx_px=-50.0, dy_px=4.0, prediction_miss_px=1.5))
    held = FullResolution()
    held.keep(full, work)
    out = held.restore(kf)
    assert out.image is full.image and out.mask.shape == (720, 1280)
    assert set(np.unique(out.mask)) == {0, 255} and out.mask[:, 700:].all() and not out.mask[:, :600].any()
    d = out.decision
    assert (d.dx_px, d.dy_px, d.prediction_miss_px, d.overlap_to_previous) == (-100.0, 8.0, 3.0, 81.0)
    held.release_below(8)
    assert len(held) == 0 and held.restore(kf) is kf  # released: nothing to restore


def _jpeg(image: np.ndarray) -> bytes:
    ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 90])
    assert ok
    return buf.tobytes()


def test_an_encoded_frame_is_decoded_straight_to_the_working_size():
    image = render(textured_wall(3200, 1000, seed=5), sweep(textured_wall(3200, 1000, seed=5), 1, 40, 1280, 720,
                                                             y=500)[0])
    enc = EncodedFrame(9, 0.9, _jpeg(image), 1280, 720)
    full = decode_full(enc)
    assert full.image.shape == (720, 1280, 3) and (full.index, full.capture_time_s) == (9, 0.9)
    for long_side, shape in ((640, (360, 640, 3)), (480, (270, 480, 3)), (1000, (562, 1000, 3))):
        copy = WorkingCopy(long_side).of(enc)
        assert copy.image.shape == shape and (copy.index, copy.capture_time_s) == (9, 0.9)
        ref = cv2.resize(full.image, shape[1::-1], interpolation=cv2.INTER_AREA)
        # the decoder's DCT scaling (+ an area resize for the rest) against a full decode + area resize: the same
        # picture within a grey level or so on this high-contrast synthetic texture (0.2 on simulator frames)
        assert np.abs(copy.image.astype(float) - ref).mean() < 1.5
    assert WorkingCopy(0).of(enc).image.shape == (720, 1280, 3)
    assert WorkingCopy(640).of(EncodedFrame(10, 1.0, b"\xff\xd8 not a jpeg", 1280, 720)) is None


def test_restore_decodes_an_encoded_keyframe_at_full_resolution():
    image = np.zeros((720, 1280, 3), np.uint8)
    image[:, 640:] = 200
    enc = EncodedFrame(7, 0.7, _jpeg(image), 1280, 720)
    work = WorkingCopy(640).of(enc)
    kf = Keyframe(work, None, np.full((360, 640), 255, np.uint8), GateDecision(overlap_to_previous=81.0))
    held = FullResolution()
    held.keep(enc, work)
    out = held.restore(kf)
    assert out.image.shape == (720, 1280, 3) and out.mask.shape == (720, 1280)
    assert abs(int(out.image[100, 1000, 0]) - 200) <= 3 and int(out.image[100, 100, 0]) <= 3


@pytest.mark.parametrize("encoded", [False, True], ids=["decoded", "encoded"])
def test_chain_on_1280_px_frames_spools_full_resolution_keyframes_at_the_overlap_target(tmp_path, encoded):
    tex = textured_wall(3200, 1000, seed=3)
    step = 40  # texture px per frame at zoom 1: the true full-resolution shift
    views = sweep(tex, 36, step, 1280, 720, y=500)
    chain = build_chain(tmp_path, FrameTagger(_buffer(len(views)), ClockMap(0.0)), mask=False)
    seen = []  # the frame sizes the gate decided on
    for name in ("measure", "push"):
        method = getattr(chain.gate, name)
        setattr(chain.gate, name, lambda masked, method=method: seen.append(masked.image.shape) or method(masked))
    held = []
    for i, view in enumerate(views):
        image = render(tex, view)
        chain.process(EncodedFrame(i, i / 10.0, _jpeg(image), 1280, 720) if encoded else Frame(i, i / 10.0, image))
        held.append(chain.full_resolution_held)
    if encoded:  # a frame whose data is not an image is counted as corrupt, not processed, and stops nothing
        chain.process(EncodedFrame(len(views), len(views) / 10.0, b"garbage", 1280, 720))
        assert chain.stats.corrupt == 1 and chain.stats.frames_processed == len(views)
    chain.finish()
    assert seen and set(seen) == {(360, 640, 3)}  # the gate's cost is that of a 640 px frame
    assert max(held) <= chain.selection.schedule.max_held + 2  # full-resolution frames are let go once decided
    lines = [json.loads(x) for x in (tmp_path / MANIFEST).read_text().splitlines()]
    idx = [x["index"] for x in lines]
    assert idx[0] == 0 and idx[-1] == len(views) - 1 and len(idx) >= 4
    for a, b in zip(idx, idx[1:], strict=False):
        assert true_overlap(views[a], views[b]) >= 0.80 - 0.03
        if b + 1 < len(views):
            assert true_overlap(views[a], views[b + 1]) < 0.80 + 0.03
    for line in lines[1:]:
        stem = tmp_path / f"kf_{line['index']:06d}"
        assert cv2.imread(str(stem) + ".jpg").shape == (720, 1280, 3)
        assert cv2.imread(str(stem) + "_mask.png", cv2.IMREAD_GRAYSCALE).shape == (720, 1280)
        side = json.loads((stem.with_suffix(".json")).read_text())
        frames = side["frames_since_previous"]
        # the wall moved right, so its image moved left by `step` full-resolution px per frame
        assert abs(side["dx_px"] + step * frames) < 0.02 * step * frames + 2.0


def test_off_scan_frames_do_not_pile_up_at_full_resolution(tmp_path):
    from companion.keyframes.gate_scope import ScanScope
    from evaluation.keyframes.synthetic import WallCamera, WallScene

    scene = WallScene(textured_wall(600, 200, seed=1), textured_wall(160, 60, seed=2), 16.0, 10.0,
                      width_px=1280, height_px=720)
    buf = TelemetryBuffer()
    for i in range(12):  # a transit 15 m out: every frame off the scan
        buf.add(scene.pose(WallCamera(4.0 + 0.1 * i, 15.0, 5.0), i / 10.0))
    chain = build_chain(tmp_path, FrameTagger(buf, ClockMap(0.0)), mask=False)
    chain.scope = ScanScope(scene.frame, 4.0)
    image = np.zeros((720, 1280, 3), np.uint8)
    for i in range(10):
        chain.process(Frame(i, i / 10.0, image))
        assert chain.full_resolution_held == 0
    assert chain.stats.off_scan == 10 and chain.stats.keyframes == 0


def test_frames_off_the_scan_or_before_telemetry_are_never_decoded(tmp_path, monkeypatch):
    """Tagging and the scan scope need the capture time only: a transit frame costs no JPEG decode (issue 17)."""
    from companion.keyframes.gate_scope import ScanScope
    from companion.onboard import working
    from evaluation.keyframes.synthetic import WallCamera, WallScene

    scene = WallScene(textured_wall(600, 200, seed=1), textured_wall(160, 60, seed=2), 16.0, 10.0,
                      width_px=1280, height_px=720)
    buf = TelemetryBuffer()
    for i in range(3, 14):  # telemetry from 0.3 s; a transit 15 m out: every frame off the scan
        buf.add(scene.pose(WallCamera(4.0 + 0.1 * i, 15.0, 5.0), i / 10.0))
    chain = build_chain(tmp_path, FrameTagger(buf, ClockMap(0.0)), mask=False)
    chain.scope = ScanScope(scene.frame, 4.0)
    decodes = []
    real_imdecode = working.cv2.imdecode
    monkeypatch.setattr(working.cv2, "imdecode", lambda *a: decodes.append(1) or real_imdecode(*a))
    data = _jpeg(np.zeros((720, 1280, 3), np.uint8))
    for i in range(12):
        chain.process(EncodedFrame(i, i / 10.0, data, 1280, 720))
    st = chain.stats
    assert st.before_telemetry >= 2 and st.off_scan >= 9 and st.before_telemetry + st.off_scan == 12
    assert st.frames_processed == 12
    assert decodes == [] and st.corrupt == 0 and chain.full_resolution_held == 0

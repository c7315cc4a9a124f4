"""Frames taken far off the scan's standoff (take-off, transit, landing facing the wall) are counted, not judged."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from companion.capture.tagging import FrameTagger
from companion.capture.telemetry import ClockMap, TelemetryBuffer
from companion.errors import CompanionError
from companion.keyframes import FeatureConfig, GateConfig, KeyframeGate
from companion.keyframes.gate_scope import ScanScope
from companion.keyframes.synthetic import WallCamera, WallScene, textured_wall
from companion.mission import load_mission
from companion.onboard.chain import CullChain
from companion.onboard.crosscheck import OverlapCrossCheck
from companion.onboard.setup import build_chain
from companion.spool import KeyframeSpool

W, H = 320, 180
STANDOFF = 4.0
DEMO = Path(__file__).resolve().parents[1] / "missions" / "demo-facade.yaml"


@pytest.fixture(scope="module")
def scene() -> WallScene:
    wall = textured_wall(1200, 600, seed=1)  # 12 m x 6 m at 100 px/m
    far = cv2.normalize(textured_wall(1800, 600, seed=9), None, 0, 255, cv2.NORM_MINMAX)
    return WallScene(wall, far, 12.0, 6.0, width_px=W, height_px=H)


def test_a_camera_beyond_twice_the_standoff_is_off_the_scan(scene):
    scope = ScanScope(scene.frame, STANDOFF)
    assert not scope.off_scan(scene.pose(WallCamera(6.0, 4.0, 3.0)))
    assert not scope.off_scan(scene.pose(WallCamera(6.0, 7.5, 3.0)))  # a GNSS error of metres keeps the frame
    assert scope.off_scan(scene.pose(WallCamera(6.0, 13.0, 3.0)))  # the demo's take-off spot
    assert not scope.off_scan(scene.pose(WallCamera(6.0, 13.0, 3.0)), stale=True)  # no trusted pose: images decide
    assert not scope.off_scan(None)
    with pytest.raises(CompanionError, match="factor"):
        ScanScope(scene.frame, STANDOFF, max_distance_factor=1.0)


def test_a_frame_showing_none_of_the_wall_and_its_margins_is_off_the_scan(scene):
    scope = ScanScope(scene.frame, STANDOFF, extent=(-1.0, 13.0, 0.0, 7.0), hfov_deg=scene.hfov_deg, aspect=H / W)
    corners = scope.footprint(scene.pose(WallCamera(6.0, STANDOFF, 3.0)))
    half_w, half_h = (float(np.ptp(corners[:, k])) / 2.0 for k in (0, 1))
    top = 7.0 + half_h  # the highest camera whose footprint still reaches the extent's top edge
    assert not scope.off_scan(scene.pose(WallCamera(6.0, STANDOFF, top + 0.9)))  # within the 1 m tolerance
    assert scope.off_scan(scene.pose(WallCamera(6.0, STANDOFF, top + 1.5)))  # over the roof: roof and sky only
    assert scope.off_scan(scene.pose(WallCamera(13.0 + half_w + 1.5, STANDOFF, 3.0)))  # past the end
    assert not ScanScope(scene.frame, STANDOFF).off_scan(scene.pose(WallCamera(6.0, STANDOFF, top + 1.5)))


def _chain(scene, buf, spool_dir, scope):
    check = OverlapCrossCheck(scene.frame, scene.hfov_deg, H / W, standoff_m=STANDOFF)
    gate = KeyframeGate(GateConfig(features=FeatureConfig(long_side_px=W, max_features=1000)))
    return CullChain(FrameTagger(buf, ClockMap(0.0)), None, gate, KeyframeSpool(spool_dir), crosscheck=check,
                     scope=scope)  # fmt: skip


def test_take_off_facing_the_wall_makes_no_keyframe_and_the_scan_is_culled_as_before(scene, tmp_path):
    climb = [WallCamera(6.0, 13.0, 1.0 + 0.25 * i) for i in range(16)]  # climbing 13 m out, facing the wall
    scan = [WallCamera(3.0 + 0.3 * i, STANDOFF, 3.0) for i in range(20)]
    cams = climb + scan
    buf = TelemetryBuffer()
    for i, c in enumerate(cams):
        buf.add(scene.pose(c, i / 3.0))
    frames = [scene.masked_frame(i, c, t_s=i / 3.0, mask="none").frame for i, c in enumerate(cams)]

    def cull(scope, name):
        chain = _chain(scene, buf, tmp_path / name, scope)
        for f in frames:
            chain.process(f)
        chain.finish()
        return chain, [e.index for e in chain.spool.entries]

    before, kept_before = cull(None, "before")
    assert any(i < len(climb) for i in kept_before)  # without the scope the climb made keyframes of its own
    chain, kept = cull(ScanScope(scene.frame, STANDOFF), "after")
    assert chain.stats.off_scan == len(climb)
    assert kept[0] == len(climb) and kept == [i for i in kept_before if i >= len(climb)] != []
    pairs = [100.0 * scene.true_overlap(cams[a], cams[b]) for a, b in zip(kept, kept[1:], strict=False)]
    assert min(pairs) >= 77.0


def test_the_chain_built_for_a_mission_knows_its_standoff(tmp_path):
    chain = build_chain(tmp_path, FrameTagger(TelemetryBuffer(), ClockMap(0.0)), mission=load_mission(DEMO),
                        mask=False)  # fmt: skip
    assert chain.scope is not None and chain.scope.max_distance_m == pytest.approx(8.0)
    assert build_chain(tmp_path / "none", FrameTagger(TelemetryBuffer(), ClockMap(0.0)), mask=False).scope is None

"""The mission's wall bound in the chain (``companion/depth/pose_bound.py``): frames with a telemetry pose, beyond the
4 m standoff, are masked only where the wall can be; a GNSS bias of 1.5 m never cuts true wall; at 4 m nothing."""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pytest

from companion.depth.masker import Masker
from companion.depth.photo_pose import MissionWall
from companion.depth.pose_bound import TelemetryWallBound
from companion.depth.wall_bound import PoseUncertainty, frontal_view, wall_bound
from companion.mission.spec import load_mission
from companion.records import Frame, Pose, TaggedFrame

ROOT = Path(__file__).resolve().parents[1]
W, H = 640, 360


@pytest.fixture(scope="module")
def mission():
    return load_mission(ROOT / "missions" / "demo-facade.yaml")


@pytest.fixture(scope="module")
def far_mission(mission):
    return mission.model_copy(update={"standoff_m": 30.0})


class _NearEverywhere:
    """The shipped model's metadata and a network that reads every pixel 5 m away (it keeps the whole frame)."""

    def __init__(self):
        from companion.depth.session import DepthSession

        self.info = DepthSession().info

    def disparity(self, image):
        return np.full((self.info.height, self.info.width), self.info.disparity_for_depth(5.0), np.float32)


def _pose(wall: MissionWall, along: float, out: float, up: float) -> Pose:
    """The vehicle's pose estimate at facade (along, out, up), camera level and facing the wall."""
    lat, lon, _ = wall.frame.facade_to_geodetic(along, out, up)
    return Pose(0.0, float(lat), float(lon), wall.ground_alt_amsl_m + up, up, 0.0, 0.0,
                wall.frame.yaw_facing_wall_deg, gimbal_pitch_deg=0.0, gimbal_yaw_deg=0.0)


def _true_wall(wall: MissionWall, hfov_deg: float, along: float, out: float, up: float) -> np.ndarray:
    focal = (W / 2) / np.tan(np.radians(hfov_deg / 2))
    exact = PoseUncertainty(horizontal_m=0.0, vertical_m=0.0, attitude_deg=0.0)
    return wall_bound(frontal_view(focal, W, H, along, out, up), wall.extent, exact) > 0


def test_the_bound_is_used_only_beyond_the_4_m_standoff(mission, far_mission):
    assert float(mission.standoff_m) == pytest.approx(4.0)
    assert TelemetryWallBound.for_mission(mission) is None
    assert TelemetryWallBound.for_mission(mission, beyond_standoff_m=None) is not None
    assert TelemetryWallBound.for_mission(far_mission) is not None


def test_a_still_30_m_out_loses_the_building_beyond_the_walls_end_and_keeps_its_wall(far_mission):
    """A still 30 m out aimed at the wall's right end: the network keeps everything; the bound cuts what lies
    beyond the end (past its 2-sigma margin) and keeps every true wall pixel, under a 1.5 m GNSS bias too."""
    bound = TelemetryWallBound.for_mission(far_mission)
    wall = bound.wall
    length = wall.extent.length_m
    along, out, up = length, 30.0, 6.0
    truth = _true_wall(wall, far_mission.camera.hfov_deg, along, out, up)
    assert 0.2 < truth.mean() < 0.6
    for da, do, du in itertools.product((-1.5, 0.0, 1.5), (-1.5, 0.0, 1.5), (-0.3, 0.3)):
        masker = Masker(session=_NearEverywhere(), bound=bound)
        tagged = TaggedFrame(Frame(0, 0.0, np.full((H, W, 3), 128, np.uint8)), _pose(wall, along + da, out + do,
                                                                                    up + du))
        masked = masker(tagged)
        assert masked is not None
        kept = masked.mask > 0
        assert not np.any(truth & ~kept), (da, do, du)  # no true wall cut
        assert not kept[:, -150:].any()  # beyond the wall's end, past the margin: cut
        assert masker.stats.bound_cut == 1 and masker.stats.bound_dropped == 0


def test_a_still_past_the_walls_end_is_dropped_and_a_stale_pose_is_not_bounded(far_mission):
    bound = TelemetryWallBound.for_mission(far_mission)
    masker = Masker(session=_NearEverywhere(), bound=bound)
    image = np.full((H, W, 3), 128, np.uint8)
    beyond = _pose(bound.wall, bound.wall.extent.length_m + 30.0, 30.0, 6.0)
    assert masker(TaggedFrame(Frame(0, 0.0, image), beyond)) is None
    assert masker.stats.bound_dropped == 1 and masker.stats.dropped_empty == 1
    stale = masker(TaggedFrame(Frame(1, 0.1, image), beyond, pose_stale=True))
    assert stale is not None and stale.mask.all()  # a stale pose cannot place the wall: the network decides


def test_the_chain_masks_within_the_bound_only_beyond_4_m(tmp_path, mission, far_mission):
    from companion.capture.tagging import FrameTagger
    from companion.capture.telemetry import ClockMap, TelemetryBuffer
    from companion.onboard.setup import build_chain

    near = build_chain(tmp_path / "near", FrameTagger(TelemetryBuffer(), ClockMap(0.0)), mission=mission)
    far = build_chain(tmp_path / "far", FrameTagger(TelemetryBuffer(), ClockMap(0.0)), mission=far_mission)
    assert near.masker.bound is None
    assert isinstance(far.masker.bound, TelemetryWallBound)


def test_a_jump_of_the_relative_altitude_does_not_move_the_bound(far_mission):
    """Real PX4 reports a relative altitude that jumps by up to 1.5 m between samples while its AMSL altitude is
    smooth (../shared/notes/real-firmware.md): the bound places the frame by the AMSL altitude."""
    from dataclasses import replace

    bound = TelemetryWallBound.for_mission(far_mission)
    pose = _pose(bound.wall, bound.wall.extent.length_m, 30.0, 6.0)
    jumped = replace(pose, relative_alt_m=pose.relative_alt_m + 1.5)
    assert np.array_equal(bound(pose, (H, W)), bound(jumped, (H, W)))
    lower = replace(pose, alt_amsl_m=pose.alt_amsl_m - 8.0)  # the AMSL altitude does move it
    assert not np.array_equal(bound(pose, (H, W)), bound(lower, (H, W)))


def test_the_chain_drops_the_near_building_beyond_the_walls_end_and_keeps_the_wall(tmp_path):
    """Stills 5 m apart 25 m from a 60 m wall, a background 15 m behind it (40 m from the camera: within the 2.5
    standoffs parallax calls near, so parallax keeps it): through the chain with the mission's wall bound the
    keyframes past the wall's end keep far less of that background (48 -> 13 % of the keyframes' background), the
    stills that show no wall are no longer spooled, and no keyframe loses wall."""
    import json

    import cv2
    import pymap3d

    from companion.capture.tagging import FrameTagger
    from companion.capture.telemetry import ClockMap, TelemetryBuffer
    from companion.depth.parallax import SequenceParallax
    from companion.depth.wall_bound import WallExtent
    from companion.geo import FacadeFrame, GeoPoint
    from companion.keyframes.gate import GateConfig, KeyframeGate
    from companion.onboard.chain import CullChain
    from companion.onboard.tracked import MeasureSchedule
    from companion.spool import KeyframeSpool
    from companion.spool.layout import MANIFEST
    from sim.camera.model import CameraModel
    from sim.camera.photo_scene import PhotoPass, PhotoPassRenderer, PhotoTexture

    standoff, length, origin = 25.0, 60.0, (47.0, 8.0, 400.0)

    def texture(seed: int) -> np.ndarray:
        small = np.random.default_rng(seed).integers(0, 255, (75, 150, 3), dtype=np.uint8)
        return cv2.GaussianBlur(cv2.resize(small, (1200, 600), interpolation=cv2.INTER_NEAREST), (5, 5), 0)

    renderer = PhotoPassRenderer(PhotoPass(
        "near-building", PhotoTexture("wall", texture(1), length), PhotoTexture("bg", texture(2), 1.0),
        background_distance_m=15.0, standoff_m=standoff, frames=16, background_frames=4,
        camera=CameraModel(width=640, height=360, hfov_deg=69.0)))
    renders = [renderer.render(i) for i in range(len(renderer))]
    end = pymap3d.enu2geodetic(length, 0.0, 0.0, *origin)
    frame = FacadeFrame.from_wall(GeoPoint(*origin), GeoPoint(float(end[0]), float(end[1]), origin[2]))
    wall = MissionWall(frame, WallExtent(length, length / 2), origin[2], origin[2], 69.0)

    def pose(t: float) -> Pose:
        along = float(np.interp(t / 2.0, range(len(renders)), [f.along_m for f in renders]))
        up = renders[0].up_m
        lat, lon, alt = pymap3d.enu2geodetic(along + 1.0, -(standoff + 1.0), up + 0.3, *origin)  # a GNSS bias
        return Pose(round(t, 3), float(lat), float(lon), float(alt), up, 0.0, 0.0, 0.0, gimbal_pitch_deg=0.0,
                    gimbal_yaw_deg=0.0)

    def cull(out, bound) -> dict[int, np.ndarray]:
        buf = TelemetryBuffer()
        for t in np.arange(-0.5, 2.0 * (len(renders) - 1) + 0.55, 0.1):
            buf.add(pose(float(t)))
        masker = Masker("sim", parallax=SequenceParallax(69.0, standoff_m=standoff), bound=bound)
        chain = CullChain(FrameTagger(buf, ClockMap(0.0)), masker, KeyframeGate(GateConfig(rth=0.80)),
                          KeyframeSpool(out), track=MeasureSchedule())
        for i, f in enumerate(renders):
            chain.process(Frame(i, 2.0 * i, f.image))
        chain.finish()
        entries = [json.loads(line) for line in (out / MANIFEST).read_text().splitlines()]
        return {e["index"]: cv2.imread(str(out / e["mask"]), cv2.IMREAD_GRAYSCALE) > 127 for e in entries}

    without = cull(tmp_path / "without", None)
    within = cull(tmp_path / "within", TelemetryWallBound(wall))
    background_kept = {}
    for name, spooled in (("without", without), ("within", within)):
        kept = total = 0
        for i, mask in spooled.items():
            background = renders[i].roi_mask == 0
            kept, total = kept + int((mask & background).sum()), total + int(background.sum())
        background_kept[name] = kept / max(1, total)
    assert background_kept["without"] > 0.3  # parallax alone keeps the near building
    assert background_kept["within"] < 0.5 * background_kept["without"]
    # parallax alone spools stills that show no wall at all; the bound drops them
    assert any(not renders[i].roi_mask.any() for i in without)
    assert all(renders[i].roi_mask.any() for i in within)
    for i in set(without) & set(within):
        wall_px = renders[i].roi_mask > 0
        assert (within[i] & wall_px).sum() >= (without[i] & wall_px).sum() - 0.002 * wall_px.size, i

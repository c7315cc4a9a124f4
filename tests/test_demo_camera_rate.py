"""`companion demo` plans for the frame rate its simulated camera delivers, and reads the camera's frame counts."""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest

from companion.errors import CompanionError
from companion.mission import load_mission, plan_scan
from sim.demo import plan_for_camera, run_demo
from sim.rig import SitlRig

MISSION = Path("missions/demo-facade.yaml")


def test_the_plan_keeps_enough_camera_frames_between_keyframes():
    mission = load_mission(MISSION)
    full = plan_scan(mission)
    assert plan_for_camera(MISSION, mission.camera.fps).estimates == full.estimates  # the camera's own rate
    # the demo's PX4 moves home as real PX4 SIH does: the plan flies the strips' bottoms after PX4's home window, as
    # a real flight's does (the simulator is not special-cased), and scans instead of hovering through it
    assert full.estimates.px4_low_after_s > 120 and full.estimates.px4_home_settle_hold_s == 0.0
    ten = plan_for_camera(MISSION, 10.0).estimates
    # at 10 frames/s the frames-per-keyframe limit slows the scan to 10 frames per keyframe spacing; the last frame
    # still >= Rth is then the 9th, so the rule keeps more keyframes than at 30 fps (companion.mission.keyframe_count)
    assert ten.scan_speed_m_s < full.estimates.scan_speed_m_s
    assert ten.frames_per_keyframe == pytest.approx(mission.min_frames_per_keyframe)
    assert ten.expected_keyframes > full.estimates.expected_keyframes


def test_a_bad_frame_rate_is_refused_before_anything_is_written(tmp_path):
    args = argparse.Namespace(out=tmp_path / "demo", fps=0.0, mission=MISSION)
    with pytest.raises(CompanionError, match="--fps"):
        run_demo(args)
    assert not (tmp_path / "demo").exists()


def test_the_rig_reads_the_cameras_frame_counts(tmp_path):
    rig = SitlRig(MISSION, log_dir=tmp_path)
    assert rig.camera_counts() is None  # no camera log yet
    (tmp_path / "camera.log").write_text("camera: poses on udp://...\ncamera: 2712 frames sent, 3 dropped "
                                         "(rendering behind simulated time)\n")
    assert rig.camera_counts() == {"frames_sent": 2712, "frames_dropped": 3}

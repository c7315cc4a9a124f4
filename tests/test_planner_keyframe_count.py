"""The planner's expected keyframe count is the paper's rule walked frame by frame along the planned path."""

from __future__ import annotations

import math
from pathlib import Path

from companion.mission import load_mission, plan_scan
from companion.mission.keyframe_count import (
    PathPoint,
    ScanView,
    expected_keyframes,
    frame_centres,
    rule_keyframes,
)
from sim.demo import plan_for_camera

DEMO = Path(__file__).resolve().parents[1] / "missions" / "demo-facade.yaml"
W, H, RTH = 5.0, 3.0, 0.8  # footprint 5 x 3 m: 0.6 m of vertical travel between keyframes at 80 %


def _view(fps: float) -> ScanView:
    return ScanView(W, H, fps, standoff_m=4.0, standoff_tolerance_m=0.05, extent=(-10.0, 40.0, -10.0, 40.0))


def test_each_keyframe_step_is_a_whole_number_of_frames_at_or_under_the_spacing():
    # 0.06 m per frame: the 10th frame lands exactly on Rth, so the rule steps 9 frames (0.54 m), not 0.6 m
    strip = [PathPoint(0.0, 4.0, 6.0, 0.6), PathPoint(0.0, 4.0, 0.0, 0.6)]
    assert expected_keyframes(strip, _view(10.0), RTH) == math.ceil(6.0 / 0.54) + 1 == 13
    # three times the frame rate: 29 frames of 0.02 m (0.58 m) per keyframe
    assert expected_keyframes(strip, _view(30.0), RTH) == math.ceil(6.0 / 0.58) + 1 == 12


def test_a_strip_to_strip_step_wider_than_the_rule_allows_is_paid_in_keyframes():
    def two_strips(step_m: float) -> int:
        down = [PathPoint(0.0, 4.0, 6.0, 0.6), PathPoint(0.0, 4.0, 0.0, 0.6)]
        up = [PathPoint(step_m, 4.0, 0.0, 0.6), PathPoint(step_m, 4.0, 6.0, 0.6)]
        return expected_keyframes(down + up, _view(10.0), RTH)

    # 20 % of the 5 m width is 1 m: a 0.5 m step is crossed without a keyframe, 1.5 m needs one, 2 m two
    assert two_strips(1.5) == two_strips(0.5) + 1
    assert two_strips(2.0) == two_strips(0.5) + 2


def test_take_off_transit_and_landing_off_the_standoff_add_no_keyframe():
    strip = [PathPoint(0.0, 4.0, 6.0, 0.6), PathPoint(0.0, 4.0, 0.0, 0.6)]
    takeoff = [PathPoint(5.0, 13.0, 0.0, 2.0), PathPoint(5.0, 13.0, 8.0, 2.0), PathPoint(0.0, 4.0, 8.0, 5.0)]
    landing = [PathPoint(5.0, 13.0, 8.0, 5.0), PathPoint(5.0, 13.0, 0.0, 0.7)]
    # the descent from 8 m onto the strip (at the standoff, wall in view) is judged; the rest is not
    with_descent = [PathPoint(0.0, 4.0, 8.0, 0.6), *strip]
    assert expected_keyframes(takeoff + strip[:1] + strip[1:] + landing, _view(10.0), RTH) == expected_keyframes(
        with_descent, _view(10.0), RTH
    )


def test_frames_whose_footprint_misses_the_scan_extent_are_not_judged():
    climb = [PathPoint(0.0, 4.0, 0.0, 0.6), PathPoint(0.0, 4.0, 20.0, 0.6)]
    view = ScanView(W, H, 10.0, 4.0, 0.05, extent=(-10.0, 10.0, -1.5, 6.0))
    centres = frame_centres(climb, view)
    judged = [c for c in centres if c is not None]
    # judged while the footprint (1.5 m either side of the centre) meets the extent: centres below 7.5 m, then none
    assert 7.4 < max(u for _, u in judged) < 7.5
    assert centres[: len(judged)] == judged and all(c is None for c in centres[len(judged) :])
    assert expected_keyframes(climb, view, RTH) == rule_keyframes(judged, W, H, RTH) == math.ceil(7.44 / 0.54) + 1


def test_a_frame_with_nothing_in_between_above_rth_is_kept_below_it():
    # frames 1 m apart on a 3 m-high footprint: 67 % overlap each, every frame is a keyframe
    assert rule_keyframes([(0.0, float(u)) for u in range(5)], W, H, RTH) == 5
    # a stretch without judged frames ends the segment: its last candidate is kept, the next frame starts anew
    assert rule_keyframes([(0.0, 0.0), (0.0, 0.3), None, (9.0, 0.0)], W, H, RTH) == 3


def test_the_demo_plan_counts_what_its_camera_rate_makes_the_rule_keep():
    mission = load_mission(DEMO)
    plan = plan_scan(mission).for_autopilot("ardupilot")  # the strips in plain order (PX4's: a bottom band after)
    e = plan.estimates
    # the count before: one keyframe per spacing along each scan leg plus its start
    legs_only = sum(
        math.ceil(math.dist((plan.waypoints[i].along_m, plan.waypoints[i].up_m),
                            (plan.waypoints[j].along_m, plan.waypoints[j].up_m)) / e.keyframe_spacing_m - 1e-9) + 1
        for i, j in plan.scan_legs
    )  # fmt: skip
    assert legs_only == 247
    # 25.9 frames per spacing at 30 fps: 25-frame steps, 12 strip-to-strip moves, the roof margin in and out
    assert legs_only * 1.1 < e.expected_keyframes < legs_only * 1.25
    # at 10 fps the planner slows to 10 frames per spacing, and the rule steps 9: more keyframes than at 30 fps
    ten = plan_for_camera(DEMO, 10.0)
    assert ten.for_autopilot("ardupilot").estimates.expected_keyframes > e.expected_keyframes
    assert ten.estimates.expected_keyframes > plan_scan(mission).estimates.expected_keyframes  # PX4's too


def test_only_frames_showing_the_wall_are_judged_as_the_chain_s_scope_judges_them():
    """Issue 17: the chain's scan scope judges only frames showing the wall (over the roof margin the depth mask
    found no facade, so the gate could not keep keyframes there at the rule's spacing); the count walks the same
    rule. Down from 9 m over a 6 m wall with a 1.5 m roof margin (frames 1.5 m either side) and back up: counted
    from the first frame reaching the wall top (centre 7.5 m) to the last, not over the margin."""
    wall = (-5.0, 5.0, 0.0, 6.0)
    extent = (-7.0, 7.0, 0.0, 7.5)
    down_up = [PathPoint(0.0, 4.0, 9.0, 0.6), PathPoint(0.0, 4.0, 1.5, 0.6), PathPoint(0.0, 4.0, 9.0, 0.6)]
    margin_too = ScanView(W, H, 10.0, 4.0, 0.05, extent=extent)
    on_wall = ScanView(W, H, 10.0, 4.0, 0.05, extent=extent, wall=wall)
    judged = [c for c in frame_centres(down_up, on_wall) if c is not None]
    assert 7.4 < judged[0][1] <= 7.5 and 7.4 < judged[-1][1] <= 7.5
    assert max(c[1] for c in frame_centres(down_up, margin_too) if c is not None) > 8.9
    # 1.5 m of margin-only travel each way at 0.54 m per keyframe: two or three keyframes each way
    assert 4 <= expected_keyframes(down_up, margin_too, RTH) - expected_keyframes(down_up, on_wall, RTH) <= 6

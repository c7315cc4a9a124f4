"""Telemetry cross-check of the gate's overlap: contradicting image overlaps are flagged, agreeing ones are not."""

from __future__ import annotations

import math

import pytest

from companion.geo import FacadeFrame, GeoPoint
from companion.onboard.crosscheck import OverlapCrossCheck
from companion.records import Pose

FRAME = FacadeFrame.from_wall(GeoPoint(37.5665, 126.978, 30.0), GeoPoint(37.5665, 126.9783, 30.0))
CHECK = OverlapCrossCheck(FRAME, 69.0, 9 / 16)


def _pose(along: float, up: float, out: float = 4.0) -> Pose:
    lat, lon, alt = (float(v) for v in FRAME.facade_to_geodetic(along, out, up))
    return Pose(0.0, lat, lon, alt, up, 0.0, 0.0, 0.0)


def test_predicted_overlap_matches_the_footprint_geometry():
    height = 2 * 4.0 * math.tan(math.radians(34.5)) * 9 / 16  # 3.09 m footprint height at 4 m
    assert CHECK.predicted_percent(_pose(5, 3), _pose(5, 3 + 0.2 * height)) == pytest.approx(80.0, abs=0.05)
    assert CHECK.predicted_percent(_pose(5, 3), _pose(5, 3)) == pytest.approx(100.0)


def test_contradiction_is_flagged_agreement_is_not():
    a, near, far = _pose(5, 3), _pose(5, 3.5), _pose(5, 3.9)  # 16 % and 29 % of the footprint height
    assert CHECK.suspect(84.0, a, near, 80.0) is None  # telemetry ~83.8 %: agrees
    assert CHECK.suspect(95.0, a, far, 80.0) == pytest.approx(70.9, abs=0.2)  # telemetry says a gap
    assert CHECK.suspect(70.0, a, far, 80.0) is None  # the gate already flagged it as low overlap
    assert CHECK.suspect(95.0, None, far, 80.0) is None  # no pose: nothing to check

"""Typed records passed between pipeline stages (capture -> tag -> mask -> gate -> spool -> stitch).

Stages exchange only these; none reaches into another stage's internals.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class Pose:
    """Vehicle/camera pose from telemetry. Angles in degrees; yaw clockwise from north."""

    time_s: float
    lat: float
    lon: float
    alt_amsl_m: float
    relative_alt_m: float
    roll_deg: float
    pitch_deg: float
    yaw_deg: float
    velocity_ned_m_s: tuple[float, float, float] = (0.0, 0.0, 0.0)
    gimbal_pitch_deg: float = 0.0
    mission_item: int = -1


@dataclass
class Frame:
    """One camera image as delivered by a source. ``image`` is BGR uint8 (OpenCV order)."""

    index: int
    capture_time_s: float
    image: np.ndarray


@dataclass
class TaggedFrame:
    frame: Frame
    pose: Pose | None  # None when telemetry was stale at capture time
    pose_stale: bool = False


@dataclass
class MaskedFrame:
    tagged: TaggedFrame
    mask: np.ndarray  # uint8 0/255 at full frame resolution, 255 = facade (ROI)
    disparity: np.ndarray | None = None  # model output at model resolution


@dataclass
class Keyframe:
    masked: MaskedFrame
    overlap_to_previous: float | None  # percent, None for the first keyframe or after a gap
    inliers: int = 0
    gap_before: bool = False  # tracking was lost between the previous keyframe and this one
    extra: dict = field(default_factory=dict)

"""Typed records passed between pipeline stages (capture -> tag -> mask -> gate -> spool -> stitch).

Stages exchange only these; none reaches into another stage's internals.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

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


@dataclass(frozen=True)
class Frame:
    """One camera image as delivered by a source. ``image`` is BGR uint8 (OpenCV order)."""

    index: int
    capture_time_s: float
    image: np.ndarray


@dataclass(frozen=True)
class TaggedFrame:
    """A frame with the telemetry pose at its capture time."""

    frame: Frame
    pose: Pose | None  # None when telemetry was stale at capture time
    pose_stale: bool = False

    @property
    def index(self) -> int:
        return self.frame.index

    @property
    def image(self) -> np.ndarray:
        return self.frame.image


@dataclass(frozen=True)
class MaskedFrame:
    """A tagged frame with its ROI mask. The depth network's disparity is not carried: only an evaluation needs
    it, and it gets it from ``Masker.mask_measured``."""

    tagged: TaggedFrame
    mask: np.ndarray  # uint8 0/255 at full frame resolution, 255 = facade (ROI)

    @property
    def frame(self) -> Frame:
        return self.tagged.frame

    @property
    def pose(self) -> Pose | None:
        return self.tagged.pose

    @property
    def pose_stale(self) -> bool:
        return self.tagged.pose_stale

    @property
    def index(self) -> int:
        return self.tagged.frame.index

    @property
    def image(self) -> np.ndarray:
        return self.tagged.frame.image


@dataclass(frozen=True)
class GateDecision:
    """Why the keyframe gate kept a frame and what it measured (written to the keyframe's sidecar as is).

    Overlaps are percent. The defaults describe a first keyframe (nothing to compare with)."""

    overlap_to_previous: float | None = None  # None for the first keyframe or after a gap
    inliers: int = 0
    gap_before: bool = False  # tracking was lost between the previous keyframe and this one
    reason: str = "first"  # first | overlap | tracking_lost | low_overlap | end_of_stream
    segment: int = 0  # tracking segment (a gap starts a new one)
    previous_index: int | None = None
    frames_since_previous: int = 0
    matches: int = 0
    dx_px: float | None = None
    dy_px: float | None = None
    R_displacement: float | None = None
    R_polygon: float | None = None
    sharpness: float = 0.0
    low_overlap: bool = False
    # where R came from: "image", or the telemetry prediction ("telemetry": the image held too little wall to
    # measure; "telemetry_veto": the poses overruled an image R >= Rth); None without a comparison
    overlap_source: str | None = None
    R_image: float | None = None
    R_telemetry: float | None = None
    prediction_miss_px: float | None = None
    background_matches_rejected: int = 0

    def as_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class Keyframe:
    """A kept frame: the image, its pose and mask, and the gate's decision; never changed after creation.

    ``telemetry_overlap_suspect``: the overlap the poses predict where they contradict the image's (the chain's
    cross-check, a new record made with ``dataclasses.replace``); None when they agree or were not checked."""

    frame: Frame
    pose: Pose | None
    mask: np.ndarray  # uint8 0/255 at full frame resolution, 255 = facade (ROI)
    decision: GateDecision = field(default_factory=GateDecision)
    pose_stale: bool = False
    telemetry_overlap_suspect: float | None = None

    @classmethod
    def of(cls, masked: MaskedFrame, decision: GateDecision) -> Keyframe:
        return cls(masked.frame, masked.pose, masked.mask, decision, masked.pose_stale)

    @property
    def index(self) -> int:
        return self.frame.index

    @property
    def image(self) -> np.ndarray:
        return self.frame.image

    @property
    def capture_time_s(self) -> float:
        return self.frame.capture_time_s

    @property
    def overlap_to_previous(self) -> float | None:
        return self.decision.overlap_to_previous

    @property
    def inliers(self) -> int:
        return self.decision.inliers

    @property
    def gap_before(self) -> bool:
        return self.decision.gap_before

    @property
    def overlap_suspect(self) -> bool:
        return self.telemetry_overlap_suspect is not None

"""Typed records passed between pipeline stages (capture -> tag -> mask -> gate -> spool -> stitch).

Stages exchange only these; none reaches into another stage's internals.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, fields
from enum import StrEnum

import numpy as np

from companion.attitude import gimbal_camera_angles


class GimbalSource(StrEnum):
    """Where a pose's gimbal angles came from."""

    TELEMETRY = "telemetry"  # the gimbal's own attitude report (GIMBAL_DEVICE_ATTITUDE_STATUS)
    PLAN = "plan"  # the mission's gimbal command, once the vehicle has passed it (no gimbal telemetry)


@dataclass(frozen=True)
class Pose:
    """Vehicle pose from telemetry, and the camera gimbal's angles. Angles in degrees; yaw clockwise from north.

    The gimbal is stabilised (no camera roll): ``gimbal_pitch_deg`` from the horizon (down negative),
    ``gimbal_yaw_deg`` relative to the vehicle's heading. Each is None when unknown (never a made-up 0);
    ``gimbal_source`` says where known ones came from.
    """

    time_s: float  # autopilot time (MAVLink time_boot_ms / 1000)
    lat: float
    lon: float
    alt_amsl_m: float
    relative_alt_m: float
    roll_deg: float
    pitch_deg: float
    yaw_deg: float
    velocity_ned_m_s: tuple[float, float, float] = (0.0, 0.0, 0.0)
    gimbal_pitch_deg: float | None = None
    mission_item: int = -1
    gimbal_yaw_deg: float | None = None
    gimbal_source: GimbalSource | None = None
    # the forward rangefinder's distance to what is ahead (DISTANCE_SENSOR, orientation forward), metres: the one
    # measure of the standoff that a GNSS bias does not move; None without a fresh, in-range reading
    range_forward_m: float | None = None

    def camera_angles(self) -> tuple[float, float, float]:
        """(yaw, pitch, roll) of the camera on its stabilised gimbal (``companion.attitude.gimbal_camera_angles``:
        an unknown gimbal angle is taken as level and forward)."""
        return gimbal_camera_angles(self.yaw_deg, self.gimbal_pitch_deg, self.gimbal_yaw_deg)

    def to_json(self) -> dict:
        """The one JSON form of a pose: telemetry-log rows, the spool's manifest and sidecars all use it."""
        return pose_json(**{f.name: getattr(self, f.name) for f in fields(self)})

    @classmethod
    def from_json(cls, row: dict) -> Pose | None:
        """A Pose from :meth:`to_json`'s form (a telemetry-log row or a spooled pose; extra keys are ignored);
        None when the row lacks a time, a position fix or an attitude."""
        keys = ("t_boot_s", "lat", "lon", "alt_amsl_m", "roll_deg", "pitch_deg", "yaw_deg")
        if row is None or any(row.get(k) is None for k in keys):
            return None
        source = row.get("gimbal_source")
        return cls(
            time_s=float(row["t_boot_s"]),
            lat=float(row["lat"]),
            lon=float(row["lon"]),
            alt_amsl_m=float(row["alt_amsl_m"]),
            relative_alt_m=float(row.get("rel_alt_m") or 0.0),
            roll_deg=float(row["roll_deg"]),
            pitch_deg=float(row["pitch_deg"]),
            yaw_deg=float(row["yaw_deg"]) % 360.0,
            velocity_ned_m_s=tuple(float(row.get(k) or 0.0) for k in ("vn_m_s", "ve_m_s", "vd_m_s")),
            gimbal_pitch_deg=_optional_float(row.get("gimbal_pitch_deg")),
            mission_item=int(row["mission_item"]) if row.get("mission_item") is not None else -1,
            gimbal_yaw_deg=_optional_float(row.get("gimbal_yaw_deg")),
            gimbal_source=GimbalSource(source) if source is not None else None,
            range_forward_m=_optional_float(row.get("range_forward_m")),
        )


def pose_json(
    *,
    time_s: float | None,
    lat: float | None,
    lon: float | None,
    alt_amsl_m: float | None,
    relative_alt_m: float | None,
    roll_deg: float | None,
    pitch_deg: float | None,
    yaw_deg: float | None,
    velocity_ned_m_s: tuple[float | None, float | None, float | None] = (None, None, None),
    gimbal_pitch_deg: float | None = None,
    mission_item: int = -1,
    gimbal_yaw_deg: float | None = None,
    gimbal_source: str | None = None,
    range_forward_m: float | None = None,
) -> dict:
    """Pose fields -> their JSON keys. The telemetry recorder calls it with what it has so far (None where a
    stream has not arrived yet); :meth:`Pose.to_json` with a whole pose. The keys are the telemetry log's columns
    (docs/FLIGHT.md), the one place they are spelled."""
    vn, ve, vd = velocity_ned_m_s
    return {
        "t_boot_s": time_s, "lat": lat, "lon": lon, "alt_amsl_m": alt_amsl_m, "rel_alt_m": relative_alt_m,
        "roll_deg": roll_deg, "pitch_deg": pitch_deg, "yaw_deg": yaw_deg, "vn_m_s": vn, "ve_m_s": ve, "vd_m_s": vd,
        "gimbal_pitch_deg": gimbal_pitch_deg, "gimbal_yaw_deg": gimbal_yaw_deg,
        "gimbal_source": None if gimbal_source is None else str(gimbal_source), "mission_item": mission_item,
        "range_forward_m": range_forward_m,
    }


def _optional_float(value) -> float | None:
    return None if value is None else float(value)


@dataclass(frozen=True)
class Frame:
    """One camera image as delivered by a source. ``image`` is BGR uint8 (OpenCV order)."""

    index: int
    capture_time_s: float
    image: np.ndarray


@dataclass(frozen=True)
class EncodedFrame:
    """A camera frame still as the camera compressed it (JPEG), with the size the camera declared.

    Why not decode on arrival: at 30 fps most frames are only tracked on a small working copy, and under load some
    are dropped from the backlog before the chain sees them. Decoding every 1280x720 JPEG in full costs about twice
    what a DCT-scaled half-size decode does, so the chain decodes a frame only when it takes it, at the working
    size, and decodes the full image only for the keyframes it spools (``companion.onboard.working``)."""

    index: int
    capture_time_s: float
    data: bytes
    width: int
    height: int


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


class GateReason(StrEnum):
    """Why the keyframe gate kept a frame (``GateDecision.reason``). A StrEnum so that the sidecar, the manifest
    and the reports keep the same strings, while the gate and its readers compare members, not typed-out text."""

    FIRST = "first"  # the stream's first keyframe: nothing to compare with
    OVERLAP = "overlap"  # the last frame at or above Rth, kept when the next fell below it
    TRACKING_LOST = "tracking_lost"  # the candidate (or, with none, the frame) where tracking against the key broke
    LOW_OVERLAP = "low_overlap"  # kept below Rth: no frame in between was at or above it
    END_OF_STREAM = "end_of_stream"  # the held candidate, kept when the stream ended
    END_OF_SEGMENT = "end_of_segment"  # the held candidate, kept when the scan was left
    NEW_SEGMENT = "new_segment"  # the first keyframe after the scan resumed


class OverlapSource(StrEnum):
    """Where an overlap R came from (``OverlapEstimate.source``, ``GateDecision.overlap_source``). A StrEnum: the
    sidecar and the reports keep the same strings, the gate and its readers compare members."""

    IMAGE = "image"  # the images' own match
    TELEMETRY = "telemetry"  # the poses' prediction: the image held too little wall to measure
    TELEMETRY_VETO = "telemetry_veto"  # the poses' prediction overruled an image R >= Rth


@dataclass(frozen=True)
class GateDecision:
    """Why the keyframe gate kept a frame and what it measured (written to the keyframe's sidecar as is).

    Overlaps are percent. The defaults describe a first keyframe (nothing to compare with)."""

    overlap_to_previous: float | None = None  # None for the first keyframe or after a gap
    inliers: int = 0
    gap_before: bool = False  # tracking was lost, or the scan left and resumed, since the previous keyframe
    reason: GateReason = GateReason.FIRST
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
    overlap_source: OverlapSource | None = None  # where R came from; None without a comparison
    R_image: float | None = None
    R_telemetry: float | None = None
    prediction_miss_px: float | None = None
    background_matches_rejected: int = 0

    def as_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class StandoffEstimate:
    """The camera-to-wall distance measured from the images at ``time_s`` (``companion.keyframes.standoff``):
    metres, one sigma, from ``measurements`` frame pairs of the last few seconds. ``source``: what measured it."""

    distance_m: float
    sigma_m: float
    measurements: int
    time_s: float
    source: str = "camera"

    def as_json(self) -> dict:
        """The spool's keys (sidecar and manifest line); :func:`standoff_json` gives them for no estimate."""
        return standoff_json(self)


def standoff_json(estimate: StandoffEstimate | None) -> dict:
    """``standoff_measured_m``, ``standoff_sigma_m``, ``standoff_source`` (None each without an estimate)."""
    if estimate is None:
        return {"standoff_measured_m": None, "standoff_sigma_m": None, "standoff_source": None}
    return {"standoff_measured_m": estimate.distance_m, "standoff_sigma_m": estimate.sigma_m,
            "standoff_source": estimate.source}


@dataclass(frozen=True)
class Keyframe:
    """A kept frame: the image, its pose and mask, and the gate's decision; never changed after creation.

    ``telemetry_overlap_suspect``: the overlap the poses predict where they contradict the image's (the chain's
    cross-check, a new record made with ``dataclasses.replace``); None when they agree or were not checked.
    ``standoff``: the chain's measured camera-to-wall distance when the keyframe was spooled (None: none measured
    in the last few seconds, or no chain measuring it)."""

    frame: Frame
    pose: Pose | None
    mask: np.ndarray  # uint8 0/255 at full frame resolution, 255 = facade (ROI)
    decision: GateDecision = field(default_factory=GateDecision)
    pose_stale: bool = False
    telemetry_overlap_suspect: float | None = None
    standoff: StandoffEstimate | None = None  # the measured standoff when it was spooled (the chain's estimate)

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

"""The wall's image motion between two frames, predicted from the two frames' telemetry poses.

Why: the image overlap is measured on whatever features RANSAC agrees on. Where the ROI holds a strongly textured
far background (the mask kept it, or no mask), the static background can win RANSAC and say R 96-99 % while the
wall has moved half a frame. The wall is a plane at a known place (the facade frame) and the camera's motion
between two frames a second apart is well measured even when absolute GNSS is off by a metre: a constant bias
cancels in the relative motion. So the poses predict where each wall point of frame a lands in frame b (a plane
homography), which tells the wall's inliers from the background's, and gives the overlap when the image cannot.

Camera model: a pinhole with square pixels and the principal point at the image centre; a stabilised gimbal
(camera yaw = vehicle yaw, camera pitch = ``gimbal_pitch_deg``, no camera roll), as the stitcher assumes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from companion.attitude import camera_rotation_enu
from companion.errors import CompanionError
from companion.geo import FacadeFrame
from companion.polygons import convex_intersection_area, polygon_area
from companion.records import Pose
from companion.wall_footprint import corner_footprint


def intrinsics(hfov_deg: float, width: int, height: int) -> np.ndarray:
    """The pinhole matrix of the module's camera model (square pixels, principal point at the image centre)."""
    f = (width / 2.0) / math.tan(math.radians(hfov_deg) / 2.0)
    return np.array([[f, 0.0, width / 2.0], [0.0, f, height / 2.0], [0.0, 0.0, 1.0]])


def pose_camera(frame: FacadeFrame, pose: Pose) -> tuple[np.ndarray, np.ndarray]:
    """(camera centre in facade coordinates (along, out, up), rotation facade <- camera) of a telemetry pose."""
    de, dn = frame.along_enu
    oe, on = frame.out_enu
    basis = np.array([[de, oe, 0.0], [dn, on, 0.0], [0.0, 0.0, 1.0]])  # columns: along, out, up in ENU
    centre = np.array([float(v) for v in frame.geodetic_to_facade(pose.lat, pose.lon, pose.alt_amsl_m)])
    yaw, pitch, roll = pose.camera_angles()
    return centre, basis.T @ camera_rotation_enu(yaw_deg=yaw, pitch_deg=pitch, roll_deg=roll)


def wall_to_image(K: np.ndarray, centre: np.ndarray, rot: np.ndarray) -> np.ndarray:
    """Homography from wall-plane coordinates (along_m, up_m, 1) to image pixels."""
    to_cam = np.array([[1.0, 0.0, -centre[0]], [0.0, 0.0, -centre[1]], [0.0, 1.0, -centre[2]]])
    return K @ rot.T @ to_cam


@dataclass(frozen=True)
class WallMotion:
    """Where the wall plane seen in frame a appears in frame b, predicted from the two poses.

    ``H`` maps frame a's pixels to frame b's pixels (full resolution) for points on the wall plane;
    ``overlap_percent`` is the share of a's footprint on the wall plane that b's footprint covers (the simulator's
    true overlap); ``dx``/``dy`` the predicted shift of a's image centre (b minus a, px).
    """

    H: np.ndarray
    overlap_percent: float | None  # None: not asked for (``predict(..., overlap=False)``)
    dx: float
    dy: float
    baseline_m: float  # camera travel between the two poses

    def map_points(self, points: np.ndarray) -> np.ndarray:
        """Frame-a pixels (N x 2) -> predicted frame-b pixels of the same wall points."""
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        homog = np.hstack([pts, np.ones((len(pts), 1))]) @ self.H.T
        return homog[:, :2] / homog[:, 2:3]


@dataclass(frozen=True)
class WallMotionPredictor:
    """Predicts the wall's image motion for one wall and one lens.

    ``standoff_m``: when given, the wall's distance is taken from the plan and only the poses' RELATIVE position
    is used (both cameras are shifted together so their mean distance to the wall is the standoff): a GNSS bias
    towards or away from the wall would otherwise scale every predicted shift. None: the poses' own distance.
    """

    frame: FacadeFrame
    hfov_deg: float
    standoff_m: float | None = None
    # pose -> (centre, rotation): the tracker predicts from the previous frame's pose and the keyframe's on every
    # frame, so each pose is turned into a camera once, not two to four times (bounded, oldest dropped)
    _cameras: dict = field(default_factory=dict, init=False, repr=False, compare=False, hash=False)

    def __post_init__(self) -> None:
        if not 1.0 < self.hfov_deg < 179.0:
            raise CompanionError(
                f"hfov_deg={self.hfov_deg} is outside (1, 179)", "give the camera's horizontal field of view in degrees"
            )
        if self.standoff_m is not None and self.standoff_m <= 0.1:
            raise CompanionError(f"standoff_m={self.standoff_m} is not a distance in front of the wall",
                                 "give the planned camera-to-wall distance in metres (e.g. 4.0)")

    def _camera(self, pose: Pose) -> tuple[np.ndarray, np.ndarray]:
        """(camera centre in facade coordinates, rotation facade <- camera)."""
        known = self._cameras.get(pose)
        if known is None:
            known = self._cameras[pose] = self._camera_of(pose)
            while len(self._cameras) > 64:
                self._cameras.pop(next(iter(self._cameras)))
        return known

    def _camera_of(self, pose: Pose) -> tuple[np.ndarray, np.ndarray]:
        return pose_camera(self.frame, pose)

    @staticmethod
    def _wall_to_image(K: np.ndarray, centre: np.ndarray, rot: np.ndarray) -> np.ndarray:
        return wall_to_image(K, centre, rot)

    def predict(self, a: Pose | None, b: Pose | None, width: int, height: int, *,
                overlap: bool = True) -> WallMotion | None:
        """The wall's motion from frame a to frame b (``width`` x ``height`` px); None without a usable geometry
        (a pose missing or not finite, a camera behind the wall plane or looking past it). ``overlap=False``: the
        homography and shift only, without the footprints' intersection (the tracker's frame-to-frame first
        guess needs no overlap; the polygon clipping is most of a prediction's CPU)."""
        if a is None or b is None:
            return None
        values = (a.lat, a.lon, a.alt_amsl_m, *a.camera_angles(), b.lat, b.lon, b.alt_amsl_m, *b.camera_angles())
        if not all(math.isfinite(float(v)) for v in values):
            return None
        (ca, ra), (cb, rb) = self._camera(a), self._camera(b)
        if self.standoff_m is not None:
            shift = self.standoff_m - (ca[1] + cb[1]) / 2.0
            ca, cb = ca + [0.0, shift, 0.0], cb + [0.0, shift, 0.0]
        if ca[1] <= 0.1 or cb[1] <= 0.1:
            return None
        K = intrinsics(self.hfov_deg, width, height)
        footprints = [corner_footprint(K, width, height, c, r) for c, r in ((ca, ra), (cb, rb))]
        if footprints[0] is None or footprints[1] is None:  # a corner ray does not reach the wall ahead
            return None
        area_a = polygon_area(footprints[0])
        if area_a <= 0.0:
            return None
        share = (float(min(100.0, 100.0 * convex_intersection_area(footprints[1], footprints[0]) / area_a))
                 if overlap else None)
        Ha, Hb = self._wall_to_image(K, ca, ra), self._wall_to_image(K, cb, rb)
        H = Hb @ np.linalg.inv(Ha)
        H = H / H[2, 2]
        motion = WallMotion(H, share, 0.0, 0.0, float(np.linalg.norm(cb - ca)))
        centre_b = motion.map_points(np.array([[width / 2.0, height / 2.0]]))[0]
        return WallMotion(H, motion.overlap_percent, float(centre_b[0] - width / 2.0),
                          float(centre_b[1] - height / 2.0), motion.baseline_m)

"""Where a photo can show the wall at all: the mission's wall rectangle projected with the photo's pose.

Why: the network alone calls a building beyond the wall's end or the sky above its roof line near on photos it
never saw (issue 27). Where the photo has a pose (EXIF GPS + gimbal angles) and the mission gives the wall (start,
end, ground to ``height_m``), every pixel outside the wall's projection is background whatever the network says:
the network decides only inside that bound.

The pose is the vehicle's estimate, not the truth: GNSS absolute position is off by 1-2 m for minutes, so the bound
is the union of the wall's projections from every camera centre in a box of ``sigmas`` x the position's standard
deviation around the estimate (horizontally 1.5 m like the stitcher's ``gnss_sigma_m``; vertically the barometric
relative altitude, better), grown by the attitude's uncertainty in pixels. The projection of a convex set (the wall
rectangle swept over the box of centres) is convex, so the hull of the 32 projected corners is that union exactly
(parts behind the camera clipped first). A metre of position error moves the wall's image by f x 1 m / standoff: the
bound is loose at 4 m (a 3 m margin is most of a frame) and tight on sparse stills 13-31 m away.

Facade coordinates (along_m, out_m, up_m) as in companion/geo.py; the wall is ``out_m = 0``, ``0 <= along_m <=
length_m``, ``0 <= up_m <= height_m``; a camera is its centre and its rotation facade <- camera (OpenCV axes).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import cv2
import numpy as np

from companion.errors import CompanionError
from companion.polygons import clip_half_plane

NEAR_M = 0.05  # wall points nearer the camera plane than this are not projected (they lie outside any image)


@dataclass(frozen=True)
class WallExtent:
    """The mission's wall: ``length_m`` from start to end along the wall, ``height_m`` from the ground up."""

    length_m: float
    height_m: float

    def __post_init__(self) -> None:
        if not (self.length_m > 0 and self.height_m > 0):
            raise CompanionError(f"wall {self.length_m} x {self.height_m} m", "give a positive wall length and height")


@dataclass(frozen=True)
class PoseUncertainty:
    """Standard deviations of the pose estimate; the bound holds for errors up to ``sigmas`` of them."""

    horizontal_m: float = 1.5  # GNSS absolute position (the stitcher's gnss_sigma_m)
    vertical_m: float = 0.5  # barometric relative altitude; GNSS altitude alone is worse (photo_pose.py: 3 m)
    attitude_deg: float = 1.0  # gimbal yaw / pitch / roll as recorded
    sigmas: float = 2.0


@dataclass(frozen=True)
class CameraView:
    """One photo's camera: intrinsics at the photo's size, centre and rotation (facade <- camera)."""

    K: np.ndarray
    width: int
    height: int
    centre: np.ndarray  # (along_m, out_m, up_m)
    rotation: np.ndarray  # 3x3, facade <- camera


def frontal_view(focal_px: float, width: int, height: int, along_m: float, out_m: float, up_m: float) -> CameraView:
    """A level camera looking straight at the wall from ``(along_m, out_m, up_m)`` (tests, benchmarks)."""
    K = np.array([[focal_px, 0.0, width / 2.0], [0.0, focal_px, height / 2.0], [0.0, 0.0, 1.0]])
    rotation = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, -1.0, 0.0]])  # x -> along, y -> down, z -> wall
    return CameraView(K, width, height, np.array([along_m, out_m, up_m], float), rotation)


def _projected_corners(view: CameraView, wall: WallExtent, centre: np.ndarray) -> np.ndarray:
    """Image points of the wall rectangle's part in front of a camera at ``centre`` (empty when none is)."""
    R = view.rotation
    rect = np.array([[0.0, 0.0], [wall.length_m, 0.0], [wall.length_m, wall.height_m], [0.0, wall.height_m]])
    forward = R[:, 2]  # camera z in facade axes; depth of wall point (a, 0, u) = forward . (X - C)
    normal = (forward[0], forward[2])
    offset = -float(forward @ centre) - NEAR_M
    poly = clip_half_plane(rect, normal, offset)
    if len(poly) < 3:
        return np.zeros((0, 2))
    points = np.column_stack([poly[:, 0], np.zeros(len(poly)), poly[:, 1]])
    cam = (points - centre) @ R  # rows: R^T (X - C)
    uvw = cam @ view.K.T
    return uvw[:, :2] / uvw[:, 2:3]


def _fill_convex(points: np.ndarray, width: int, height: int) -> np.ndarray:
    """uint8 0/255 mask of the convex hull of ``points`` (clipped to a box around the image first, so rays
    grazing the wall plane do not overflow the integer raster)."""
    hull = cv2.convexHull(points.astype(np.float32)).reshape(-1, 2).astype(np.float64)
    for normal, offset in (((1, 0), width), ((-1, 0), 2 * width), ((0, 1), height), ((0, -1), 2 * height)):
        hull = clip_half_plane(hull, normal, float(offset))
        if len(hull) < 3:
            return np.zeros((height, width), np.uint8)
    mask = np.zeros((height, width), np.uint8)
    cv2.fillConvexPoly(mask, np.round(hull * 16).astype(np.int32), 255, lineType=cv2.LINE_8, shift=4)
    return mask


def wall_bound(view: CameraView, wall: WallExtent, uncertainty: PoseUncertainty | None = None) -> np.ndarray | None:
    """uint8 0/255 (photo size): 255 where the wall can be for any pose within the uncertainty; None when that is
    the whole photo (nothing to cut) or the camera may be at or behind the wall plane (no bound can be trusted)."""
    u = uncertainty or PoseUncertainty()
    h, v = u.sigmas * u.horizontal_m, u.sigmas * u.vertical_m
    centre = np.asarray(view.centre, float)
    if centre[1] - h <= NEAR_M:
        return None
    points = [_projected_corners(view, wall, centre + np.array(d))
              for d in itertools.product((-h, h), (-h, h), (-v, v))]
    points = np.concatenate(points)
    if len(points) < 3:
        return np.zeros((view.height, view.width), np.uint8)
    mask = _fill_convex(points, view.width, view.height)
    margin = math.ceil(float(view.K[0, 0]) * math.tan(math.radians(u.sigmas * u.attitude_deg))) + 1
    if margin > 0 and mask.any():
        mask = cv2.dilate(mask, cv2.getStructuringElement(cv2.MORPH_RECT, (2 * margin + 1, 2 * margin + 1)))
    return None if mask.all() else mask


def apply_bound(mask: np.ndarray, bound: np.ndarray | None) -> np.ndarray:
    """The mask with everything outside the bound cut (the mask itself when there is no bound)."""
    return mask if bound is None else cv2.bitwise_and(mask, bound)

"""Homography helpers and the telemetry prior: where a camera pose says each image lands on the wall plane.

Coordinates used throughout the worker:
  * image-normalised: ``((x - cx) / f, (y - cy) / f)`` so that homographies are well conditioned;
  * plane: ``(along_m, up_m)`` on the facade plane (geo.py convention), metres.
"""

from __future__ import annotations

import numpy as np
import pymap3d

from companion.polygons import polygon_area
from companion.stitch.inputs import CameraPose, FacadeGeometry


def apply_h(H: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Maps (N, 2) points by a 3x3 homography."""
    pts = np.asarray(pts, dtype=float).reshape(-1, 2)
    q = pts @ H[:, :2].T + H[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        return q[:, :2] / q[:, 2:3]


def prior_plane_from_image(pose: CameraPose, facade: FacadeGeometry, out_shift_m: float = 0.0) -> np.ndarray:
    """Homography image-normalised -> plane (along_m, up_m) induced by the wall plane for this camera pose.

    ``out_shift_m`` moves the camera that far out from the wall (negative: towards it) before projecting: the
    correction the measured wall distance makes to a GNSS position that is biased across the wall
    (``wall_distance.py``)."""
    c = camera_centre_enu(pose, facade)
    oe, on = facade.frame.out_enu
    c = c + out_shift_m * np.array([oe, on, 0.0])
    de, dn = facade.frame.along_enu
    a = np.array([de, dn, 0.0])
    u = np.array([0.0, 0.0, 1.0])
    img_from_plane = pose.R_enu_from_cam.T @ np.column_stack((a, u, -c))
    H = np.linalg.inv(img_from_plane)
    return H / H[2, 2]


def camera_centre_enu(pose: CameraPose, facade: FacadeGeometry) -> np.ndarray:
    """The camera's position (ENU metres from the wall's start on the ground) as its telemetry gives it."""
    o = facade.frame.origin
    return np.array(pymap3d.geodetic2enu(pose.lat, pose.lon, pose.alt_amsl_m, o.lat, o.lon, o.alt_amsl_m), dtype=float)


def camera_distance_to_wall(pose: CameraPose, facade: FacadeGeometry) -> float:
    e, n, _ = camera_centre_enu(pose, facade)
    _, out, _ = facade.frame.enu_to_facade(e, n, 0.0)
    return float(out)


def reference_plane_from_image(scale_m: float) -> np.ndarray:
    """Without telemetry: the first keyframe defines the plane (x right = along, y down = -up) at ``scale_m``."""
    return np.array([[scale_m, 0.0, 0.0], [0.0, -scale_m, 0.0], [0.0, 0.0, 1.0]])


def is_sane_homography(H: np.ndarray, corners: np.ndarray, *, max_area_ratio: float = 4.0) -> bool:
    """Rejects degenerate/implausible pairwise homographies: folded, mirrored, vanishing or extreme scale."""
    if not np.all(np.isfinite(H)):
        return False
    q = corners @ H[:, :2].T + H[:, 2]
    if np.any(q[:, 2] <= 1e-6 * np.abs(q[:, 2]).max()):
        return False  # a corner goes through the horizon line
    p = q[:, :2] / q[:, 2:3]

    # convex and same orientation as the input quadrilateral
    def cross_signs(poly):
        d1 = np.roll(poly, -1, axis=0) - poly
        d2 = np.roll(poly, -2, axis=0) - np.roll(poly, -1, axis=0)
        return np.sign(d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0])

    s_in, s_out = cross_signs(corners), cross_signs(p)
    if not (np.all(s_out == s_out[0]) and s_out[0] == s_in[0]):
        return False

    ratio = polygon_area(p) / max(polygon_area(corners), 1e-12)
    return bool(1.0 / max_area_ratio < ratio < max_area_ratio)

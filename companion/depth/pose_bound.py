"""The wall bound for frames that carry the autopilot's pose: the onboard chain and ``companion cull``.

Why: ``companion mask --mission`` cuts each photo to the mission's wall rectangle projected with the photo's pose
(``photo_pose.py``, ``wall_bound.py``), so that the building beyond the wall's end and the sky above its roof line are
background whatever the network says (issue 27 item 2). The chain's frames are tagged with the same kind of pose
(position, barometric height above take-off, camera heading and tilt) and it always has the mission, so it gets the
same bound. On stills 13-30 m out it matters: parallax keeps as wall whatever lies within 2.5 standoffs of the camera
(``ParallaxParams.max_near_standoffs``, which a wall 30 m away needs), so a building 40 m behind such a wall, beyond
its end, was kept, and the stitcher matched it (bench/sparse_stills.py's background inliers).

Only beyond the standoff the parallax window was made for (``ParallaxParams.baseline_standoff_m``, the paper's 4 m):
there the bound's 2-sigma position margin (3 m along and across the wall) reaches past most of a frame, and the
frames beyond the wall's ends and above its roof margin are already left unjudged by the scan's scope
(``companion/keyframes/gate_scope.py``), so the bound would only move the scan's masks by a few border pixels.

The pose is the vehicle's estimate, biased by GNSS for minutes: ``wall_bound`` takes the union over every camera
centre within 2 sigma (1.5 m horizontally) and 2 x 1 deg of attitude, so a constant bias of 1-2 m never cuts wall.
The height is the pose's AMSL altitude against the mission's ground, as the rest of the chain places a frame
(``ScanScope``, ``SequenceParallax``), with the GNSS vertical sigma (3 m, ``photo_pose.GNSS_VERTICAL_SIGMA_M``): not
the relative altitude a tagged photo's bound uses, because real PX4 reports a relative altitude that jumps by up to
1.5 m between samples while its AMSL altitude is smooth (``../shared/notes/real-firmware.md``), and the AMSL
altitude's origin is the autopilot's GNSS fix at take-off.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from companion.depth.photo_pose import GNSS_VERTICAL_SIGMA_M, MissionWall, PhotoPose, camera_view
from companion.depth.wall_bound import PoseUncertainty, wall_bound
from companion.records import Pose


@dataclass(frozen=True)
class TelemetryWallBound:
    """Where a frame taken at a telemetry pose can show the mission's wall (``wall_bound``'s 0/255 mask)."""

    wall: MissionWall
    uncertainty: PoseUncertainty = field(default_factory=lambda: PoseUncertainty(vertical_m=GNSS_VERTICAL_SIGMA_M))

    @classmethod
    def for_mission(cls, mission, beyond_standoff_m: float | None = 4.0) -> TelemetryWallBound | None:
        """The bound of ``mission``'s wall when its standoff is beyond ``beyond_standoff_m`` (None: at any
        standoff); None at or inside it (module docstring: why not at the paper's 4 m)."""
        if beyond_standoff_m is not None and not float(mission.standoff_m) > beyond_standoff_m:
            return None
        return cls(MissionWall.from_mission(mission))

    def __call__(self, pose: Pose | None, shape: tuple[int, ...]) -> np.ndarray | None:
        """The bound at the frame's (height, width): None without a pose, or when the whole frame may be wall or
        the camera may be at or behind the wall plane (nothing to cut)."""
        if pose is None:
            return None
        yaw, pitch, roll = pose.camera_angles()
        photo = PhotoPose(pose.lat, pose.lon, pose.alt_amsl_m, None, yaw % 360.0, pitch, roll, None)
        return wall_bound(camera_view(photo, self.wall, int(shape[1]), int(shape[0])), self.wall.extent,
                          self.uncertainty)

"""The telemetry a fast (kinematic) recording would have received: rows in the format of
``companion fly --telemetry-log`` (companion/flight/telemetry_log.py), so ``companion cull`` reads a fast recording
exactly as it reads a flown one.

What the flight code stores, the rows here store the same way: time as the autopilot's ``time_boot_ms`` (whole
milliseconds; the kinematic flight's clock starts at 0 at the first scan waypoint), position as
GLOBAL_POSITION_INT quantises it (1e-7 degree, millimetre altitude, centimetre per second velocity), ``t_wall`` the
companion's clock when the row was written. The kinematic model has a stabilised camera and no body dynamics:
the vehicle yaw is the camera's, roll and pitch are the camera's small attitude wobble around the gimbal pitch,
and the gimbal pitch is the mission's command (``gimbal_source: plan``), as a flown log without gimbal telemetry
has it once the vehicle passed the gimbal item. There is no mission progress (``mission_item`` -1, as the flight
code writes before the autopilot reports one).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

from companion.records import GimbalSource, pose_json
from sim.camera.trajectory import KinematicFlight


def telemetry_rows(flight: KinematicFlight, t_start_s: float, t_end_s: float, *, home_alt_amsl_m: float,
                   rate_hz: float = 10.0, epoch_unix_s: float = 0.0) -> list[dict]:
    """Samples every ``1 / rate_hz`` s of autopilot time covering ``[t_start_s, t_end_s]`` (one sample past each
    end, so a frame at either end lies between two samples)."""
    if rate_hz <= 0:
        raise ValueError(f"rate_hz={rate_hz} must be positive")
    k0 = math.floor(t_start_s * rate_hz) - 1
    k1 = math.ceil(t_end_s * rate_hz) + 1
    rows = []
    for k in range(max(k0, 0), k1 + 1):
        t = round(k / rate_hz, 3)  # time_boot_ms
        pose = flight.pose(t)
        ve, vn, vu = (float(v) for v in pose.velocity_enu_m_s)
        alt = round(pose.alt_amsl_m, 3)
        row = pose_json(
            time_s=t, lat=round(pose.lat * 1e7) / 1e7, lon=round(pose.lon * 1e7) / 1e7, alt_amsl_m=alt,
            relative_alt_m=round(alt - home_alt_amsl_m, 3), roll_deg=pose.roll_deg,
            pitch_deg=pose.pitch_deg - flight.gimbal_pitch_deg, yaw_deg=pose.yaw_deg % 360.0,
            velocity_ned_m_s=(round(vn, 2), round(ve, 2), round(-vu, 2)), mission_item=-1,
            gimbal_pitch_deg=flight.gimbal_pitch_deg, gimbal_yaw_deg=0.0, gimbal_source=GimbalSource.PLAN,
        )
        rows.append({"t_wall": round(epoch_unix_s + t, 4), **row, "mission_total": 0, "flight_mode": "MISSION",
                     "armed": True, "in_air": True})
    return rows


def write_telemetry_log(path: str | Path, rows: list[dict]) -> Path:
    path = Path(path)
    path.write_text("".join(json.dumps(row) + "\n" for row in rows), encoding="utf-8")
    return path

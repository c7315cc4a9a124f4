"""A SITL's own truth message (SIM_STATE, id 108) as a line of the camera's pose channel: pure conversions.

Why: a simulated camera flown beside a real firmware's SITL must render from that simulator's TRUE pose, not from
the autopilot's estimate (GLOBAL_POSITION_INT), or a GNSS bias the SITL applies (ArduPilot SIM_GPS1_GLTCH_*,
our ``--gnss-bias``) never shows in the images. ArduPilot's SITL reports its physics state in SIM_STATE
(libraries/SITL/SITL.cpp ``SIM::sim_state_send``) with these conventions, which this module undoes:

* roll, pitch, yaw in radians, yaw wrapped to -pi..pi (the pose channel wants degrees, yaw 0..360 clockwise from
  north);
* ``lat`` / ``lon`` are floats carrying degrees * 1e7 (a known quirk: the message says degrees), float32 on the
  wire, so only good to ~0.3 m; the extension fields ``lat_int`` / ``lon_int`` (int32 degE7) carry the exact
  value. An extension a sender leaves out reads 0, so both 0 means 'absent'; then the floats are taken, divided
  by 1e7 when they are too large to be degrees (another sender may well send real degrees, as MAVLink says);
* ``alt`` metres AMSL; ``vn``, ``ve``, ``vd`` m/s NED;
* no time stamp: the autopilot clock (``t_s``) comes from the latest ``time_boot_ms`` of another message.

The gimbal is not in SIM_STATE: the pose carries the latest gimbal report when the vehicle sends one, else the
angles the bridge was told (level and forward: our missions command the gimbal level).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

from companion.flight.telemetry_log import gimbal_from_status

DEG_E7 = 1e7


@dataclass(frozen=True)
class Gimbal:
    """Camera gimbal angles as the pose channel has them: pitch from the horizon (down negative), yaw relative to
    the vehicle's heading."""

    pitch_deg: float = 0.0
    yaw_deg: float = 0.0


@dataclass(frozen=True)
class Home:
    lat: float
    lon: float
    alt_amsl_m: float

    def as_dict(self) -> dict:
        return {"lat": self.lat, "lon": self.lon, "alt_amsl_m": self.alt_amsl_m}


def sim_state_lat_lon(fields: Mapping) -> tuple[float, float]:
    """(lat, lon) degrees of a SIM_STATE: from the int32 extensions when sent, else from the float fields, read as
    degE7 when either is out of the degree range (ArduPilot's quirk) and as degrees otherwise."""
    lat_int, lon_int = int(fields.get("lat_int") or 0), int(fields.get("lon_int") or 0)
    if lat_int or lon_int:
        return lat_int / DEG_E7, lon_int / DEG_E7
    lat, lon = float(fields["lat"]), float(fields["lon"])
    if abs(lat) > 90.0 or abs(lon) > 180.0:
        return lat / DEG_E7, lon / DEG_E7
    return lat, lon


def yaw_0_360(yaw_rad: float) -> float:
    """A yaw in radians (ArduPilot sends -pi..pi) as degrees clockwise from north in [0, 360)."""
    return math.degrees(float(yaw_rad)) % 360.0


def pose_from_sim_state(fields: Mapping, *, t_s: float, gimbal: Gimbal = Gimbal(), home: Home | None = None
                        ) -> dict | None:
    """The pose-channel line (the keys ``SimVehicle.true_pose()`` writes and ``PoseListener`` reads) of one
    SIM_STATE received when the autopilot clock read ``t_s``; None when its position is not finite (a SITL that
    has not placed its vehicle yet)."""
    lat, lon = sim_state_lat_lon(fields)
    alt = float(fields["alt"])
    if not all(math.isfinite(v) for v in (lat, lon, alt)):
        return None
    pose = {
        "t_s": round(float(t_s), 4), "time_boot_ms": int(round(t_s * 1000)),
        "lat": lat, "lon": lon, "alt_amsl_m": alt,
        "vn_m_s": float(fields["vn"]), "ve_m_s": float(fields["ve"]), "vd_m_s": float(fields["vd"]),
        "roll_deg": math.degrees(float(fields["roll"])), "pitch_deg": math.degrees(float(fields["pitch"])),
        "yaw_deg": yaw_0_360(fields["yaw"]),
        "gimbal_pitch_deg": float(gimbal.pitch_deg), "gimbal_yaw_deg": float(gimbal.yaw_deg),
        "source": "SIM_STATE",
    }
    if home is not None:
        pose["home"] = home.as_dict()
    return pose


def gimbal_from_device_status(fields: Mapping, vehicle_yaw_deg: float | None) -> Gimbal | None:
    """The gimbal of a GIMBAL_DEVICE_ATTITUDE_STATUS (its yaw made relative to the vehicle when the flags say it is
    in the earth frame); None when that yaw cannot be made relative (no vehicle yaw yet)."""
    pitch, yaw = gimbal_from_status(dict(fields), vehicle_yaw_deg)
    if yaw is None or not (math.isfinite(pitch) and math.isfinite(yaw)):
        return None
    return Gimbal(pitch_deg=pitch, yaw_deg=yaw)


def gimbal_from_mount_status(fields: Mapping) -> Gimbal:
    """The gimbal of an ArduPilot MOUNT_STATUS (older firmware): pointing_a pitch and pointing_c yaw (relative to
    the vehicle), centidegrees."""
    return Gimbal(pitch_deg=float(fields["pointing_a"]) / 100.0, yaw_deg=float(fields["pointing_c"]) / 100.0)


def home_from_position(fields: Mapping) -> Home:
    """Home of a HOME_POSITION message (degE7, millimetres AMSL)."""
    return Home(lat=int(fields["latitude"]) / DEG_E7, lon=int(fields["longitude"]) / DEG_E7,
                alt_amsl_m=int(fields["altitude"]) / 1000.0)

"""Keyframe JPEGs tagged the way photogrammetry tools read them (which tool reads which tag: docs/OUTPUTS.md).

EXIF: Make/Model from the mission's camera, FocalLength with FocalPlaneX/YResolution (the focal in pixels, exact
in COLMAP and OpenDroneMap), image size, GPS position/altitude, DateTimeOriginal with SubSecTime(Original) in UTC.
XMP: Pix4D's ``Camera:Yaw/Pitch/Roll`` (pitch 90 = horizontal camera, the convention OpenDroneMap normalises to),
DJI's ``drone-dji`` flight attitude and altitudes, and DJI's gimbal angles only for DJI-convention makes (a
non-DJI make with ``GimbalPitchDegree`` = 0 reads as a nadir camera in OpenDroneMap).
"""

from __future__ import annotations

import datetime as dt
import io
import math
from fractions import Fraction

import cv2
import numpy as np
import piexif

from companion.records import Pose
from companion.spool.camera import CameraTags

XMP_HEADER = b"http://ns.adobe.com/xap/1.0/\x00"
FOCAL_PLANE_UNIT_MM = 4  # EXIF FocalPlaneResolutionUnit: 2 inch, 3 cm, 4 mm, 5 um


def _rational(value: float, denom: int = 10000) -> tuple[int, int]:
    f = Fraction(value).limit_denominator(denom)
    return f.numerator, f.denominator


def _dms(deg: float) -> tuple[tuple[int, int], tuple[int, int], tuple[int, int]]:
    deg = abs(deg)
    d = int(deg)
    m = int((deg - d) * 60)
    s = (deg - d - m / 60) * 3600
    return (d, 1), (m, 1), (int(round(s * 10000)), 10000)


def exif_bytes(
    pose: Pose | None, capture_utc: dt.datetime | None, camera: CameraTags, width_px: int, height_px: int
) -> bytes:
    """EXIF for one keyframe; ``capture_utc`` None (no wall clock known) leaves the time tags out, never 1970."""
    zeroth: dict = {piexif.ImageIFD.Orientation: 1}
    if camera.make:
        zeroth[piexif.ImageIFD.Make] = camera.make
    if camera.model:
        zeroth[piexif.ImageIFD.Model] = camera.model
    exif: dict = {
        piexif.ExifIFD.PixelXDimension: int(width_px),
        piexif.ExifIFD.PixelYDimension: int(height_px),
    }
    if capture_utc is not None:
        stamp = capture_utc.strftime("%Y:%m:%d %H:%M:%S")
        subsec = f"{capture_utc.microsecond // 1000:03d}"
        zeroth[piexif.ImageIFD.DateTime] = stamp
        exif.update({
            piexif.ExifIFD.DateTimeOriginal: stamp,
            piexif.ExifIFD.DateTimeDigitized: stamp,
            piexif.ExifIFD.SubSecTime: subsec,
            piexif.ExifIFD.SubSecTimeOriginal: subsec,
            piexif.ExifIFD.SubSecTimeDigitized: subsec,
            piexif.ExifIFD.OffsetTime: "+00:00",
            piexif.ExifIFD.OffsetTimeOriginal: "+00:00",
            piexif.ExifIFD.OffsetTimeDigitized: "+00:00",
        })
    focal = camera.focal_for(width_px, height_px)
    if focal is not None:
        focal_mm, px_per_mm_x, px_per_mm_y = focal
        exif[piexif.ExifIFD.FocalLength] = _rational(focal_mm, 100000)
        exif[piexif.ExifIFD.FocalPlaneXResolution] = _rational(px_per_mm_x, 100000)
        exif[piexif.ExifIFD.FocalPlaneYResolution] = _rational(px_per_mm_y, 100000)
        exif[piexif.ExifIFD.FocalPlaneResolutionUnit] = FOCAL_PLANE_UNIT_MM
    gps = {}
    if pose is not None and all(math.isfinite(v) for v in (pose.lat, pose.lon, pose.alt_amsl_m)):
        gps = {
            piexif.GPSIFD.GPSVersionID: (2, 3, 0, 0),
            piexif.GPSIFD.GPSLatitudeRef: "N" if pose.lat >= 0 else "S",
            piexif.GPSIFD.GPSLatitude: _dms(pose.lat),
            piexif.GPSIFD.GPSLongitudeRef: "E" if pose.lon >= 0 else "W",
            piexif.GPSIFD.GPSLongitude: _dms(pose.lon),
            piexif.GPSIFD.GPSAltitudeRef: 0 if pose.alt_amsl_m >= 0 else 1,
            piexif.GPSIFD.GPSAltitude: _rational(abs(pose.alt_amsl_m), 1000),
        }
        if capture_utc is not None:
            gps[piexif.GPSIFD.GPSTimeStamp] = (
                (capture_utc.hour, 1),
                (capture_utc.minute, 1),
                _rational(capture_utc.second + capture_utc.microsecond / 1e6, 1000),
            )
            gps[piexif.GPSIFD.GPSDateStamp] = capture_utc.strftime("%Y:%m:%d")
    return piexif.dump({"0th": zeroth, "Exif": exif, "GPS": gps, "1st": {}, "thumbnail": None})


def _dji_degrees(angle: float) -> float:
    """An angle in DJI's XMP range (-180, 180], rounded to the 0.01 deg written (359.9997 -> 0.00, never 360.00)."""
    wrapped = -((-round(angle, 2) + 180.0) % 360.0 - 180.0)
    return wrapped + 0.0  # no -0.00


def xmp_packet(pose: Pose | None, camera: CameraTags | None = None) -> bytes:
    if pose is None:
        return b""
    camera = camera or CameraTags()
    cam_yaw, cam_pitch, _ = pose.camera_angles()  # the gimbal's heading and tilt
    cam_yaw = round(cam_yaw, 2) % 360.0  # rounded first: 359.999 -> 0.00
    fields = {
        "drone-dji:GpsLatitude": f"{pose.lat:.9f}",
        "drone-dji:GpsLongitude": f"{pose.lon:.9f}",
        "drone-dji:AbsoluteAltitude": f"{pose.alt_amsl_m:+.3f}",
        "drone-dji:RelativeAltitude": f"{pose.relative_alt_m:+.3f}",
        "drone-dji:FlightRollDegree": f"{pose.roll_deg:+.2f}",
        "drone-dji:FlightYawDegree": f"{_dji_degrees(pose.yaw_deg):+.2f}",
        "drone-dji:FlightPitchDegree": f"{pose.pitch_deg:+.2f}",
    }
    if camera.dji_gimbal_convention:
        # DJI's convention (0 = horizontal, -90 = nadir); readers turn it into their own only for these makes.
        fields.update({
            "drone-dji:GimbalRollDegree": "+0.00",
            "drone-dji:GimbalYawDegree": f"{_dji_degrees(cam_yaw):+.2f}",
            "drone-dji:GimbalPitchDegree": f"{cam_pitch:+.2f}",
        })
    fields.update({
        "Camera:Yaw": f"{cam_yaw:.2f}",
        "Camera:Pitch": f"{cam_pitch + 90.0:.2f}",  # Pix4D: 0 = nadir, 90 = horizontal
        "Camera:Roll": "0.00",  # the gimbal holds the camera level
    })
    attrs = "\n   ".join(f'{k}="{v}"' for k, v in fields.items())
    xml = (
        '<?xpacket begin="\ufeff" id="W5M0MpCehiHzreSzNTczkc9d"?>\n'
        '<x:xmpmeta xmlns:x="adobe:ns:meta/">\n <rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#">\n'
        '  <rdf:Description rdf:about=""\n'
        '   xmlns:drone-dji="http://www.dji.com/drone-dji/1.0/"\n'
        '   xmlns:Camera="http://pix4d.com/camera/1.0/"\n'
        f'   {attrs}/>\n </rdf:RDF>\n</x:xmpmeta>\n<?xpacket end="w"?>'
    )
    return xml.encode("utf-8")


def encode_tagged_jpeg(
    image: np.ndarray, pose: Pose | None, capture_utc: dt.datetime | None, camera: CameraTags, quality: int = 95
) -> bytes:
    ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, quality])
    if not ok:
        raise ValueError("JPEG encoding failed")
    out = io.BytesIO()
    height, width = image.shape[:2]
    piexif.insert(exif_bytes(pose, capture_utc, camera, width, height), buf.tobytes(), out)
    return _insert_xmp(out.getvalue(), xmp_packet(pose, camera))


def _insert_xmp(jpeg: bytes, xmp: bytes) -> bytes:
    """Put the XMP APP1 segment right after the EXIF APP1 (or after SOI)."""
    if not xmp:
        return jpeg
    payload = XMP_HEADER + xmp
    segment = b"\xff\xe1" + (len(payload) + 2).to_bytes(2, "big") + payload
    pos = 2
    if jpeg[2:4] == b"\xff\xe1":
        pos = 4 + int.from_bytes(jpeg[4:6], "big")
    return jpeg[:pos] + segment + jpeg[pos:]


def read_xmp(jpeg: bytes) -> str | None:
    """The XMP packet of a JPEG (for tests and tools)."""
    i = jpeg.find(XMP_HEADER)
    if i < 0:
        return None
    length = int.from_bytes(jpeg[i - 2 : i], "big")
    return jpeg[i + len(XMP_HEADER) : i - 2 + length].decode("utf-8")

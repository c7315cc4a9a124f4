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

import numpy as np
from PIL import Image, TiffTags
from PIL.ExifTags import GPS, IFD, Base
from PIL.TiffImagePlugin import IFDRational

from companion.records import Pose
from companion.spool.camera import CameraTags

XMP_HEADER = b"http://ns.adobe.com/xap/1.0/\x00"
FOCAL_PLANE_UNIT_MM = 4  # EXIF FocalPlaneResolutionUnit: 2 inch, 3 cm, 4 mm, 5 um


def _rational(value: float, denom: int = 10000) -> IFDRational:
    f = Fraction(value).limit_denominator(denom)
    return IFDRational(f.numerator, f.denominator)


def _dms(deg: float) -> tuple[IFDRational, IFDRational, IFDRational]:
    deg = abs(deg)
    d = int(deg)
    m = int((deg - d) * 60)
    s = (deg - d - m / 60) * 3600
    return IFDRational(d, 1), IFDRational(m, 1), IFDRational(int(round(s * 10000)), 10000)


# Pillow's EXIF table knows no type for ComponentsConfiguration and would write the 4 bytes as BYTE; EXIF says
# UNDEFINED (exiftool -validate: "Non-standard format"). Its table is extended once, never overriding a Pillow
# that knows the tag.
TiffTags.TAGS_V2_GROUPS[IFD.Exif].setdefault(
    Base.ComponentsConfiguration,
    TiffTags.TagInfo(Base.ComponentsConfiguration, "ComponentsConfiguration", TiffTags.UNDEFINED, 1))

# What EXIF 2.32 requires of a JPEG besides our tags (exiftool -validate checks each): 72 dpi, centred chroma,
# EXIF version 2.32, YCbCr components, Flashpix 1.0, sRGB.
_IFD0_REQUIRED = {Base.XResolution: IFDRational(72, 1), Base.YResolution: IFDRational(72, 1), Base.ResolutionUnit: 2,
                  Base.YCbCrPositioning: 1}
_EXIF_REQUIRED = {Base.ExifVersion: b"0232", Base.ComponentsConfiguration: b"\x01\x02\x03\x00",
                  Base.FlashPixVersion: b"0100", Base.ColorSpace: 1}


def _time_tags(capture_utc: dt.datetime) -> dict:
    stamp = capture_utc.strftime("%Y:%m:%d %H:%M:%S")
    subsec = f"{capture_utc.microsecond // 1000:03d}"
    return {
        Base.DateTimeOriginal: stamp, Base.DateTimeDigitized: stamp,
        Base.SubsecTime: subsec, Base.SubsecTimeOriginal: subsec, Base.SubsecTimeDigitized: subsec,
        Base.OffsetTime: "+00:00", Base.OffsetTimeOriginal: "+00:00", Base.OffsetTimeDigitized: "+00:00",
    }


def _gps_tags(pose: Pose, capture_utc: dt.datetime | None) -> dict:
    gps = {
        GPS.GPSVersionID: b"\x02\x03\x00\x00",
        GPS.GPSLatitudeRef: "N" if pose.lat >= 0 else "S",
        GPS.GPSLatitude: _dms(pose.lat),
        GPS.GPSLongitudeRef: "E" if pose.lon >= 0 else "W",
        GPS.GPSLongitude: _dms(pose.lon),
        GPS.GPSAltitudeRef: b"\x00" if pose.alt_amsl_m >= 0 else b"\x01",
        GPS.GPSAltitude: _rational(abs(pose.alt_amsl_m), 1000),
    }
    if capture_utc is not None:
        gps[GPS.GPSTimeStamp] = (IFDRational(capture_utc.hour, 1), IFDRational(capture_utc.minute, 1),
                                 _rational(capture_utc.second + capture_utc.microsecond / 1e6, 1000))
        gps[GPS.GPSDateStamp] = capture_utc.strftime("%Y:%m:%d")
    return gps


def keyframe_exif(
    pose: Pose | None, capture_utc: dt.datetime | None, camera: CameraTags, width_px: int, height_px: int
) -> Image.Exif:
    """EXIF for one keyframe, written by Pillow (IFDs chained and aligned as EXIF 2.32 says; the hand-packed
    piexif IFDs before gave exiftool -validate 15 warnings); ``capture_utc`` None (no wall clock known) leaves
    the time tags out, never 1970."""
    exif = Image.Exif()
    exif.update({Base.Orientation: 1, **_IFD0_REQUIRED})
    if camera.make:
        exif[Base.Make] = camera.make
    if camera.model:
        exif[Base.Model] = camera.model
    sub: dict = {**_EXIF_REQUIRED, Base.ExifImageWidth: int(width_px), Base.ExifImageHeight: int(height_px)}
    if capture_utc is not None:
        exif[Base.DateTime] = capture_utc.strftime("%Y:%m:%d %H:%M:%S")
        sub.update(_time_tags(capture_utc))
    focal = camera.focal_for(width_px, height_px)
    if focal is not None:
        focal_mm, px_per_mm_x, px_per_mm_y = focal
        sub[Base.FocalLength] = _rational(focal_mm, 100000)
        sub[Base.FocalPlaneXResolution] = _rational(px_per_mm_x, 100000)
        sub[Base.FocalPlaneYResolution] = _rational(px_per_mm_y, 100000)
        sub[Base.FocalPlaneResolutionUnit] = FOCAL_PLANE_UNIT_MM
    exif[IFD.Exif] = dict(sorted(sub.items()))  # EXIF wants each IFD's entries in tag order
    if pose is not None and all(math.isfinite(v) for v in (pose.lat, pose.lon, pose.alt_amsl_m)):
        exif[IFD.GPSInfo] = _gps_tags(pose, capture_utc)
    return exif


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
    """``image`` (BGR) as a JPEG carrying the keyframe's EXIF and XMP, both written by Pillow's JPEG encoder
    (4:2:0, like OpenCV's default)."""
    height, width = image.shape[:2]
    exif = keyframe_exif(pose, capture_utc, camera, width, height)
    if image.ndim == 3:  # Pillow unpacks BGR itself: one copy, no cvtColor
        rgb = Image.frombuffer("RGB", (width, height), np.ascontiguousarray(image), "raw", "BGR", 0, 1)
    else:
        rgb = Image.fromarray(image)
    out = io.BytesIO()
    try:
        rgb.save(out, "JPEG", quality=quality, dpi=(72, 72), exif=exif, xmp=xmp_packet(pose, camera))
    except (OSError, ValueError) as exc:
        raise ValueError(f"JPEG encoding failed ({exc})") from exc
    return out.getvalue()


def read_xmp(jpeg: bytes) -> str | None:
    """The XMP packet of a JPEG (for tests and tools)."""
    i = jpeg.find(XMP_HEADER)
    if i < 0:
        return None
    length = int.from_bytes(jpeg[i - 2 : i], "big")
    return jpeg[i + len(XMP_HEADER) : i - 2 + length].decode("utf-8")

"""Keyframe images read by the real tools: exiftool, pycolmap, and OpenDroneMap's photo parser rules.

OpenDroneMap's parser (opendm/photo.py, read at commit 32cfaacf) is not a Python package; its rules are restated
here on top of the same libraries it uses (ExifRead for EXIF, xmltodict for XMP), so the tag names and value
forms it looks up are checked for real. exiftool is a Debian package: a missing exiftool fails with the fix.
"""

from __future__ import annotations

import datetime as dt
import json
import math
import shutil
import subprocess
from dataclasses import replace
from pathlib import Path

import exifread
import numpy as np
import pycolmap
import pytest
import xmltodict

from companion.capture.telemetry import ClockMap
from companion.cli import main
from companion.records import Frame, Keyframe, Pose
from companion.spool import KeyframeSpool
from companion.spool.camera import CameraTags, Intrinsics, camera_tags_for_mission, load_calibration
from companion.spool.clock import TelemetryWallClock
from companion.spool.layout import MANIFEST, META

W, H, HFOV = 1920, 1080, 69.0
TRUE_FOCAL_PX = (W / 2) / math.tan(math.radians(HFOV / 2))
FLIGHT_UNIX = dt.datetime(2026, 11, 30, 14, 3, 7, 250000, tzinfo=dt.UTC).timestamp()


def exiftool(*args: str) -> dict:
    tool = shutil.which("exiftool")
    if tool is None:
        pytest.fail("exiftool is not installed: apt-get install -y libimage-exiftool-perl (scripts/bootstrap.sh)")
    out = subprocess.run([tool, "-j", "-n", "-G1", *args], capture_output=True, text=True, check=True).stdout
    return json.loads(out)[0]


def _keyframe(index: int, capture_time_s: float, yaw=20.0, gimbal_pitch=0.0) -> Keyframe:
    rng = np.random.default_rng(index)
    image = rng.integers(0, 255, (H, W, 3), dtype=np.uint8)
    pose = Pose(
        time_s=100.0 + index, lat=37.5665, lon=126.978, alt_amsl_m=41.2, relative_alt_m=11.2,
        roll_deg=1.0, pitch_deg=-2.0, yaw_deg=yaw, gimbal_pitch_deg=gimbal_pitch,
    )
    mask = np.full((H, W), 255, np.uint8)
    return Keyframe(Frame(index, capture_time_s, image), pose, mask)


def _spool_one(tmp_path: Path, tags: CameraTags, capture_time_s=FLIGHT_UNIX, **kw) -> Path:
    meta = {"camera": {"width_px": 3840, "height_px": 2160, "hfov_deg": HFOV}}
    spool = KeyframeSpool(tmp_path, meta=meta, camera_tags=tags)
    entry = spool.append(_keyframe(3, capture_time_s, **kw))
    return tmp_path / entry.image


def _sim_tags(sensor_width_mm=None, make="companion") -> CameraTags:
    # the mission's camera is 3840 px wide; the keyframes arrive at 1920 px: the focal in pixels halves
    return CameraTags(make, "sim-pinhole", Intrinsics.from_hfov(3840, 2160, HFOV), sensor_width_mm)


# --- OpenDroneMap's rules (opendm/photo.py), restated --------------------------------------------------------------


def odm_read(path: Path) -> dict:
    """Focal in pixels, yaw/pitch/roll (ODM's normalised convention: pitch 0 = nadir, 90 = forward) and UTC time."""
    with open(path, "rb") as fh:
        tags = exifread.process_file(fh, details=True, extract_thumbnail=False)
        fh.seek(0)
        raw = fh.read()
    make = str(tags["Image Make"].values).strip() if "Image Make" in tags else ""

    def num(tag):
        v = tags[tag].values
        v = v[0] if isinstance(v, list) else v
        return float(v.num) / float(v.den) if hasattr(v, "den") else float(v)

    # focal: the 35 mm equivalent / 36 if present, else FocalLength / sensor width from the focal-plane resolution
    width = W
    if "EXIF FocalLengthIn35mmFilm" in tags and num("EXIF FocalLengthIn35mmFilm") > 0:
        ratio = num("EXIF FocalLengthIn35mmFilm") / 36.0
    elif "EXIF FocalPlaneXResolution" in tags and "EXIF FocalLength" in tags:
        mm_per_unit = {2: 25.4, 3: 10.0, 4: 1.0, 5: 0.001}[int(num("EXIF FocalPlaneResolutionUnit"))]
        sensor_width = width / num("EXIF FocalPlaneXResolution") * mm_per_unit
        ratio = num("EXIF FocalLength") / sensor_width
    else:
        ratio = 0.85  # ODM's fallback
    # XMP: the first tag present of each list; DJI-convention makes get 90 added to the pitch
    start, end = raw.find(b"<x:xmpmeta"), raw.find(b"</x:xmpmeta")
    desc = xmltodict.parse(raw[start : end + 12].decode())["x:xmpmeta"]["rdf:RDF"]["rdf:Description"]

    def first(names):
        return next((float(desc[n]) for n in names if n in desc), None)

    yaw = first(["@drone-dji:FlightYawDegree", "@Camera:Yaw", "Camera:Yaw"])
    pitch = first(["@drone-dji:GimbalPitchDegree", "@Camera:Pitch", "Camera:Pitch"])
    roll = first(["@drone-dji:GimbalRollDegree", "@Camera:Roll", "Camera:Roll"])
    if pitch is not None and make.lower() in ("dji", "hasselblad"):
        pitch += 90.0
    # time: DateTimeOriginal + SubSecTime read as an integer after "0." (leading zeros are lost there)
    utc = dt.datetime.strptime(str(tags["EXIF DateTimeOriginal"].values), "%Y:%m:%d %H:%M:%S")
    if "EXIF SubSecTime" in tags:
        utc += dt.timedelta(seconds=float(f"0.{int(str(tags['EXIF SubSecTime'].values))}"))
    return {
        "focal_px": ratio * max(W, H), "yaw": yaw, "pitch": pitch, "roll": roll,
        "utc": utc.replace(tzinfo=dt.UTC).timestamp(), "make": make,
    }


# --- tests ------------------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("sensor_width_mm", [None, 13.2])
def test_exiftool_reads_camera_focal_size_time_and_place(tmp_path, sensor_width_mm):
    path = _spool_one(tmp_path, _sim_tags(sensor_width_mm))
    t = exiftool(str(path))
    assert t["IFD0:Make"] == "companion" and t["IFD0:Model"] == "sim-pinhole"
    assert (t["ExifIFD:ExifImageWidth"], t["ExifIFD:ExifImageHeight"]) == (W, H)
    focal_px = t["ExifIFD:FocalLength"] * t["ExifIFD:FocalPlaneXResolution"]  # unit: mm
    assert t["ExifIFD:FocalPlaneResolutionUnit"] == 4
    assert focal_px == pytest.approx(TRUE_FOCAL_PX, rel=1e-4)
    if sensor_width_mm:
        assert t["ExifIFD:FocalLength"] == pytest.approx(13.2 / 2 / math.tan(math.radians(HFOV / 2)), rel=1e-4)
    else:  # the 35 mm-film equivalent (36 mm wide image area)
        assert t["ExifIFD:FocalLength"] == pytest.approx(36 * TRUE_FOCAL_PX / W, rel=1e-4)
    assert t["Composite:SubSecDateTimeOriginal"] == "2026:11:30 14:03:07.250+00:00"
    assert t["ExifIFD:SubSecTime"] == 250 and t["ExifIFD:SubSecTimeOriginal"] == 250
    assert t["Composite:GPSLatitude"] == pytest.approx(37.5665, abs=1e-7)
    assert t["Composite:GPSLongitude"] == pytest.approx(126.978, abs=1e-7)
    assert t["XMP-Camera:Pitch"] == 90 and t["XMP-Camera:Yaw"] == 20 and t["XMP-Camera:Roll"] == 0
    assert "XMP-drone-dji:GimbalPitchDegree" not in t  # DJI convention only for DJI makes (see the ODM test)


@pytest.mark.parametrize("with_time", [True, False])
def test_exiftool_validates_a_keyframe_without_a_warning(tmp_path, with_time):
    """EXIF 2.32 as exiftool checks it: IFDs chained and aligned, the required tags present (issue 29: piexif's
    IFDs gave 15 warnings)."""
    path = _spool_one(tmp_path, _sim_tags(13.2), FLIGHT_UNIX if with_time else 12.5)  # 12.5: no wall clock
    tool = shutil.which("exiftool")
    assert tool is not None, "exiftool is not installed: apt-get install -y libimage-exiftool-perl"
    out = subprocess.run([tool, "-validate", "-warning", "-a", str(path)], capture_output=True, text=True,
                         check=True).stdout
    assert out.split() == ["Validate", ":", "OK"], out
    t = exiftool(str(path))
    assert (t["ExifIFD:ExifVersion"], t["ExifIFD:ColorSpace"], t["IFD0:XResolution"]) == ("0232", 1, 72)


def test_pycolmap_takes_the_focal_from_exif(tmp_path):
    for sensor in (None, 13.2):
        path = _spool_one(tmp_path / str(sensor), _sim_tags(sensor))
        cam = pycolmap.infer_camera_from_image(path)
        assert cam.has_prior_focal_length
        assert (cam.width, cam.height) == (W, H)
        assert cam.focal_length == pytest.approx(TRUE_FOCAL_PX, rel=1e-4)


def test_pycolmap_takes_a_calibrated_focal(tmp_path):
    calib = tmp_path / "calib.yaml"
    calib.write_text("width_px: 3840\nheight_px: 2160\nfx: 2811.0\nfy: 2809.0\ncx: 1925.0\ncy: 1077.5\n"
                     "distortion: [-0.11, 0.09, 0.0004, -0.0002, -0.03]\n")
    tags = CameraTags("companion", "sim-pinhole", load_calibration(calib), 13.2)
    path = _spool_one(tmp_path / "spool", tags)
    assert pycolmap.infer_camera_from_image(path).focal_length == pytest.approx(2811.0 / 2, rel=1e-4)
    cam = json.loads((tmp_path / "spool" / META).read_text())["camera"]
    assert cam["K"][0][0] == pytest.approx(2811.0 / 2) and cam["K"][1][2] == pytest.approx(1077.5 / 2)
    assert cam["distortion_opencv"] == [-0.11, 0.09, 0.0004, -0.0002, -0.03]
    assert cam["intrinsics_source"] == str(calib) and cam["sensor_width_mm"] == 13.2


def test_opencv_calibration_file_is_read(tmp_path):
    import cv2

    path = tmp_path / "cam.yml"
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    fs.write("image_width", 1280)
    fs.write("image_height", 720)
    fs.write("camera_matrix", np.array([[930.0, 0, 641.0], [0, 931.0, 359.0], [0, 0, 1]]))
    fs.write("distortion_coefficients", np.array([[-0.1, 0.05, 0.0, 0.0, 0.0]]))
    fs.release()
    k = load_calibration(path)
    assert (k.width_px, k.fx, k.cy, k.distortion[0]) == (1280, 930.0, 359.0, -0.1)


def test_calibration_of_another_aspect_is_refused(tmp_path):
    from companion.errors import CompanionError
    from companion.mission.spec import Camera

    calib = tmp_path / "calib.yaml"
    calib.write_text("width_px: 4000\nheight_px: 3000\nfx: 2900\nfy: 2900\ncx: 2000\ncy: 1500\n")
    cam = Camera(width_px=3840, height_px=2160, hfov_deg=69, fps=30, exposure_s=0.002, calibration=str(calib))
    with pytest.raises(CompanionError, match="another aspect ratio"):
        camera_tags_for_mission(cam)


def test_opendronemap_reads_a_horizontal_camera_with_the_true_focal(tmp_path):
    odm = odm_read(_spool_one(tmp_path, _sim_tags(), yaw=200.0))
    assert odm["focal_px"] == pytest.approx(TRUE_FOCAL_PX, rel=0.01)  # not the 0.85 fallback
    assert odm["pitch"] == pytest.approx(90.0) and odm["roll"] == 0.0
    assert odm["yaw"] == pytest.approx(-160.0)  # heading 200 deg in DJI's -180..180 (what real DJI photos carry)
    assert odm["utc"] == pytest.approx(FLIGHT_UNIX, abs=1e-3)


def test_opendronemap_reads_a_dji_make_as_horizontal_too(tmp_path):
    path = _spool_one(tmp_path, _sim_tags(make="DJI"), gimbal_pitch=-10.0)
    odm = odm_read(path)
    assert odm["pitch"] == pytest.approx(80.0)  # DJI's -10 (down from horizontal) + ODM's 90
    assert exiftool(str(path))["XMP-Camera:Pitch"] == 80


def test_no_wall_clock_gives_no_date_never_1970(tmp_path):
    path = _spool_one(tmp_path, _sim_tags(), capture_time_s=12.5)  # a video time, not a Unix time
    t = exiftool(str(path))
    assert not any(k.endswith(("DateTimeOriginal", "SubSecTime", "GPSDateStamp")) for k in t)
    side = json.loads(next(tmp_path.glob("kf_*.json")).read_text())
    assert side["capture_utc"] is None


def test_wall_clock_from_telemetry_rows():
    rows = [{"t_wall": 1_764_000_000.0 + 0.02 + 0.005 * (i % 3) + i * 0.1, "t_boot_s": 50.0 + i * 0.1}
            for i in range(100)]
    clock = TelemetryWallClock.from_log_rows(rows, ClockMap(fixed_offset_s=-50.0))  # video time 0 = boot 50 s
    assert clock.unix_time(1.0) == pytest.approx(1_764_000_000.0 + 0.02 + 1.0, abs=1e-6)


def test_cull_dates_images_from_the_telemetry_wall_clock(tmp_path):
    import cv2
    from test_onboard_chain import _scan  # the synthetic scan of the chain test

    _, images = _scan(n=12)
    frames = tmp_path / "frames"
    frames.mkdir()
    for i, img in enumerate(images):
        cv2.imwrite(str(frames / f"{i:04d}.jpg"), img)
    log = tmp_path / "telemetry.jsonl"
    boot_to_unix = FLIGHT_UNIX - 50.0
    with open(log, "w") as fh:
        for i in range(20):
            t_boot = 50.0 + i / 10.0
            fh.write(json.dumps({
                "t_wall": round(t_boot + boot_to_unix + 0.03, 4), "t_boot_s": t_boot, "lat": 37.0,
                "lon": 127.0 + i * 1e-6, "alt_amsl_m": 40.0, "rel_alt_m": 10.0, "roll_deg": 0.0,
                "pitch_deg": 0.0, "yaw_deg": 0.0, "mission_item": 3,
            }) + "\n")
    out = tmp_path / "spool"
    args = ["cull", str(frames), "--telemetry", str(log), "--out", str(out), "--no-mask", "--no-mission", "--fps", "10",
            "--time-offset", "50"]
    assert main(args) == 0
    for line in (out / MANIFEST).read_text().splitlines():
        rec = json.loads(line)
        t = exiftool(str(out / rec["image"]))
        expected = dt.datetime.fromtimestamp(boot_to_unix + 0.03 + 50.0 + rec["index"] / 10.0, tz=dt.UTC)
        got = dt.datetime.strptime(t["Composite:SubSecDateTimeOriginal"], "%Y:%m:%d %H:%M:%S.%f%z")
        assert abs((got - expected).total_seconds()) < 0.002, (rec["index"], got, expected)
        assert got.date() == dt.date(2026, 11, 30)


def test_mission_camera_calibration_is_resolved_next_to_the_mission(tmp_path):
    import yaml

    from companion.errors import CompanionError
    from companion.mission import load_mission

    doc = yaml.safe_load(Path("missions/demo-facade.yaml").read_text())
    doc["camera"]["calibration"] = "cal/cam.yaml"
    doc["camera"]["sensor_width_mm"] = 13.2
    mission_path = tmp_path / "m.yaml"
    mission_path.write_text(yaml.safe_dump(doc))
    with pytest.raises(CompanionError, match="camera.calibration cal/cam.yaml does not exist"):
        load_mission(mission_path)
    (tmp_path / "cal").mkdir()
    (tmp_path / "cal" / "cam.yaml").write_text(
        "width_px: 1920\nheight_px: 1080\nfx: 1400\nfy: 1400\ncx: 960\ncy: 540\n"
    )
    tags = camera_tags_for_mission(load_mission(mission_path).camera)
    assert tags.intrinsics.fx == pytest.approx(2800.0) and tags.intrinsics.width_px == 3840  # scaled to the mission
    assert (tags.make, tags.model, tags.sensor_width_mm) == ("companion", "simulated pinhole", 13.2)


def test_live_tailer_teaches_the_sim_camera_clock_the_wall_time(tmp_path):
    """Live SITL: the simulator camera stamps frames on the autopilot clock; the tailer learns boot -> Unix."""
    import time

    from companion.capture.telemetry import TelemetryBuffer
    from companion.onboard.live import TelemetryLogTailer

    log = tmp_path / "telemetry.jsonl"
    boot_to_unix = FLIGHT_UNIX - 300.0
    wall = TelemetryWallClock(ClockMap(fixed_offset_s=0.0))
    buffer = TelemetryBuffer()
    tailer = TelemetryLogTailer(log, buffer, None, wall_clock=wall)  # before the flight writes its rows
    log.write_text("".join(
        json.dumps({"t_wall": 300.0 + i * 0.1 + boot_to_unix + 0.004 * (1 + i % 2), "t_boot_s": 300.0 + i * 0.1,
                    "lat": 37.0, "lon": 127.0, "alt_amsl_m": 40.0, "roll_deg": 0.0, "pitch_deg": 0.0,
                    "yaw_deg": 0.0}) + "\n" for i in range(20)))
    tailer.start()
    deadline = time.monotonic() + 30.0
    while len(buffer) < 20 and time.monotonic() < deadline:
        time.sleep(0.02)
    tailer.stop()
    tailer.join(5.0)
    assert len(buffer) == 20
    assert wall.unix_time(301.0) == pytest.approx(boot_to_unix + 301.0 + 0.004, abs=1e-6)


def test_pycolmap_registers_every_keyframe_with_the_exif_focal(tmp_path):
    """COLMAP on our keyframes as they are (no intrinsics given): the EXIF focal is its prior; every image registers.

    A flat wall cannot pin the focal down in bundle adjustment, so it may drift a little from the prior (issue 16
    measured 1474-2233 px for a true 698 px starting from COLMAP's own guess); from the EXIF prior it stays close.
    """
    import pymap3d

    from companion.geo import FacadeFrame, GeoPoint
    from companion.stitch.inputs import CameraModel
    from evaluation.stitch.synthetic import SyntheticWall, make_texture, view

    w, h, hfov = 640, 360, 70.0
    wall = SyntheticWall(length_m=6.0, height_m=3.0)
    cam = CameraModel.from_hfov(w, h, hfov)
    start = GeoPoint(37.5665, 126.978, 30.0)
    _, end_lon, _ = pymap3d.enu2geodetic(6.0, 0.0, 0.0, start.lat, start.lon, start.alt_amsl_m)
    frame = FacadeFrame.from_wall(start, GeoPoint(start.lat, float(end_lon), 30.0))
    texture = make_texture(wall)
    spool = KeyframeSpool(tmp_path / "spool", camera_tags=CameraTags("companion", "simulated pinhole",
                                                                     Intrinsics.from_hfov(w, h, hfov)))
    rng = np.random.default_rng(1)
    k = 0
    for up in (1.0, 2.0):  # two overlapping rows, small attitude jitter as in flight
        for along in np.arange(1.8, 4.3, 0.5):
            yaw, pitch = (float(v) for v in rng.normal(0, 2.0, 2))
            img, mask, _ = view(texture, wall, cam, frame, float(along), up, 4.0, yaw_offset_deg=yaw, pitch_deg=pitch)
            lat, lon, alt = frame.facade_to_geodetic(along, 4.0, up)
            pose = Pose(k, float(lat), float(lon), float(alt), up, 0.0, pitch, (frame.yaw_facing_wall_deg + yaw) % 360)
            spool.append(Keyframe(Frame(k, FLIGHT_UNIX + k, img), pose, mask))
            k += 1
    images = tmp_path / "images"
    images.mkdir()
    for p in (tmp_path / "spool").glob("kf_*.jpg"):
        shutil.copy(p, images / p.name)
    db = tmp_path / "db.db"
    pycolmap.extract_features(db, images)
    pycolmap.match_exhaustive(db)
    maps = pycolmap.incremental_mapping(db, images, tmp_path / "sparse")
    best = max(maps.values(), key=lambda r: r.num_reg_images())
    assert best.num_reg_images() == k
    (camera,) = best.cameras.values()
    assert camera.has_prior_focal_length  # taken from the EXIF, not guessed
    assert camera.focal_length == pytest.approx(cam.focal_px, rel=0.05)


def test_a_cropped_stream_is_spooled_without_a_wrong_focal(tmp_path, caplog):
    """A 4:3 stream from a camera modelled 16:9 is a crop: its focal is unknown, so none is written (and no stop)."""
    from PIL import Image
    from PIL.ExifTags import IFD, Base

    tags = CameraTags("companion", "sim-pinhole", Intrinsics.from_hfov(3840, 2160, HFOV))
    spool = KeyframeSpool(tmp_path, meta={"camera": {"width_px": 3840, "height_px": 2160, "hfov_deg": HFOV}},
                          camera_tags=tags)
    kf = _keyframe(1, FLIGHT_UNIX)
    kf = replace(kf, frame=replace(kf.frame, image=kf.image[:, :1440]))  # 1440 x 1080: 4:3
    entry = spool.append(kf)
    with Image.open(tmp_path / entry.image) as im:
        exif = im.getexif().get_ifd(IFD.Exif)
    assert Base.FocalLength not in exif and exif[Base.ExifImageWidth] == 1440
    assert "another aspect ratio" in caplog.text and "without a focal length" in caplog.text
    assert "K" not in json.loads((tmp_path / META).read_text())["camera"]


def test_a_camera_without_make_and_model_still_gets_both():
    """COLMAP shares one camera only among images with a Make and Model: a mission without them still needs them."""
    from companion.mission.spec import Camera

    tags = camera_tags_for_mission(Camera(width_px=3840, height_px=2160, hfov_deg=69, fps=30, exposure_s=0.002))
    assert tags.make == "companion" and tags.model == "mission camera 3840x2160 hfov 69 deg"


def test_wall_clock_follows_a_simulator_running_faster_than_real_time():
    """SITL at 1.5x: boot time runs 1.5x faster than the Unix clock. Keyframes are dated while the flight goes on,
    some seconds after their exposure (a backlog): their times must stay right and in order."""
    rng = np.random.default_rng(0)
    boot = np.arange(0.0, 120.0, 1 / 30)
    wall = FLIGHT_UNIX + boot / 1.5 + rng.uniform(0.002, 0.030, boot.size)  # rows written 2-30 ms late
    clock = TelemetryWallClock(ClockMap(fixed_offset_s=0.0))
    keyframes = [(float(t), 0.5 if k % 2 else 12.0) for k, t in enumerate(np.arange(20.0, 100.0, 5.0))]
    dated, seen = [], 0
    for t, lag in keyframes:  # dated once the telemetry has reached t + lag
        while seen < boot.size and boot[seen] <= t + lag:
            clock.observe(wall[seen], boot[seen])
            seen += 1
        dated.append(clock.unix_time(t))
    for (t, _), unix in zip(keyframes, dated, strict=True):
        assert unix == pytest.approx(FLIGHT_UNIX + t / 1.5 + 0.002, abs=0.01)
    assert all(a < b for a, b in zip(dated, dated[1:], strict=False))


@pytest.mark.parametrize(("yaw", "dji_yaw"), [(359.9997, 0.0), (190.0, -170.0), (20.0, 20.0)])
def test_dji_yaws_are_in_djis_range(tmp_path, yaw, dji_yaw):
    """drone-dji yaws in DJI's -180..180 (a SITL heading of 359.9997 deg was written as +360.00); Pix4D's 0..360."""
    t = exiftool(str(_spool_one(tmp_path, _sim_tags(make="DJI"), yaw=yaw)))
    assert float(t["XMP-drone-dji:FlightYawDegree"]) == dji_yaw
    assert float(t["XMP-drone-dji:GimbalYawDegree"]) == dji_yaw
    assert float(t["XMP-Camera:Yaw"]) == dji_yaw % 360.0

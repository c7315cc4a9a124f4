"""The camera gimbal's attitude reaches the stitcher: plan / gimbal telemetry -> telemetry log -> spool -> reader.

A mission flown with a tilted camera (``gimbal_pitch_deg: -20``) used to be stitched as if the camera were level:
the telemetry log had no gimbal column, the spool wrote ``gimbal_pitch_deg: 0.0`` and the stitcher believed it.
"""

from __future__ import annotations

import io
import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from companion.attitude import angles_from_rotation, euler_to_quat
from companion.cli import main
from companion.flight.telemetry_log import PlannedGimbal, TelemetryRecorder, gimbal_from_status
from companion.mission import load_mission, plan_scan
from companion.records import GimbalSource, Pose
from companion.spool.reader import load_spool
from companion.stitch.geometry import prior_plane_from_image

SMALL_WALL = Path(__file__).parent / "data" / "small-wall.yaml"
TILT_DEG = -20.0


def _tilted_mission(tmp_path: Path) -> Path:
    spec = yaml.safe_load(SMALL_WALL.read_text())
    spec["gimbal_pitch_deg"] = TILT_DEG
    path = tmp_path / "tilted-wall.yaml"
    path.write_text(yaml.safe_dump(spec))
    return path


def _rotation_error_deg(R_a: np.ndarray, R_b: np.ndarray) -> float:
    cos = (np.trace(R_a.T @ R_b) - 1.0) / 2.0
    return float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))


def test_a_tilted_camera_mission_reaches_the_stitcher_with_its_tilt(tmp_path):
    from sim.camera.recording import load_recording

    mission = _tilted_mission(tmp_path)
    rec_dir, spool_dir = tmp_path / "rec", tmp_path / "spool"
    assert main(["record", str(mission), "--out", str(rec_dir), "--fast", "--width", "160",
                 "--max-frames", "30", "--stride", "10"]) == 0
    rows = [json.loads(x) for x in (rec_dir / "telemetry.jsonl").read_text().splitlines()]
    assert {(r["gimbal_pitch_deg"], r["gimbal_source"]) for r in rows} == {(TILT_DEG, "plan")}
    assert main(["cull", str(rec_dir / "frames"), "--telemetry", str(rec_dir / "telemetry.jsonl"),
                 "--out", str(spool_dir), "--mission", str(mission), "--no-mask"]) == 0

    recording = load_recording(rec_dir)
    inp = load_spool(spool_dir)
    assert len(inp.keyframes) >= 3 and inp.facade is not None
    for kf in inp.keyframes:
        truth = recording.camera_pose(kf.index)
        # the camera's true attitude is the gimbal's tilt plus a small flight wobble (under 2 degrees)
        assert _rotation_error_deg(kf.pose.R_enu_from_cam, truth.R_world_from_cam) < 2.5
        _, pitch, roll = angles_from_rotation(kf.pose.R_enu_from_cam)
        assert pitch == pytest.approx(TILT_DEG, abs=0.01) and roll == pytest.approx(0.0, abs=0.01)
        # where the stitcher's telemetry prior puts the image centre on the wall: where the camera really looks,
        # about standoff * tan(20 deg) = 1.5 m below the camera, not level with it
        prior = prior_plane_from_image(kf.pose, inp.facade)
        centre = prior @ np.array([0.0, 0.0, 1.0])
        along, up = centre[:2] / centre[2]
        cam_along, cam_out, cam_up = (float(v) for v in inp.facade.frame.geodetic_to_facade(
            truth.lat, truth.lon, truth.alt_amsl_m))
        drop = cam_up - up
        assert drop == pytest.approx(cam_out * np.tan(np.radians(-TILT_DEG)), abs=0.25), (kf.index, drop)
        assert abs(along - cam_along) < 0.25


def test_the_plans_gimbal_command_is_found_for_both_autopilots():
    plan = plan_scan(load_mission(SMALL_WALL).model_copy(update={"gimbal_pitch_deg": TILT_DEG}))
    for flavour in ("px4", "ardupilot"):
        items = plan.mavlink_items(flavour)
        planned = PlannedGimbal.from_items(items)
        assert planned is not None and planned.pitch_deg == TILT_DEG and planned.yaw_deg == 0.0
        assert items[planned.seq].command in (1000, 205)  # DO_GIMBAL_MANAGER_PITCHYAW or DO_MOUNT_CONTROL


def _row(rec: TelemetryRecorder) -> dict:
    rec._file = io.StringIO()
    rec._write_row(12.345, 37.5, 127.0, 40.0, 10.0, (0.1, 0.2, 0.0))
    return json.loads(rec._file.getvalue())


def test_the_log_says_where_the_gimbal_angle_came_from():
    rec = TelemetryRecorder(vehicle=None, planned_gimbal=PlannedGimbal(seq=2, pitch_deg=TILT_DEG, yaw_deg=0.0))
    rec.state.update(mission_item=1)  # before the gimbal item: the gimbal angle is not known, not 0
    before = _row(rec)
    assert before["gimbal_pitch_deg"] is None and before["gimbal_source"] is None
    assert Pose.from_json({**before, "roll_deg": 0.0, "pitch_deg": 0.0, "yaw_deg": 10.0}).gimbal_pitch_deg is None
    rec.state.update(mission_item=3)  # past it: the plan's command
    after = _row(rec)
    assert (after["gimbal_pitch_deg"], after["gimbal_yaw_deg"], after["gimbal_source"]) == (TILT_DEG, 0.0, "plan")

    # the gimbal's own report wins over the plan
    class Msg:
        q = [float(v) for v in euler_to_quat(yaw_deg=5.0, pitch_deg=-33.0, roll_deg=0.0)]
        fields_json = json.dumps({"q": q, "flags": 32})  # yaw in the vehicle frame

    rec._on_gimbal_status(Msg())
    told = _row(rec)
    assert told["gimbal_source"] == "telemetry"
    assert told["gimbal_pitch_deg"] == pytest.approx(-33.0) and told["gimbal_yaw_deg"] == pytest.approx(5.0)


def test_gimbal_status_in_the_earth_frame_is_made_relative_to_the_vehicle():
    q = [float(v) for v in euler_to_quat(yaw_deg=100.0, pitch_deg=-45.0, roll_deg=0.0)]
    pitch, yaw = gimbal_from_status({"q": q, "flags": 64}, vehicle_yaw_deg=90.0)
    assert pitch == pytest.approx(-45.0) and yaw == pytest.approx(10.0)
    assert gimbal_from_status({"q": q, "flags": 16}, vehicle_yaw_deg=None)[1] is None  # YAW_LOCK: earth frame


def test_pose_json_round_trip_keeps_unknown_gimbal_unknown():
    pose = Pose(1.5, 37.5, 127.0, 40.0, 10.0, 1.0, -2.0, 359.0, (0.1, 0.2, 0.3), None, 4)
    assert Pose.from_json(pose.to_json()) == pose
    tilted = Pose(1.5, 37.5, 127.0, 40.0, 10.0, 1.0, -2.0, 90.0, gimbal_pitch_deg=-20.0, gimbal_yaw_deg=3.0,
                  gimbal_source=GimbalSource.TELEMETRY)
    assert Pose.from_json(json.loads(json.dumps(tilted.to_json()))) == tilted
    assert tilted.camera_angles() == (93.0, -20.0, 0.0)


def test_a_tilted_camera_mission_stitches_where_the_camera_looked(tmp_path):
    """The whole stitcher, not just its prior: after image matching and global alignment each keyframe's image
    centre lands on the wall where the tilted camera really looked (standoff * tan 20 deg below the camera). With
    the old level-camera assumption the map put every keyframe about 1.5 m too high."""
    from companion.stitch.worker import Stitcher
    from sim.camera.recording import load_recording

    mission = _tilted_mission(tmp_path)
    rec_dir, spool_dir, out = tmp_path / "rec", tmp_path / "spool", tmp_path / "map"
    assert main(["record", str(mission), "--out", str(rec_dir), "--fast", "--width", "320",
                 "--max-frames", "60", "--stride", "5"]) == 0
    assert main(["cull", str(rec_dir / "frames"), "--telemetry", str(rec_dir / "telemetry.jsonl"),
                 "--out", str(spool_dir), "--mission", str(mission), "--no-mask"]) == 0
    recording, inp = load_recording(rec_dir), load_spool(spool_dir)
    stitcher = Stitcher(progress=False)
    out.mkdir()
    found = stitcher.features(inp, out)
    priors = stitcher.priors(found)
    aligned = stitcher.alignment(found, priors, stitcher.pairs(found, priors, out))
    assert len(aligned.placed) == len(inp.keyframes) >= 5 and len(aligned.accepted) >= len(inp.keyframes) - 1
    for k in aligned.placed:
        kf = inp.keyframes[k]
        centre = aligned.alignment.G[k] @ np.array([0.0, 0.0, 1.0])  # image-normalised centre -> wall metres
        along, up = centre[:2] / centre[2]
        truth = recording.camera_pose(kf.index)
        cam_along, cam_out, cam_up = (float(v) for v in inp.facade.frame.geodetic_to_facade(
            truth.lat, truth.lon, truth.alt_amsl_m))
        assert cam_up - up == pytest.approx(cam_out * np.tan(np.radians(-TILT_DEG)), abs=0.1), (kf.index, up)
        assert abs(along - cam_along) < 0.1, (kf.index, along, cam_along)

"""A ground station sees the companion as a MAVLink camera: information on request, keyframes as photos."""

from __future__ import annotations

from pymavlink import mavutil

from companion.onboard.camera_protocol import CameraDescription, MavlinkCamera
from companion.records import Pose
from sim.process import free_port

mav = mavutil.mavlink


def test_camera_information_and_captured_images():
    port = free_port()
    gcs = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=255, source_component=190)
    cam = MavlinkCamera(f"udpout:127.0.0.1:{port}", CameraDescription(width_px=3840, height_px=2160)).start()
    try:
        hb = gcs.recv_match(type="HEARTBEAT", blocking=True, timeout=5)
        assert hb is not None and hb.type == mav.MAV_TYPE_CAMERA and hb.get_srcComponent() == 100
        gcs.mav.command_long_send(1, 100, mav.MAV_CMD_REQUEST_MESSAGE, 0, 259, 0, 0, 0, 0, 0, 0)
        info = gcs.recv_match(type="CAMERA_INFORMATION", blocking=True, timeout=5)
        assert info is not None and info.resolution_h == 3840 and info.resolution_v == 2160
        pose = Pose(10.0, 37.5665, 126.978, 41.5, 11.5, 0.0, 0.0, 0.0)
        cam.publish(pose, "kf_000000.jpg")
        cam.publish(pose, "kf_000031.jpg")
        got = [gcs.recv_match(type="CAMERA_IMAGE_CAPTURED", blocking=True, timeout=5) for _ in range(2)]
        assert [g.image_index for g in got] == [0, 1]
        assert got[0].lat == 375665000 and got[0].relative_alt == 11500 and got[0].capture_result == 1
        # A ground station that missed one asks again.
        gcs.mav.command_long_send(1, 100, mav.MAV_CMD_REQUEST_MESSAGE, 0, 263, 1, 0, 0, 0, 0, 0)
        again = gcs.recv_match(type="CAMERA_IMAGE_CAPTURED", blocking=True, timeout=5)
        assert again is not None and again.image_index == 1 and "kf_000031.jpg" in again.file_url
        gcs.mav.command_long_send(1, 100, mav.MAV_CMD_REQUEST_MESSAGE, 0, 263, 7, 0, 0, 0, 0, 0)
        ack = gcs.recv_match(type="COMMAND_ACK", blocking=True, timeout=5)
        while ack is not None and ack.result == mav.MAV_RESULT_ACCEPTED:
            ack = gcs.recv_match(type="COMMAND_ACK", blocking=True, timeout=5)
        assert ack is not None and ack.result == mav.MAV_RESULT_FAILED  # no image 7
    finally:
        cam.close()
        gcs.close()

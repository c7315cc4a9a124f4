"""``python -m sim posebridge`` against the simulator process (issue 26): the camera's pose channel carries the
SITL's TRUE position from SIM_STATE, a GNSS bias away from what GLOBAL_POSITION_INT reports; and a vehicle that sends
no SIM_STATE, or no vehicle at all, is a clear error."""

from __future__ import annotations

import json
import socket
import threading
import time

import pymap3d
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.errors import CompanionError
from sim.camera.live import PoseListener
from sim.pose_bridge import BridgeConfig, PoseBridge
from sim.process import free_port
from tests.sitl import SitlVehicle

pytestmark = pytest.mark.sitl

HOME = (37.56638, 126.97815, 30.0)


class _Watching(PoseBridge):
    """The bridge, also asking for and keeping GLOBAL_POSITION_INT (the estimate) from the same link."""

    def __init__(self, cfg):
        super().__init__(cfg)
        self.estimates = []

    def _request(self):
        super()._request()
        self.conn.mav.command_long_send(*self.target, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 0,
                                        mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, 1e5, 0, 0, 0, 0, 0)

    def handle(self, msg):
        if msg.get_type() == "GLOBAL_POSITION_INT":
            self.estimates.append(msg)
        return super().handle(msg)


def test_the_bridge_publishes_the_truth_of_an_ardupilot_sitl_not_its_biased_estimate(tmp_path):
    truth_log = tmp_path / "truth.jsonl"
    port = free_port()
    listener = PoseListener(0)  # the camera's own receiver
    bridge_truth = tmp_path / "bridge-truth.jsonl"  # what the bridge says the flight truly was
    bridge = _Watching(BridgeConfig(connect=f"udpin:127.0.0.1:{port}", pose_port=listener.port, timeout_s=20.0,
                                    truth_log=bridge_truth))
    errors = []

    def _run():
        try:
            bridge.run()
        except Exception as exc:  # noqa: BLE001 (reported below)
            errors.append(exc)

    try:
        bridge.open()  # bound before the vehicle sends
        with SitlVehicle(autopilot="ardupilot", speedup=5, mavlink_port=port, truth_log=truth_log,
                         home=",".join(str(v) for v in HOME), home_yaw=250, gnss_bias=(0, -1.5, 0)):
            thread = threading.Thread(target=_run, daemon=True)
            thread.start()
            # home comes once the autopilot's estimator uses GPS (simulated seconds after boot: longer in wall
            # time on a loaded machine); wait for a pose published after it, bounded
            deadline = time.monotonic() + 60.0
            while time.monotonic() < deadline and not errors and (
                    len(listener.poses) < 20 or "home" not in listener.poses[-1] or len(bridge.estimates) < 3):
                time.sleep(0.1)
            bridge.stop()
            thread.join(5.0)
    finally:
        bridge.close()
        listener.close()
    assert not errors, errors
    poses = list(listener.poses)
    assert len(poses) >= 20 and listener.bad == 0
    truth = {row["time_boot_ms"]: row for row in map(json.loads, truth_log.read_text().splitlines())}
    for pose in poses:
        # stamped with a time the vehicle was at (ATTITUDE's time_boot_ms truncates the clock: 1 ms either way)
        ms = pose["time_boot_ms"]
        row = truth.get(ms) or truth.get(ms + 1) or truth[ms - 1]
        assert (pose["lat"], pose["lon"]) == pytest.approx((row["lat"], row["lon"]), abs=2e-7)  # int32 degE7: 1 cm
        assert pose["alt_amsl_m"] == pytest.approx(row["alt_amsl_m"], abs=1e-3)
        assert pose["yaw_deg"] == pytest.approx(250.0, abs=1e-3)
        # home once the autopilot reports it (after its estimator uses GPS)
        assert pose.get("home", {"lat": HOME[0], "lon": HOME[1], "alt_amsl_m": HOME[2]}) == {
            "lat": HOME[0], "lon": HOME[1], "alt_amsl_m": HOME[2]}
    times = [p["t_s"] for p in poses]
    assert times == sorted(times) and len(set(times)) == len(times)
    written = [json.loads(line) for line in bridge_truth.read_text().splitlines()]
    assert len(written) == bridge.published and written[:len(poses)] == poses  # every pose published, as sent
    pose = poses[-1]
    assert "home" in pose
    for est in bridge.estimates:  # the autopilot's estimate: the bias (1.5 m South) off the published truth
        n, e, _ = pymap3d.geodetic2ned(est.lat / 1e7, est.lon / 1e7, HOME[2], pose["lat"], pose["lon"], HOME[2])
        assert (float(n), float(e)) == pytest.approx((-1.5, 0.0), abs=0.03)


def test_a_vehicle_without_sim_state_is_named_with_the_fix():
    port = free_port()
    bridge = PoseBridge(BridgeConfig(connect=f"udpin:127.0.0.1:{port}", pose_port=free_port(), timeout_s=3.0))
    try:
        bridge.open()
        with SitlVehicle(autopilot="px4", speedup=5, mavlink_port=port), \
                pytest.raises(CompanionError, match="no SIM_STATE .*not a SITL, or its sim-state messages are off") \
                as err:
            bridge.run()
        assert "ArduPilot SITL" in err.value.fix
    finally:
        bridge.close()


def test_no_autopilot_at_the_url_is_a_clear_error():
    bridge = PoseBridge(BridgeConfig(connect=f"tcp:127.0.0.1:{free_port(socket.SOCK_STREAM)}", timeout_s=1.0))
    try:
        with pytest.raises(CompanionError, match="cannot connect to the autopilot"):
            bridge.run()
    finally:
        bridge.close()


def test_python_m_sim_posebridge_reports_the_error_and_exits_2(capsys):
    from sim.__main__ import main

    assert main(["posebridge", "--connect", f"tcp:127.0.0.1:{free_port(socket.SOCK_STREAM)}", "--timeout", "1",
                 "--pose-port", str(free_port())]) == 2
    err = capsys.readouterr().err
    assert "cannot connect to the autopilot" in err and "fix:" in err


def test_external_rig_camera_renders_from_the_sitl_truth(tmp_path):
    """Camera + bridge (``ExternalSitlRig``) beside an ArduPilot-flavoured SITL with a 1.5 m GNSS bias: the frames
    stream, and the recorded camera pose is where the vehicle truly is, not where its GPS puts it."""
    from companion.capture.simcam import SimCameraSource
    from companion.mission import load_mission, plan_scan
    from sim.camera.recording import load_recording
    from sim.external_rig import ExternalSitlRig
    from tests.sitl import ROOT

    mission = ROOT / "missions/demo-facade.yaml"
    home = plan_scan(load_mission(mission)).home
    port = free_port()
    truth_log = tmp_path / "truth.jsonl"
    rig = ExternalSitlRig(mission, f"udpin:127.0.0.1:{port}", log_dir=tmp_path / "logs", width_px=160, fps=5.0,
                          record_dir=tmp_path / "rec")
    assert rig.capture == f"sim://127.0.0.1:{rig.stream_port}"
    frames = []
    vehicle = SitlVehicle(autopilot="ardupilot", speedup=2, mavlink_port=port, truth_log=truth_log, home_yaw=90,
                          home=f"{home.lat},{home.lon},{home.alt_amsl_m}", gnss_bias=(0, -1.5, 0))
    with vehicle, rig, SimCameraSource(port=rig.stream_port, idle_timeout_s=20.0) as src:
        for f in src:
            frames.append(f)
            if len(frames) == 3:
                break
    assert len(frames) == 3
    rec = load_recording(tmp_path / "rec")
    assert len(rec) >= 3
    row = json.loads(truth_log.read_text().splitlines()[-1])
    for i in range(len(rec)):
        pose = rec.camera_pose(i)
        assert (pose.lat, pose.lon) == pytest.approx((row["lat"], row["lon"]), abs=2e-7)
        n, _, _ = pymap3d.geodetic2ned(row["nav_lat"], row["nav_lon"], home.alt_amsl_m, pose.lat, pose.lon,
                                       home.alt_amsl_m)
        assert float(n) == pytest.approx(-1.5, abs=0.03)  # the estimate is elsewhere
        assert pose.yaw_deg == pytest.approx(90.0, abs=1e-3)

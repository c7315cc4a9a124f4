"""Mission protocol server and in-process mission execution of the simulated vehicle (no MAVLink peer)."""

from __future__ import annotations

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink  # common + ArduPilot messages

from companion.mission import items as mi
from sim.vehicle import flavours as fl
from sim.vehicle.autopilot import SimVehicle, VehicleConfig
from sim.vehicle.mission_server import MissionServer

HOME_X, HOME_Y = 375663800, 1269781500


def _item(seq, command, frame=mi.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, p=(0.0, 0.0, 0.0, float("nan")), x=HOME_X,
          y=HOME_Y, z=5.0):
    return mi.MissionItem(seq, frame, command, 0, 1, *p, x, y, z)


class _Wire:
    """A GCS talking to a MissionServer: encodes messages as the GCS, decodes what the server sends."""

    def __init__(self, validate=lambda item, i: None, max_items=50):
        self.vehicle = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
        self.gcs = mavlink.MAVLink(None, srcSystem=245, srcComponent=190)
        self.out = []
        self.missions = []
        self.server = MissionServer(self.vehicle, self.out.append, validate, self.missions.append, max_items)

    def send(self, msg):
        buf = msg.pack(self.gcs)
        for m in self.vehicle.parse_buffer(buf) or []:
            assert self.server.handle(m)

    def take(self):
        out, self.out[:] = list(self.out), []
        return out


def _upload(wire: _Wire, items, duplicate_every=None):
    wire.send(wire.gcs.mission_count_encode(1, 1, len(items), 0))
    while True:
        replies = wire.take()
        assert len(replies) == 1
        r = replies[0]
        if r.get_type() == "MISSION_ACK":
            return r
        assert r.get_type() == "MISSION_REQUEST_INT"
        it = items[r.seq]
        msg = wire.gcs.mission_item_int_encode(1, 1, it.seq, it.frame, it.command, 0, 1, it.param1, it.param2,
                                               it.param3, it.param4, it.x, it.y, it.z, 0)
        wire.send(msg)
        if duplicate_every and r.seq % duplicate_every == 0 and r.seq + 1 < len(items):
            wire.take()  # request for seq+1 ...
            wire.send(msg)  # ... then a duplicate of seq arrives (its first request looked lost to the GCS)
            again = wire.take()
            assert again[0].get_type() == "MISSION_REQUEST_INT" and again[0].seq == r.seq + 1
            wire.out.append(again[0])


def test_upload_download_and_duplicates():
    wire = _Wire()
    items = [_item(i, mi.MAV_CMD_NAV_WAYPOINT, z=5.0 + i) for i in range(6)]
    ack = _upload(wire, items, duplicate_every=2)
    assert ack.type == mavlink.MAV_MISSION_ACCEPTED
    assert [it.z for it in wire.missions[-1]] == [it.z for it in items]
    wire.send(wire.gcs.mission_request_list_encode(1, 1, 0))
    (count,) = wire.take()
    assert count.get_type() == "MISSION_COUNT" and count.count == 6
    wire.send(wire.gcs.mission_request_int_encode(1, 1, 3, 0))
    (item,) = wire.take()
    assert item.get_type() == "MISSION_ITEM_INT" and item.seq == 3 and item.z == 8.0


def test_rejections_name_the_reason():
    wire = _Wire(validate=fl.Px4().validate, max_items=5)
    wire.send(wire.gcs.mission_count_encode(1, 1, 6, 0))
    (ack,) = wire.take()
    assert ack.get_type() == "MISSION_ACK" and ack.type == mavlink.MAV_MISSION_NO_SPACE
    bad = [_item(0, mi.MAV_CMD_NAV_TAKEOFF), _item(1, 31000)]  # 31000: a user command PX4 would not know
    ack = _upload(wire, bad)
    assert ack.type == mavlink.MAV_MISSION_UNSUPPORTED
    assert wire.missions == []  # nothing replaced the (empty) mission


def test_clear_all():
    wire = _Wire()
    _upload(wire, [_item(0, mi.MAV_CMD_NAV_WAYPOINT)])
    wire.send(wire.gcs.mission_clear_all_encode(1, 1, 0))
    (ack,) = wire.take()
    assert ack.type == mavlink.MAV_MISSION_ACCEPTED and wire.missions[-1] == []


def test_vehicle_flies_a_small_mission_in_process():
    # port 9: discard, nobody listens; home kept still (not about PX4's home correction)
    v = SimVehicle(VehicleConfig(pose_port=None, target=("127.0.0.1", 9), home_shift_m=0.0))
    try:
        north = 375663800 + 900  # ~10 m north of home
        items = [
            _item(0, mi.MAV_CMD_NAV_TAKEOFF, z=6.0),
            _item(1, mi.MAV_CMD_DO_CHANGE_SPEED, frame=mi.MAV_FRAME_MISSION, p=(1.0, 3.0, -1.0, 0.0), x=0, y=0, z=0),
            _item(2, mi.MAV_CMD_NAV_WAYPOINT, p=(1.0, 0.5, 0.0, 0.0), x=north, z=6.0),
            _item(3, mi.MAV_CMD_NAV_LAND, p=(0.0, 0.0, 0.0, float("nan")), x=0, y=0, z=0.0),
        ]
        v._on_new_mission(items)
        assert v.arm() is None
        assert v.set_mode(fl.MISSION) is None
        reached, max_speed, max_alt = [], 0.0, 0.0
        for _ in range(int(120 / 0.02)):
            before = v.reached_seq
            v.step()
            if v.reached_seq != before:
                reached.append(v.reached_seq)
            st = v.model.state
            max_speed = max(max_speed, float(np.hypot(st.vel[0], st.vel[1])))
            max_alt = max(max_alt, -st.pos[2])
            if not v.armed:
                break
        assert reached == [0, 1, 2, 3]
        assert not v.armed and v.on_ground
        assert max_speed <= 3.0 + 0.3  # DO_CHANGE_SPEED 3 m/s honoured (small overshoot from gusts: none here)
        assert 5.7 < max_alt < 6.5
        assert abs(v.model.state.pos[0] - 10.0) < 0.6  # landed where the waypoint was
        assert v.mission_finished
    finally:
        v.close()


def test_rtl_returns_home_and_disarms():
    v = SimVehicle(VehicleConfig(pose_port=None, target=("127.0.0.1", 9), home_shift_m=0.0))
    try:
        v.arm()
        v.set_mode(fl.TAKEOFF)
        for _ in range(int(10 / 0.02)):
            v.step()
        assert v.mode == fl.HOLD and -v.model.state.pos[2] > 2.0
        v.model.state.pos[:2] = [20.0, -5.0]  # pretend it flew away
        v.set_mode(fl.RTL)
        for _ in range(int(120 / 0.02)):
            v.step()
            if not v.armed:
                break
        assert not v.armed
        assert np.hypot(*v.model.state.pos[:2]) < 0.5
    finally:
        v.close()


def _hovering(cfg: VehicleConfig) -> SimVehicle:
    v = SimVehicle(cfg)
    v.arm()
    v.set_mode(fl.TAKEOFF)
    for _ in range(int(8 / 0.02)):
        v.step()
    assert v.mode == fl.HOLD
    return v


def test_gps_glitch_moves_the_real_vehicle_and_flags_gps_unhealthy():
    v = _hovering(VehicleConfig(pose_port=None, target=("127.0.0.1", 9), home_shift_m=0.0, gps_glitch_at_s=10.0,
                                gps_glitch_m=5.0, gps_glitch_s=4.0))
    try:
        start = v.model.state.pos.copy()
        worst = 0.0
        gps_ok_during = []
        while v.t < 14.0:
            v.step()
            if 10.5 < v.t < 13.9:
                worst = max(worst, float(np.linalg.norm(v.model.state.pos[:2] - start[:2])))
                gps_ok_during.append(bool(v._sys_status().onboard_control_sensors_health
                                          & mavlink.MAV_SYS_STATUS_SENSOR_GPS))
        assert worst > 2.0  # the controller followed the jumped estimate
        assert not any(gps_ok_during)
        for _ in range(int(20 / 0.02)):
            v.step()
        assert np.linalg.norm(v.model.state.pos[:2] - start[:2]) < 0.3  # and came back when GPS recovered
    finally:
        v.close()


def test_low_battery_triggers_rtl():
    v = _hovering(VehicleConfig(pose_port=None, target=("127.0.0.1", 9), home_shift_m=0.0))
    try:
        v.battery.consumed_mah = v.battery.capacity_mah * 0.86
        for _ in range(int(5 / 0.02)):
            v.step()
        assert v.mode == fl.RTL and v.battery_failsafe
    finally:
        v.close()


def test_ardupilot_refuses_more_than_650_items_and_says_so():
    """Real ArduCopter 4.7.0-dev SITL: a 1628-item upload -> MISSION_ACK NO_SPACE, then the STATUSTEXT "Only 650
    items are supported"; 650 items fit. (The simulator used to take up to 500 on both flavours, silently.)"""
    gcs = mavlink.MAVLink(None, srcSystem=245, srcComponent=190)
    for autopilot, limit, text in (("ardupilot", 650, "Only 650 items are supported"), ("px4", 500, None)):
        v = SimVehicle(VehicleConfig(autopilot=autopilot, pose_port=None, target=("127.0.0.1", 9), home_shift_m=0.0))
        try:
            sent = []
            v.mav.send = sent.append
            for count in (limit + 1, limit):
                for m in v.mav.parse_buffer(gcs.mission_count_encode(1, 1, count, 0).pack(gcs)) or []:
                    assert v.missions.handle(m)
            kinds = [m.get_type() for m in sent]
            assert sent[0].get_type() == "MISSION_ACK" and sent[0].type == mavlink.MAV_MISSION_NO_SPACE
            said = [m.text.decode() if isinstance(m.text, bytes) else m.text
                    for m in sent if m.get_type() == "STATUSTEXT"]
            assert said == ([text] if text else [])
            if text:
                assert sent[1].get_type() == "STATUSTEXT" and sent[1].severity == mavlink.MAV_SEVERITY_WARNING
            assert kinds[-1].startswith("MISSION_REQUEST") and sent[-1].seq == 0  # the limit itself is accepted
        finally:
            v.close()

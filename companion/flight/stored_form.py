"""What each autopilot firmware hands back for an uploaded mission item, and when that still means the same item.

A download is compared with the upload by meaning, not bit for bit: each rule below is a form in which the firmware
stores a field, observed in the recorded real downloads (``../shared/data/real-firmware/``) and read from source.
Anything else (another command, coordinate, altitude beyond the rounding, order or count) is a real mismatch.

ArduCopter 4.7.0-dev @ 2598e9d4 (AP_Mission::mavlink_int_to_mission_cmd / mission_cmd_to_mavlink_int):
  * seq 0 is the vehicle's home, not the uploaded placeholder: not compared.
  * frame: commands with a location come back in the float twin of the INT frame (6 -> 3, 5 -> 0); commands
    without one (DO_*, CONDITION_*, NAV_RETURN_TO_LAUNCH) come back in frame 0 (2 -> 0).
  * z of commands with a location: whole centimetres, truncated (12.4536 -> 12.45).
  * NAV_WAYPOINT: param1 (hold) whole seconds, truncated (0.5 -> 0); params 2-4 are not stored (come back 0).
  * NAV_TAKEOFF: param1 whole units; params 2-4 come back 0.
  * NAV_LAND: param1 whole units; param4 keeps only a direction flag (-1 if negative, else +1); params 2-3 -> 0.
  * CONDITION_YAW: param3 (direction) and param4 (relative) are stored as integers (truncated).
  * DO_CHANGE_SPEED: param1 (speed type) is stored as an integer; param4 is not stored (0).
  * everything else as sent, up to float32.
PX4 main @ 02e73e3b6f:
  * everything as sent, up to float32 (NaN stays NaN), except the yaw (param4) of NAV_WAYPOINT / NAV_TAKEOFF /
    NAV_LAND, which PX4 keeps in radians wrapped to [0, 2pi) (359.99991 comes back 359.99988; -10 would come back
    350): compared as headings, within 0.001 degree.
  * ``current`` reflects the vehicle's current item, not the upload: not compared.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from companion.mission import items as mi
from companion.mission.firmware import check_autopilot, command_name

# ArduPilot commands stored with a location (AP_Mission::stored_in_location, the ones a scan plan can hold).
ARDUPILOT_LOCATION_COMMANDS = frozenset({mi.MAV_CMD_NAV_WAYPOINT, mi.MAV_CMD_NAV_TAKEOFF, mi.MAV_CMD_NAV_LAND,
                                         17, 18, 19, 30, 31, 82, 84, 85, 94})
ARDUPILOT_FLOAT_FRAME = {mi.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT: mi.MAV_FRAME_GLOBAL_RELATIVE_ALT,
                         mi.MAV_FRAME_GLOBAL_INT: mi.MAV_FRAME_GLOBAL}
PX4_YAW_COMMANDS = frozenset({mi.MAV_CMD_NAV_WAYPOINT, mi.MAV_CMD_NAV_TAKEOFF, mi.MAV_CMD_NAV_LAND})
YAW_TOLERANCE_DEG = 1e-3
PARAMS = ("param1", "param2", "param3", "param4")


@dataclass(frozen=True)
class Mismatch:
    """One field of one item that means something else on the vehicle than in the upload."""

    seq: int
    command: int
    field: str
    sent: float
    got: float
    rule: str = ""

    def describe(self) -> str:
        text = f"item {self.seq} ({command_name(self.command)}) {self.field}: the vehicle holds {self.got!r}, " \
               f"{self.sent!r} was sent"
        return text + (f" ({self.rule})" if self.rule else "")


def _f32(value: float) -> float:
    return float(np.float32(value))


def same_float(a: float, b: float) -> bool:
    """Equal once both went through a float32 MAVLink field (NaN equals NaN)."""
    if math.isnan(a) or math.isnan(b):
        return math.isnan(a) and math.isnan(b)
    return _f32(a) == _f32(b) or abs(a - b) <= 1e-6 * max(1.0, abs(a))


def _whole(value: float) -> float:
    """A float param kept in an integer field: truncated towards zero."""
    return float(math.trunc(value)) if math.isfinite(value) else value


def _truncated_cm(sent: float, got: float) -> bool:
    """``got`` is ``sent`` truncated to whole centimetres (allowing one float32 step either side)."""
    if not (math.isfinite(sent) and math.isfinite(got)):
        return False
    cm = got * 100.0
    if abs(cm - round(cm)) > 1e-3:
        return False
    drop = abs(sent) - abs(got)  # truncation moves towards zero, by less than 1 cm
    same_side = got == 0.0 or (sent > 0) == (got > 0)
    return same_side and -1e-4 <= drop < 0.01 + 1e-4


def _same_heading(a: float, b: float) -> bool:
    if math.isnan(a) or math.isnan(b):
        return math.isnan(a) and math.isnan(b)
    return abs((a - b + 180.0) % 360.0 - 180.0) <= YAW_TOLERANCE_DEG


def _ardupilot_params(s: mi.MissionItem) -> dict[str, tuple[float, str]]:
    """Expected stored params (and the rule's wording) for commands ArduPilot does not store as sent."""
    cmd = s.command
    if cmd == mi.MAV_CMD_NAV_WAYPOINT:
        return {"param1": (_whole(s.param1), "ArduCopter keeps the hold in whole seconds, truncated"),
                "param2": (0.0, "not stored by ArduCopter"), "param3": (0.0, "not stored by ArduCopter"),
                "param4": (0.0, "not stored by ArduCopter")}
    if cmd == mi.MAV_CMD_NAV_TAKEOFF:
        return {"param1": (_whole(s.param1), "stored as a whole number"), "param2": (0.0, "not stored"),
                "param3": (0.0, "not stored"), "param4": (0.0, "not stored")}
    if cmd == mi.MAV_CMD_NAV_LAND:
        return {"param1": (_whole(s.param1), "stored as a whole number"), "param2": (0.0, "not stored"),
                "param3": (0.0, "not stored"),
                "param4": (-1.0 if s.param4 < 0 else 1.0, "ArduCopter keeps only a direction flag")}
    if cmd == mi.MAV_CMD_CONDITION_YAW:
        return {"param3": (_whole(s.param3), "stored as an integer"),
                "param4": (_whole(s.param4), "stored as an integer")}
    if cmd == mi.MAV_CMD_DO_CHANGE_SPEED:
        return {"param1": (_whole(s.param1), "stored as an integer"), "param4": (0.0, "not stored")}
    return {}


def mismatches(s: mi.MissionItem, g: mi.MissionItem, autopilot: str) -> list[Mismatch]:
    """The fields in which the downloaded item ``g`` means something else than the uploaded item ``s``."""
    check_autopilot(autopilot)
    out: list[Mismatch] = []

    def bad(field: str, sent, got, rule: str = "") -> None:
        out.append(Mismatch(s.seq, s.command, field, sent, got, rule))

    if g.seq != s.seq:
        bad("seq", s.seq, g.seq)
    if g.command != s.command:
        bad("command", s.command, g.command, f"the vehicle holds a {command_name(g.command)} here")
        return out
    ardupilot = autopilot == "ardupilot"
    if ardupilot and s.seq == 0:
        return out  # home: the vehicle's own, whatever was uploaded
    located = s.command in ARDUPILOT_LOCATION_COMMANDS
    if ardupilot:
        frame = ARDUPILOT_FLOAT_FRAME.get(s.frame, s.frame) if located else mi.MAV_FRAME_GLOBAL
    else:
        frame = s.frame
    if g.frame != frame:
        bad("frame", s.frame, g.frame, f"expected {frame} on {autopilot}")
    if g.x != s.x:
        bad("x (latitude e7)" if located else "x", s.x, g.x)
    if g.y != s.y:
        bad("y (longitude e7)" if located else "y", s.y, g.y)
    if ardupilot and located:
        if not _truncated_cm(s.z, g.z):
            bad("z", s.z, g.z, "more than ArduCopter's truncation to whole centimetres")
    elif not same_float(s.z, g.z):
        bad("z", s.z, g.z)
    if g.autocontinue != s.autocontinue:
        bad("autocontinue", s.autocontinue, g.autocontinue)
    stored = _ardupilot_params(s) if ardupilot else {}
    for name in PARAMS:
        sent, got = getattr(s, name), getattr(g, name)
        if name in stored:
            want, rule = stored[name]
            if not same_float(want, got):
                bad(name, sent, got, f"expected {want!r}: {rule}")
        elif not ardupilot and name == "param4" and s.command in PX4_YAW_COMMANDS:
            if not _same_heading(sent, got):
                bad(name, sent, got, "PX4 keeps the yaw in radians; this is another heading")
        elif not same_float(sent, got):
            bad(name, sent, got)
    return out

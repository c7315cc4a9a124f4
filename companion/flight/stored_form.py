"""When a downloaded mission item still means the uploaded one, by the form its firmware stores it in.

A download is compared with the upload by meaning, not bit for bit: each firmware's home says how it stores an item
(``Autopilot.stored_form``: the frame it comes back in, an altitude truncated to centimetres, params kept in
another form, yaws compared as headings, an item it fills in itself), each rule observed in the recorded real
downloads (``../shared/data/real-firmware/``) and read from source (``companion/mission/autopilot/``). Anything
else (another command, coordinate, altitude beyond the rounding, order or count) is a real mismatch. ``current``
reflects the vehicle's current item, not the upload: not compared.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from companion.mission import items as mi
from companion.mission.autopilot import Autopilot, autopilot_for
from companion.mission.firmware import LOCATION_COMMANDS, command_name

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


def mismatches(s: mi.MissionItem, g: mi.MissionItem, autopilot: str | Autopilot) -> list[Mismatch]:
    """The fields in which the downloaded item ``g`` means something else than the uploaded item ``s``."""
    ap = autopilot_for(autopilot)
    out: list[Mismatch] = []

    def bad(field: str, sent, got, rule: str = "") -> None:
        out.append(Mismatch(s.seq, s.command, field, sent, got, rule))

    if g.seq != s.seq:
        bad("seq", s.seq, g.seq)
    if g.command != s.command:
        bad("command", s.command, g.command, f"the vehicle holds a {command_name(g.command)} here")
        return out
    form = ap.stored_form(s)
    if not form.compared:
        return out  # the vehicle's own (ArduPilot's home), whatever was uploaded
    located = s.command in LOCATION_COMMANDS
    if g.frame != form.frame:
        bad("frame", s.frame, g.frame, f"expected {form.frame} on {ap.flavour}")
    if g.x != s.x:
        bad("x (latitude e7)" if located else "x", s.x, g.x)
    if g.y != s.y:
        bad("y (longitude e7)" if located else "y", s.y, g.y)
    if form.z_truncated_cm:
        if not _truncated_cm(s.z, g.z):
            bad("z", s.z, g.z, f"more than {ap.label}'s truncation to whole centimetres")
    elif not same_float(s.z, g.z):
        bad("z", s.z, g.z)
    if g.autocontinue != s.autocontinue:
        bad("autocontinue", s.autocontinue, g.autocontinue)
    for name in PARAMS:
        sent, got = getattr(s, name), getattr(g, name)
        if name in form.params:
            want, rule = form.params[name]
            if not same_float(want, got):
                bad(name, sent, got, f"expected {want!r}: {rule}")
        elif name in form.heading_params:
            if not _same_heading(sent, got):
                bad(name, sent, got, f"{ap.label} keeps the yaw in radians; this is another heading")
        elif not same_float(sent, got):
            bad(name, sent, got)
    return out

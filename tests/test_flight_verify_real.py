"""Verify by meaning against what real firmware returned: the recorded uploads and downloads of ArduCopter 4.7 and
PX4 main (../shared/data/real-firmware/) must verify, and tampered downloads must be refused naming item and field.
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import pytest

from companion.flight.upload import compare_missions
from companion.mission import items as mi
from companion.mission.items import MissionItem

ROOT = Path(__file__).resolve().parents[1]
REAL = ROOT.parent / "shared" / "data" / "real-firmware"
FIRMWARE = {"ardupilot": "ardupilot-copter-4.7.0-dev", "px4": "px4-main-2026-03"}
MISSIONS = ("demo-facade", "paper-edge-18-storey")


def load_items(path: Path) -> list[MissionItem]:
    rows = json.loads(path.read_text())
    nan = float("nan")
    return [MissionItem(r["seq"], r["frame"], r["command"], r["current"], r["autocontinue"],
                        *(nan if r[k] is None else float(r[k]) for k in ("param1", "param2", "param3", "param4")),
                        r["x"], r["y"], float(r["z"])) for r in rows]


def recorded(autopilot: str, mission: str, what: str) -> list[MissionItem]:
    path = REAL / FIRMWARE[autopilot] / f"{mission}.{what}.json"
    if not path.exists():
        pytest.skip(f"recorded real-firmware data not found at {path} (shared/ beside the clone)")
    return load_items(path)


@pytest.mark.parametrize("mission", MISSIONS)
@pytest.mark.parametrize("autopilot", sorted(FIRMWARE))
def test_real_downloads_verify(autopilot, mission):
    sent, got = recorded(autopilot, mission, "uploaded"), recorded(autopilot, mission, "downloaded")
    assert len(sent) == len(got) > 20
    assert compare_missions(sent, got, autopilot) == []


@pytest.mark.parametrize("mission", MISSIONS)
def test_the_equivalence_is_per_firmware(mission):
    """Copter's stored forms are not accepted from PX4 (where they would be real changes)."""
    sent, got = recorded("ardupilot", mission, "uploaded"), recorded("ardupilot", mission, "downloaded")
    problems = compare_missions(sent, got, "px4")
    assert len(problems) > 30  # frames, holds, radius, yaw, centimetres, land flag


def _first(items, command, start=1):
    return next(k for k, it in enumerate(items) if it.command == command and k >= start)


TAMPER = {
    "latitude": lambda it: dataclasses.replace(it, x=it.x + 10),
    "altitude": lambda it: dataclasses.replace(it, z=it.z - 0.5),
    "altitude up": lambda it: dataclasses.replace(it, z=it.z + 0.02),
    "command": lambda it: dataclasses.replace(it, command=mi.MAV_CMD_NAV_LAND),
}


@pytest.mark.parametrize("change", sorted(TAMPER))
@pytest.mark.parametrize("autopilot", sorted(FIRMWARE))
def test_tampered_waypoint_is_refused_naming_item_and_field(autopilot, change):
    sent, got = recorded(autopilot, "demo-facade", "uploaded"), recorded(autopilot, "demo-facade", "downloaded")
    k = _first(got, mi.MAV_CMD_NAV_WAYPOINT, start=6)
    got[k] = TAMPER[change](got[k])
    problems = compare_missions(sent, got, autopilot)
    assert problems and problems[0].startswith(f"item {k} (NAV_WAYPOINT)")
    field = {"latitude": "x (latitude e7)", "altitude": "z", "altitude up": "z", "command": "command"}[change]
    assert f") {field}:" in problems[0]


@pytest.mark.parametrize("autopilot", sorted(FIRMWARE))
def test_tampered_order_count_and_speed_are_refused(autopilot):
    sent, got = recorded(autopilot, "demo-facade", "uploaded"), recorded(autopilot, "demo-facade", "downloaded")
    n = len(sent)
    assert compare_missions(sent, got[:-1], autopilot)[0] == f"the vehicle holds {n - 1} items, {n} were uploaded"
    k = _first(got, mi.MAV_CMD_NAV_WAYPOINT, start=8)
    swapped = list(got)
    swapped[k], swapped[k + 1] = (dataclasses.replace(got[k + 1], seq=k), dataclasses.replace(got[k], seq=k + 1))
    assert any(p.startswith(f"item {k} ") for p in compare_missions(sent, swapped, autopilot))
    s = _first(got, mi.MAV_CMD_DO_CHANGE_SPEED, start=5)
    faster = list(got)
    faster[s] = dataclasses.replace(got[s], param2=got[s].param2 * 2)
    assert compare_missions(sent, faster, autopilot)[0].startswith(f"item {s} (DO_CHANGE_SPEED) param2")


def test_copter_hold_truncation_is_accepted_but_a_lost_whole_second_is_not():
    sent, got = recorded("ardupilot", "demo-facade", "uploaded"), recorded("ardupilot", "demo-facade", "downloaded")
    k = _first(sent, mi.MAV_CMD_NAV_WAYPOINT, start=6)
    sent[k] = dataclasses.replace(sent[k], param1=2.7)
    got[k] = dataclasses.replace(got[k], param1=2.0)
    assert compare_missions(sent, got, "ardupilot") == []  # whole seconds, truncated
    got[k] = dataclasses.replace(got[k], param1=1.0)
    problem = compare_missions(sent, got, "ardupilot")[0]
    assert problem.startswith(f"item {k} (NAV_WAYPOINT) param1") and "whole seconds" in problem


def test_px4_yaw_is_a_heading_stored_in_radians():
    sent, got = recorded("px4", "demo-facade", "uploaded"), recorded("px4", "demo-facade", "downloaded")
    k = _first(sent, mi.MAV_CMD_NAV_WAYPOINT)
    assert sent[k].param4 != got[k].param4  # one float32 step apart on the real download
    sent[k] = dataclasses.replace(sent[k], param4=-10.0)
    got[k] = dataclasses.replace(got[k], param4=350.0)
    assert compare_missions(sent, got, "px4") == []
    got[k] = dataclasses.replace(got[k], param4=349.0)
    assert "param4" in compare_missions(sent, got, "px4")[0]
    got[k] = dataclasses.replace(got[k], param4=math.nan)
    assert "param4" in compare_missions(sent, got, "px4")[0]

"""One home per autopilot (companion/mission/autopilot/): the firmware is chosen once, from the HEARTBEAT's
MAV_AUTOPILOT, an autopilot that is neither PX4 nor ArduPilot is refused naming its number and the fix, and no
module outside the homes branches on a flavour's name."""

from __future__ import annotations

import ast
import asyncio
from pathlib import Path

import pytest

from companion.errors import CompanionError
from companion.flight.connection import connect
from companion.mission.autopilot import Flavour, autopilot_for, autopilot_from_heartbeat
from tests.sitl import SitlVehicle

ROOT = Path(__file__).resolve().parents[1]
HOMES = ROOT / "companion" / "mission" / "autopilot"


def test_each_heartbeat_number_has_its_home_and_flavour():
    assert autopilot_from_heartbeat(12) is autopilot_for(Flavour.PX4) is autopilot_for("px4")
    assert autopilot_from_heartbeat(3) is autopilot_for("ardupilot")
    assert [str(f) for f in Flavour] == ["px4", "ardupilot"]
    assert autopilot_for("ardupilot").first_item_seq == 1 and autopilot_for("px4").first_item_seq == 0


@pytest.mark.parametrize("number, name", [(0, "MAV_AUTOPILOT_GENERIC"), (9, "MAV_AUTOPILOT_PPZ"), (250, "")])
def test_an_unknown_autopilot_is_refused_naming_its_number_and_the_fix(number, name):
    with pytest.raises(CompanionError) as err:
        autopilot_from_heartbeat(number)
    assert f"names autopilot {number}" in err.value.problem and name in err.value.problem
    assert "PX4 (12), ArduPilot (3)" in err.value.problem and "--autopilot px4|ardupilot" in err.value.fix


def test_an_unknown_flavour_name_is_refused():
    with pytest.raises(CompanionError, match="unknown autopilot flavour 'inav'") as err:
        autopilot_for("inav")
    assert err.value.fix == "use 'px4' or 'ardupilot'"


@pytest.mark.sitl
def test_a_vehicle_whose_heartbeat_names_another_autopilot_is_refused_at_connect(tmp_path):
    """The simulator told to send MAV_AUTOPILOT_GENERIC (0): connect refuses it (before, it was flown as PX4)."""
    with SitlVehicle(speedup=5, heartbeat_autopilot=0, log_path=tmp_path / "sim.log") as v:
        with pytest.raises(CompanionError) as err:
            asyncio.run(connect(v.url, timeout_s=30))
        assert "names autopilot 0 (MAV_AUTOPILOT_GENERIC)" in err.value.problem, err.value.problem
        vehicle = asyncio.run(connect(v.url, timeout_s=30, autopilot="px4"))  # said explicitly: flown as PX4
        try:
            assert vehicle.autopilot == Flavour.PX4
        finally:
            vehicle.close()


def _flavour_comparisons(path: Path, root: Path = ROOT) -> list[str]:
    """``x == "px4"`` / ``"ardupilot" != y`` / ``x in ("px4", ...)`` in a module: a branch on a flavour's name."""
    names = {str(f) for f in Flavour}
    found = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if not isinstance(node, ast.Compare):
            continue
        for operand in [node.left, *node.comparators]:
            consts = [operand] if isinstance(operand, ast.Constant) else list(getattr(operand, "elts", []))
            if any(isinstance(c, ast.Constant) and c.value in names for c in consts):
                found.append(f"{path.relative_to(root)}:{node.lineno}")
    return found


def test_no_module_outside_the_autopilot_homes_compares_a_flavour_name():
    found = [hit for path in sorted((ROOT / "companion").rglob("*.py")) if HOMES not in path.parents
             for hit in _flavour_comparisons(path)]
    assert not found, "flavour names compared outside companion/mission/autopilot/ (ask the home instead):\n" + \
        "\n".join(found)


def test_the_comparison_finder_finds_one(tmp_path):
    probe = tmp_path / "companion" / "probe.py"
    probe.parent.mkdir()
    probe.write_text('a = x == "ardupilot"\nb = "px4" != y\nc = y in ("px4", "z")\nd = y == "auto"\n')
    found = _flavour_comparisons(probe, tmp_path)
    assert found == ["companion/probe.py:1", "companion/probe.py:2", "companion/probe.py:3"]

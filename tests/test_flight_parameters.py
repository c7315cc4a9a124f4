"""Per-flight parameters (set, always restored), the failsafe check, and waypoint progress: no simulator."""

from __future__ import annotations

import asyncio
import logging
import struct

import pytest

from companion.errors import CompanionError
from companion.flight.failsafe import (
    FailsafeSettings,
    failsafe_overrides,
    failsafe_warnings,
    required_return_alt,
)
from companion.flight.parameters import FlightParameters, read_parameter
from companion.flight.progress import WaypointProgress, navigation_seqs, waypoints_done
from companion.mission import items as mi
from companion.mission import load_mission, plan_scan
from tests.sitl import ROOT


class _ParamError(Exception):
    def __init__(self, name: str):
        super().__init__(name)
        self.result = type("R", (), {"name": name})()


class _Params:
    """mavsdk's param plugin as PX4 answers it: each parameter has one type, asking with the other is WRONG_TYPE.
    Ints travel byte-wise in the float (as PX4 does), so a float read of an int would be garbage, never a value."""

    def __init__(self, values: dict, fail_set: set[str] = frozenset()):
        self.values = dict(values)
        self.fail_set = set(fail_set)
        self.writes: list[tuple[str, float]] = []

    def _get(self, name, want_int):
        if name not in self.values:
            raise _ParamError("DOES_NOT_EXIST")
        if isinstance(self.values[name], int) != want_int:
            raise _ParamError("WRONG_TYPE")
        return self.values[name]

    async def get_param_float(self, name):
        return self._get(name, False)

    async def get_param_int(self, name):
        return self._get(name, True)

    async def _set(self, name, value, is_int):
        self._get(name, is_int)
        if name in self.fail_set:
            raise _ParamError("FAILED")
        self.values[name] = value
        self.writes.append((name, value))

    async def set_param_float(self, name, value):
        await self._set(name, value, False)

    async def set_param_int(self, name, value):
        await self._set(name, value, True)


class _LossyParams(_Params):
    """Each request first times out ``timeouts`` times, as mavsdk reports a request whose re-sends were all lost."""

    def __init__(self, values: dict, timeouts: int):
        super().__init__(values)
        self.timeouts = timeouts
        self.left: dict[str, int] = {}

    def _get(self, name, want_int):
        left = self.left.setdefault(name, self.timeouts)
        if left:
            self.left[name] = left - 1
            raise _ParamError("TIMEOUT")
        return super()._get(name, want_int)


def test_a_timed_out_read_or_write_is_asked_again():
    """CI's SITL run with 20 % packet loss each way lost every re-send of one read: the flight stopped before
    take-off although the vehicle answered. Two timeouts in a row are ridden out; three are the error."""
    p = _LossyParams({"NAV_DLL_ACT": 0, "RTL_RETURN_ALT": 30.0}, timeouts=2)
    assert asyncio.run(read_parameter(p, "RTL_RETURN_ALT")).value == 30.0

    async def fly():
        async with FlightParameters(p, {"NAV_DLL_ACT": 2.0}):
            assert p.values["NAV_DLL_ACT"] == 2
    asyncio.run(fly())
    assert p.values["NAV_DLL_ACT"] == 0  # set and restored through the timeouts
    with pytest.raises(CompanionError, match=r"cannot read parameter RTL_RETURN_ALT .*\(TIMEOUT\)"):
        asyncio.run(read_parameter(_LossyParams({"RTL_RETURN_ALT": 30.0}, timeouts=3), "RTL_RETURN_ALT"))


def test_read_uses_the_parameter_own_type():
    p = _Params({"NAV_DLL_ACT": 0, "RTL_RETURN_ALT": 30.0})
    act, alt = asyncio.run(read_parameter(p, "NAV_DLL_ACT")), asyncio.run(read_parameter(p, "RTL_RETURN_ALT"))
    assert (act.value, act.is_int, alt.value, alt.is_int) == (0.0, True, 30.0, False)
    with pytest.raises(CompanionError, match="cannot read parameter NOPE .*DOES_NOT_EXIST"):
        asyncio.run(read_parameter(p, "NOPE"))


def test_parameters_are_set_for_the_flight_and_restored_after_an_error(caplog):
    caplog.set_level(logging.INFO, logger="companion.flight.parameters")
    p = _Params({"NAV_DLL_ACT": 0, "RTL_RETURN_ALT": 30.0, "MPC_XY_CRUISE": 5.0})

    async def flight():
        async with FlightParameters(p, {"NAV_DLL_ACT": 2.0, "RTL_RETURN_ALT": 45.0, "MPC_XY_CRUISE": 5.0}) as fp:
            assert p.values == {"NAV_DLL_ACT": 2, "RTL_RETURN_ALT": 45.0, "MPC_XY_CRUISE": 5.0}
            assert isinstance(p.values["NAV_DLL_ACT"], int)  # written back as an int
            raise RuntimeError("the flight failed")
        return fp

    with pytest.raises(RuntimeError):
        asyncio.run(flight())
    assert p.values == {"NAV_DLL_ACT": 0, "RTL_RETURN_ALT": 30.0, "MPC_XY_CRUISE": 5.0}
    assert ("MPC_XY_CRUISE", 5.0) not in p.writes  # already right: not touched
    said = " | ".join(r.getMessage() for r in caplog.records)
    assert "NAV_DLL_ACT set to 2 for this flight (was 0)" in said and "RTL_RETURN_ALT restored to 30" in said


def test_a_refused_set_restores_what_was_already_set():
    p = _Params({"A": 1.0, "B": 2.0}, fail_set={"B"})

    async def flight():
        async with FlightParameters(p, {"A": 3.0, "B": 4.0}):
            pytest.fail("the flight must not start")

    with pytest.raises(CompanionError, match="did not accept B = 4"):
        asyncio.run(flight())
    assert p.values == {"A": 1.0, "B": 2.0}


def test_a_failed_restore_is_reported_with_the_value_to_set_by_hand():
    p = _Params({"A": 1.0})

    async def flight():
        async with FlightParameters(p, {"A": 3.0}) as fp:
            p.fail_set.add("A")
        return fp

    fp = asyncio.run(flight())
    assert fp.restore_failures == ["A (set it back to 1)"] and [c.name for c in fp.applied] == ["A"]


def test_no_restore_is_attempted_over_a_dead_link():
    """Real ArduCopter SITL, --link-dead 20: the restore over the dead link waited 5 s for mavsdk's retries, past
    the limit. Once the link is known dead, the values to set by hand are reported at once."""
    p = _Params({"A": 1.0})

    async def flight():
        async with FlightParameters(p, {"A": 3.0}) as fp:
            fp.unreachable = "the link is dead"
        return fp

    fp = asyncio.run(flight())
    assert fp.restore_failures == ["A (set it back to 1)"]
    assert p.writes == [("A", 3.0)]  # set for the flight; no write attempted over the dead link


def test_px4_int_parameters_are_bytewise_in_the_float():
    # why the type matters: PX4 sends NAV_DLL_ACT=2 as the float whose bytes are the int 2, a denormal ~2.8e-45
    raw = struct.unpack("<f", struct.pack("<i", 2))[0]
    assert 0 < raw < 1e-44


def _settings(autopilot, action, alt_m):
    return FailsafeSettings(autopilot, action, alt_m)


def test_failsafe_warnings_for_the_real_defaults_on_the_demo():
    plan = plan_scan(load_mission(ROOT / "missions/demo-facade.yaml"))
    need = required_return_alt(plan)
    assert need.alt_m == pytest.approx(18.0) and "transit altitude" in need.reason
    copter = failsafe_warnings(_settings("ardupilot", 0, 15.0), need)
    assert len(copter) == 2
    assert "FS_GCS_ENABLE=0" in copter[0] and "--lost-link-action rtl" in copter[0]
    assert "RTL_ALT is 15 m, below the transit altitude 18.0 m" in copter[1] and "--return-alt" in copter[1]
    px4 = failsafe_warnings(_settings("px4", 0, 30.0), need)
    assert len(px4) == 1 and "NAV_DLL_ACT=0" in px4[0]
    assert failsafe_warnings(_settings("px4", 2, 30.0), need) == []
    assert failsafe_warnings(_settings("ardupilot", 2, 20.0), need)[0].startswith("lost-link failsafe FS_GCS_ENABLE=2")


def test_failsafe_overrides_in_each_firmware_units():
    plan = plan_scan(load_mission(ROOT / "missions/demo-facade.yaml"))
    need = required_return_alt(plan)
    assert failsafe_overrides("ardupilot", link_action="rtl", return_alt="auto", need=need) == {
        "FS_GCS_ENABLE": 1.0, "RTL_ALT": 1800.0}  # centimetres
    assert failsafe_overrides("px4", link_action="land", return_alt="25", need=need) == {
        "NAV_DLL_ACT": 3.0, "RTL_RETURN_ALT": 25.0}
    # auto never lowers a return altitude that is already high enough
    assert failsafe_overrides("px4", link_action=None, return_alt="auto", need=need,
                              current=_settings("px4", 0, 30.0)) == {}
    with pytest.raises(CompanionError, match="not a height"):
        failsafe_overrides("px4", link_action=None, return_alt="high", need=need)


def test_wall_top_can_set_the_return_altitude():
    m = load_mission(ROOT / "missions/demo-facade.yaml")
    plan = plan_scan(m.model_copy(update={"transit_alt_m": 10.0, "entrance_alt_m": 10.0, "exit_alt_m": 10.0}))
    need = required_return_alt(plan)
    assert "wall's top" in need.reason and need.alt_m == pytest.approx(m.facade.height_m + m.margins.roof_m)


def test_progress_counts_waypoints_not_do_items(caplog):
    plan = plan_scan(load_mission(ROOT / "missions/demo-facade.yaml"))
    items = plan.mavlink_items("px4")
    nav = navigation_seqs(items)
    assert all(items[s].command < 100 for s in nav) and len(nav) < len(items)
    # the item counter jumped 1 -> 5 -> 7 over DO items; waypoints move one at a time
    steps = [waypoints_done(nav, seq, len(items)) for seq in range(len(items) + 1)]
    assert all(b - a in (0, 1) for a, b in zip(steps, steps[1:], strict=False))
    assert steps[-1] == len(nav)
    ardu = plan.mavlink_items("ardupilot")
    assert len(nav) == len(plan.waypoints)
    # the home placeholder is not a waypoint (ArduPilot flies the plain plan: no bottom band after PX4's home window)
    assert len(navigation_seqs(ardu, first_seq=1)) == len(plan.for_autopilot("ardupilot").waypoints)

    caplog.set_level(logging.INFO, logger="companion.flight.progress")
    prog = WaypointProgress(items, enabled=True, terminal=False)
    for seq in range(len(items)):
        for _ in range(3):  # the supervisor asks ten times a second, whether anything changed or not
            prog.update(seq)
    prog.close()
    lines = [r.getMessage() for r in caplog.records if r.getMessage().startswith("progress:")]
    # one line per waypoint count, each once: not a redraw per update, nor the same line every few seconds
    assert lines == [f"progress: waypoint {n}/{len(nav)}" for n in range(steps[len(items) - 1] + 1)]
    assert prog.done == steps[len(items) - 1]


def test_item_lists_without_a_plan_still_get_a_return_altitude():
    items = [mi.MissionItem(0, 6, mi.MAV_CMD_NAV_TAKEOFF, 1, 1, 0, 0, 0, 0, 1, 1, 12.0),
             mi.MissionItem(1, 2, mi.MAV_CMD_DO_CHANGE_SPEED, 0, 1, 1, 2, -1, 0, 0, 0, 0.0)]
    assert required_return_alt(items).alt_m == 12.0

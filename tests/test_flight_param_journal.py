"""The parameter journal (written before every change, dropped once restored), the restore of what a killed run
left, and the parameters that make the lost-link failsafe watch the companion: no simulator, a fake param plugin."""

from __future__ import annotations

import asyncio
import json
from dataclasses import dataclass

import pytest

from companion.errors import CompanionError
from companion.flight.link_watch import link_watch_overrides, watched_by_gcs_id
from companion.flight.param_journal import ParamJournal, VehicleIdentity, state_dir
from companion.flight.parameters import FlightParameters
from companion.flight.restore import refuse_unless_restored, restore_left_parameters, uid_text
from tests.test_flight_parameters import _ParamError, _Params

ME = VehicleIdentity(1, "00000000000003e8")


@dataclass
class _Vehicle:
    param: _Params
    autopilot: str = "ardupilot"
    system_id: int = 1
    own_system_id: int = 245


class _JournalingParams(_Params):
    """Records what the journal file held at the moment each PARAM_SET went out."""

    def __init__(self, values, journal: ParamJournal, **kw):
        super().__init__(values, **kw)
        self.journal = journal
        self.journal_at_write: list[dict] = []

    async def _set(self, name, value, is_int):
        self.journal_at_write.append({e.name: (e.before, e.during) for e in self.journal.entries()})
        await super()._set(name, value, is_int)


def _killed_flight(params, wanted, journal):
    """A flight that sets its parameters and then dies without any way out running (kill -9)."""

    async def go():
        await FlightParameters(params, wanted, journal).__aenter__()

    asyncio.run(go())


def test_each_change_is_journaled_before_it_is_made_and_dropped_once_restored(tmp_path):
    journal = ParamJournal(tmp_path, ME, "ardupilot")
    p = _JournalingParams({"WP_YAW_BEHAVIOR": 2, "RTL_ALT": 1500.0}, journal)

    async def flight():
        async with FlightParameters(p, {"WP_YAW_BEHAVIOR": 0.0, "RTL_ALT": 1800.0}, journal):
            on_disk = json.loads(journal.path.read_text())
            assert on_disk["vehicle"] == {"system_id": 1, "uid": "00000000000003e8"}
            assert [(c["name"], c["before"], c["during"]) for c in on_disk["changes"]] == [
                ("WP_YAW_BEHAVIOR", 2.0, 0.0), ("RTL_ALT", 1500.0, 1800.0)]
            assert all(c["time_utc"].endswith("+00:00") for c in on_disk["changes"])

    asyncio.run(flight())
    # the first write went out with its own entry already on disk, the second with both
    assert p.journal_at_write[0] == {"WP_YAW_BEHAVIOR": (2.0, 0.0)}
    assert p.journal_at_write[1]["RTL_ALT"] == (1500.0, 1800.0)
    assert not journal.path.exists()  # all restored: nothing left to do for the next run
    assert p.values == {"WP_YAW_BEHAVIOR": 2, "RTL_ALT": 1500.0}


def test_what_a_killed_run_left_is_restored_by_the_next_and_the_journal_goes(tmp_path):
    vehicle = _Vehicle(_Params({"WP_YAW_BEHAVIOR": 2, "FS_GCS_ENABLE": 0, "RTL_ALT": 1500.0}))
    _killed_flight(vehicle.param, {"WP_YAW_BEHAVIOR": 0.0, "FS_GCS_ENABLE": 1.0, "RTL_ALT": 1800.0},
                   ParamJournal(tmp_path, ME, "ardupilot"))
    assert vehicle.param.values == {"WP_YAW_BEHAVIOR": 0, "FS_GCS_ENABLE": 1, "RTL_ALT": 1800.0}  # left changed

    outcome = asyncio.run(restore_left_parameters(vehicle, tmp_path, ME))
    assert vehicle.param.values == {"WP_YAW_BEHAVIOR": 2, "FS_GCS_ENABLE": 0, "RTL_ALT": 1500.0}
    assert outcome.complete and len(outcome.restored) == 3 and "RTL_ALT (1800 -> 1500)" in outcome.restored
    assert list(tmp_path.iterdir()) == []
    again = asyncio.run(restore_left_parameters(vehicle, tmp_path, ME))
    assert again.journal is None and "nothing to restore" in again.summary()


def test_a_value_someone_changed_since_is_left_and_one_never_set_needs_nothing(tmp_path):
    vehicle = _Vehicle(_Params({"A": 1.0, "B": 5.0}))
    journal = ParamJournal(tmp_path, ME, "ardupilot")
    journal.record("A", 1.0, 3.0, False)  # the run died before this PARAM_SET went out
    journal.record("B", 2.0, 4.0, False)  # set to 4, then a person set 5 on the ground station
    outcome = asyncio.run(restore_left_parameters(vehicle, tmp_path, ME))
    assert vehicle.param.writes == [] and vehicle.param.values == {"A": 1.0, "B": 5.0}
    assert outcome.already_back == ("A (1)",) and "B (is 5" in outcome.changed_since[0]
    assert not journal.path.exists()


def test_a_value_that_cannot_be_restored_stays_journaled_and_the_flight_is_refused(tmp_path):
    vehicle = _Vehicle(_Params({"FS_GCS_ENABLE": 1}, fail_set={"FS_GCS_ENABLE"}))
    journal = ParamJournal(tmp_path, ME, "ardupilot")
    journal.record("FS_GCS_ENABLE", 0, 1, True)
    outcome = asyncio.run(restore_left_parameters(vehicle, tmp_path, ME))
    assert not outcome.complete and [e.name for e in journal.entries()] == ["FS_GCS_ENABLE"]
    with pytest.raises(CompanionError) as err:
        refuse_unless_restored(outcome)
    assert "FS_GCS_ENABLE (set it back to 0)" in err.value.problem
    assert "companion restore --connect" in err.value.fix and str(journal.path) in err.value.fix


def test_another_vehicle_on_the_same_system_id_keeps_its_journal(tmp_path):
    other = ParamJournal(tmp_path, VehicleIdentity(1, "00000000000007d0"), "ardupilot")
    other.record("RTL_ALT", 1500.0, 1800.0, False)
    vehicle = _Vehicle(_Params({"RTL_ALT": 1800.0}))
    outcome = asyncio.run(restore_left_parameters(vehicle, tmp_path, ME))
    assert outcome.journal is None and vehicle.param.writes == [] and other.path.exists()
    assert "uid 00000000000007d0" in outcome.other_vehicles[0]
    assert not ME.same_vehicle(other.vehicle) and not ME.maybe_same_vehicle(other.vehicle)


def test_a_vehicle_that_reports_no_uid_is_not_given_a_journal_that_has_one(tmp_path):
    """Every vehicle ships as system 1: a simulator's journal must not be restored onto a real vehicle that did not
    send its uid in time, nor a vehicle's own journal ignored: the flight is refused, naming the file."""
    ParamJournal(tmp_path, ME, "ardupilot").record("WP_YAW_BEHAVIOR", 2, 0, True)
    vehicle = _Vehicle(_Params({"WP_YAW_BEHAVIOR": 0}))
    with pytest.raises(CompanionError, match="may belong to this vehicle") as err:
        asyncio.run(restore_left_parameters(vehicle, tmp_path, VehicleIdentity(1, None)))
    assert "WP_YAW_BEHAVIOR" in err.value.problem and vehicle.param.writes == []
    assert VehicleIdentity(1, None).same_vehicle(VehicleIdentity(1, None))


def test_a_refused_set_is_not_left_in_the_journal(tmp_path):
    journal = ParamJournal(tmp_path, ME, "px4")
    p = _Params({"A": 1.0, "B": 2.0}, fail_set={"B"})

    async def flight():
        async with FlightParameters(p, {"A": 3.0, "B": 4.0}, journal):
            pytest.fail("the flight must not start")

    with pytest.raises(CompanionError, match="did not accept B = 4"):
        asyncio.run(flight())
    assert p.values == {"A": 1.0, "B": 2.0} and not journal.path.exists()


def test_state_dir_order(tmp_path, monkeypatch):
    monkeypatch.setenv("COMPANION_STATE_DIR", str(tmp_path / "env"))
    monkeypatch.setenv("XDG_STATE_HOME", str(tmp_path / "xdg"))
    assert state_dir(tmp_path / "opt") == tmp_path / "opt"
    assert state_dir() == tmp_path / "env"
    monkeypatch.delenv("COMPANION_STATE_DIR")
    assert state_dir() == tmp_path / "xdg" / "companion"
    monkeypatch.delenv("XDG_STATE_HOME")
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert state_dir() == tmp_path / "home" / ".local" / "state" / "companion"


def test_uid_from_autopilot_version():
    assert uid_text({"uid": 1000, "uid2": [0] * 18}) == "00000000000003e8"
    assert uid_text({"uid": 0, "uid2": [0] * 17 + [7]}) == "00" * 17 + "07"
    assert uid_text({"uid": 0, "uid2": [0] * 18}) is None


def test_ardupilot_failsafe_is_made_to_watch_the_companions_heartbeats():
    assert not watched_by_gcs_id(245, 255, 0)  # as shipped: only 255 counts
    assert watched_by_gcs_id(245, 245, 0) and watched_by_gcs_id(245, 240, 250)
    assert not watched_by_gcs_id(245, 250, 255)
    new = _Vehicle(_Params({"MAV_GCS_SYSID": 255, "MAV_GCS_SYSID_HI": 0}))
    assert asyncio.run(link_watch_overrides(new)) == {"MAV_GCS_SYSID": 245.0}
    old = _Vehicle(_Params({"SYSID_MYGCS": 255}))  # before 4.7
    assert asyncio.run(link_watch_overrides(old)) == {"SYSID_MYGCS": 245.0}
    ranged = _Vehicle(_Params({"MAV_GCS_SYSID": 240, "MAV_GCS_SYSID_HI": 250}))
    assert asyncio.run(link_watch_overrides(ranged)) == {}
    with pytest.raises(CompanionError, match="MAV_GCS_SYSID"):
        asyncio.run(link_watch_overrides(_Vehicle(_Params({}))))


class _SilentOnUnknown(_Params):
    """ArduPilot as real ArduCopter V4.7.0-dev SITL answered: a read of a parameter it lacks gets no reply, which
    mavsdk reports as TIMEOUT (not DOES_NOT_EXIST); every request is counted."""

    def __init__(self, values: dict):
        super().__init__(values)
        self.requests: list[str] = []

    def _get(self, name, want_int):
        self.requests.append(name)
        if name not in self.values:
            raise _ParamError("TIMEOUT")
        return super()._get(name, want_int)


def test_a_gcs_id_range_the_firmware_lacks_costs_one_unanswered_read(caplog):
    """Real ArduCopter V4.7.0-dev has MAV_GCS_SYSID but no MAV_GCS_SYSID_HI, and leaves its read unanswered: the
    companion asked three times (about 10 s and three warnings before every flight). The optional range is asked
    once, and the flight still makes the failsafe watch the companion."""
    params = _SilentOnUnknown({"MAV_GCS_SYSID": 255})
    with caplog.at_level("INFO"):
        assert asyncio.run(link_watch_overrides(_Vehicle(params))) == {"MAV_GCS_SYSID": 245.0}
    assert params.requests.count("MAV_GCS_SYSID_HI") == 1
    assert "MAV_GCS_SYSID_HI: no answer from the vehicle" in caplog.text
    assert "asking again" not in caplog.text


def test_px4_link_loss_exceptions_in_auto_modes_are_cleared_for_the_flight():
    assert asyncio.run(link_watch_overrides(_Vehicle(_Params({"COM_DLL_EXCEPT": 0}), "px4"))) == {}
    assert asyncio.run(link_watch_overrides(_Vehicle(_Params({"COM_DLL_EXCEPT": 7}), "px4"))) == \
        {"COM_DLL_EXCEPT": 4.0}
    assert asyncio.run(link_watch_overrides(_Vehicle(_Params({}), "px4"))) == {}


def test_fly_restores_before_anything_else_and_refuses_to_fly_while_it_cannot(monkeypatch):
    from companion.flight import fly
    from companion.mission import items as mi

    calls = []

    class _Connected:
        autopilot = "ardupilot"

        def close(self):
            calls.append("close")

    async def connected(*args, **kwargs):
        return _Connected()

    async def cannot_restore(vehicle, state):
        calls.append(f"restore from {state}")
        raise CompanionError("a previous run left parameters changed ... RTL_ALT (set it back to 1500)", "fix")

    async def anything_else(*args, **kwargs):
        calls.append("something else")

    monkeypatch.setattr(fly, "connect", connected)
    monkeypatch.setattr(fly, "restore_before_flight", cannot_restore)
    monkeypatch.setattr(fly, "request_rates", anything_else)
    monkeypatch.setattr(fly, "_prepare_vehicle", anything_else)
    items = [mi.MissionItem(0, 6, mi.MAV_CMD_NAV_TAKEOFF, 1, 1, 0, 0, 0, 0, 1, 1, 12.0)]
    with pytest.raises(CompanionError, match="RTL_ALT"):
        asyncio.run(fly.fly_mission(items, "udp://:1", handle_signals=False, state_dir="/tmp/s"))
    assert calls == ["restore from /tmp/s", "close"]


def test_the_restore_lets_copter_clear_its_gcs_failsafe_before_disabling_it(tmp_path, monkeypatch, caplog):
    """The killed run's failsafe is still on: Copter clears it only at a counted heartbeat while FS_GCS_ENABLE is
    on, and refuses to arm in it. So one heartbeat period passes before anything is restored, then the failsafe
    is disabled before the GCS id goes back (newest first, as a flight restores)."""
    import logging

    from companion.flight import restore

    monkeypatch.setattr(restore, "HEARTBEAT_PERIOD_WAIT_S", 0.01)
    caplog.set_level(logging.INFO, logger="companion.flight.restore")
    vehicle = _Vehicle(_Params({"WP_YAW_BEHAVIOR": 2, "MAV_GCS_SYSID": 255, "FS_GCS_ENABLE": 0}))
    _killed_flight(vehicle.param, {"WP_YAW_BEHAVIOR": 0.0, "MAV_GCS_SYSID": 245.0, "FS_GCS_ENABLE": 1.0},
                   ParamJournal(tmp_path, ME, "ardupilot"))
    vehicle.param.writes.clear()
    asyncio.run(restore_left_parameters(vehicle, tmp_path, ME))
    said = [r.getMessage() for r in caplog.records]
    assert said[0].startswith("waiting 0.0 s for the vehicle to count a heartbeat from the companion")
    assert [name for name, _ in vehicle.param.writes] == ["FS_GCS_ENABLE", "MAV_GCS_SYSID", "WP_YAW_BEHAVIOR"]

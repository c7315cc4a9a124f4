"""Mission verify (compare uploaded vs downloaded items) and the fly command's option parsing; no processes."""

from __future__ import annotations

import math

import pytest

from companion.errors import CompanionError
from companion.flight.fly import mission_items_for
from companion.flight.upload import compare_missions, from_raw, to_raw
from companion.mission.items import MissionItem
from companion.onboard.commands import sim_options as _sim_options


def _items():
    return [
        MissionItem(0, 0, 16, 1, 1, 0.0, 0.0, 0.0, 0.0, 375663800, 1269781500, 30.0),
        MissionItem(1, 6, 22, 0, 1, 0.0, 0.0, 0.0, math.nan, 375663800, 1269781500, 18.0),
        MissionItem(2, 6, 16, 0, 1, 0.5, 0.3, 0.0, 359.9999, 375664640, 1269780085, 12.45),
    ]


def test_round_trip_through_mavsdk_items_is_identical():
    items = _items()
    back = from_raw(to_raw(items))
    assert compare_missions(items, back, "px4") == []
    assert to_raw(items)[0].current == 1 and to_raw(items)[1].current == 0


def test_differences_are_named_per_item_and_field():
    items = _items()
    got = list(items)
    got[2] = MissionItem(2, 6, 16, 0, 1, 0.5, 0.3, 0.0, 90.0, 375664640, 1269780086, 12.45)
    problems = compare_missions(items, got, "px4")
    assert len(problems) == 2 and all(p.startswith("item 2 (NAV_WAYPOINT)") for p in problems)
    assert "y (longitude e7)" in problems[0] and "param4" in problems[1]
    assert compare_missions(items, got[:2], "px4")[0] == "the vehicle holds 2 items, 3 were uploaded"


def test_ardupilot_home_and_float_frames_are_not_differences():
    items = _items()
    got = [MissionItem(0, 0, 16, 1, 1, 0.0, 0.0, 0.0, 0.0, 375660000, 1269780000, 31.2)]  # the vehicle's home
    got += [MissionItem(1, 3, 22, 0, 1, 0.0, 0.0, 0.0, 0.0, 375663800, 1269781500, 18.0),
            MissionItem(2, 3, 16, 0, 1, 0.0, 0.0, 0.0, 0.0, 375664640, 1269780085, 12.449999809)]
    assert compare_missions(items, got, "ardupilot") == []
    assert compare_missions(items, got, "px4") != []  # on PX4 the same download would be wrong


def test_float32_rounding_and_nan_compare_equal_but_real_changes_do_not():
    items = _items()
    got = list(items)
    got[2] = MissionItem(2, 6, 16, 0, 1, 0.5, 0.3, 0.0, 359.99990844726562, 375664640, 1269780085, 12.449999809)
    assert compare_missions(items, got, "px4") == []
    got[1] = MissionItem(1, 6, 22, 0, 1, 0.0, 0.0, 0.0, 0.0, 375663800, 1269781500, 18.0)  # NaN became 0
    assert "param4" in compare_missions(items, got, "px4")[0]


def test_fly_accepts_a_plan_or_items_and_rejects_anything_else():
    class _Plan:
        def mavlink_items(self, flavour="px4"):
            return _items()[1:] if flavour == "px4" else _items()

    assert len(mission_items_for(_Plan(), "px4")) == 2
    assert len(mission_items_for(_Plan(), "ardupilot")) == 3
    assert mission_items_for(_items(), "px4") == _items()
    with pytest.raises(CompanionError):
        mission_items_for([1, 2, 3], "px4")


def test_sim_arg_parsing():
    assert _sim_options(["gusts=5", "packet-loss=20"]) == {"gusts": "5", "packet_loss": "20"}
    with pytest.raises(CompanionError) as err:
        _sim_options(["gusts"])
    assert "OPT=VALUE" in err.value.problem


class _LossyMissionPlugin:
    """mavsdk MissionRaw stand-in: the vehicle cancels the first ``failures`` uploads (items lost on the link, as the
    simulator and PX4 do after their re-requests run out), then stores what it gets."""

    def __init__(self, failures: int, result: str = "TRANSFER_CANCELLED"):
        self.failures = failures
        self.result = result
        self.uploads = 0
        self.stored = None

    async def upload_mission(self, raw):
        from mavsdk.asyncio.plugins.mission_raw import MissionRawError, MissionRawResult

        self.uploads += 1
        if self.uploads <= self.failures:
            raise MissionRawError(MissionRawResult[self.result], "upload_mission()")
        self.stored = raw

    async def download_mission(self):
        return self.stored


@pytest.mark.parametrize("result", ["TRANSFER_CANCELLED", "TIMEOUT"])
def test_upload_starts_again_after_the_link_lost_the_transfer(result):
    import asyncio

    from companion.flight.upload import upload_and_verify

    plugin = _LossyMissionPlugin(failures=2, result=result)
    asyncio.run(upload_and_verify(plugin, _items(), "px4", attempts=4))
    assert plugin.uploads == 3
    plugin = _LossyMissionPlugin(failures=4, result=result)
    with pytest.raises(CompanionError, match="the link lost too much"):
        asyncio.run(upload_and_verify(plugin, _items(), "px4", attempts=4))


def test_a_refused_upload_quotes_the_text_that_follows_the_ack_and_takes_its_fix_from_it():
    """Real ArduCopter acks NO_SPACE first and says "Only 650 items are supported" after; right after boot it says
    "Only 0 items are supported", which no shorter mission fixes."""
    import asyncio

    from companion.flight.status_texts import StatusTexts
    from companion.flight.upload import upload_and_verify

    class Refusing(_LossyMissionPlugin):
        def __init__(self, text):
            super().__init__(failures=99, result="TOO_MANY_MISSION_ITEMS")
            self.text = text
            self.texts: StatusTexts | None = None

        async def upload_mission(self, raw):
            asyncio.get_running_loop().call_later(0.2, self.texts.add, "WARNING", self.text)  # after the ACK
            return await super().upload_mission(raw)

    for text, problem, fix in (("Only 650 items are supported", "it said: WARNING: Only 650 items are supported",
                                "takes at most 650 items and this mission has 3"),
                               ("Only 0 items are supported\t", "it said: WARNING: Only 0 items are supported",
                                "still starting up")):
        plugin = Refusing(text)
        plugin.texts = StatusTexts(telemetry=None)
        with pytest.raises(CompanionError) as err:
            asyncio.run(upload_and_verify(plugin, _items(), "ardupilot", texts=plugin.texts))
        assert err.value.problem == ("the vehicle rejected the mission upload (TOO_MANY_MISSION_ITEMS, 3 items); "
                                     + problem)
        assert fix in err.value.fix
    plugin = Refusing("")
    plugin.texts = StatusTexts(telemetry=None)
    plugin.upload_mission = lambda raw: _LossyMissionPlugin.upload_mission(plugin, raw)  # a vehicle that says nothing
    with pytest.raises(CompanionError) as err:
        asyncio.run(upload_and_verify(plugin, _items(), "px4", texts=plugin.texts))
    assert err.value.problem.endswith("it gave no reason (no STATUSTEXT)") and "shorten" in err.value.fix

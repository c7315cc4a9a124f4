"""A simulator's accommodations are asked for by name (``--sitl-profile FILE``), never detected: a profile file is
read or refused with the fix, the command passes it to the flight, and the home watch puts home back only when the
profile asks for it (companion/flight/sitl_profile.py)."""

from __future__ import annotations

import pytest

from companion.cli import build_parser
from companion.errors import CompanionError
from companion.flight.fly import home_watch_for
from companion.flight.sitl_profile import SitlProfile, load_sitl_profile
from companion.mission import load_mission, plan_scan
from companion.onboard.commands import scan_flight_from_args
from tests.sitl import ROOT

PX4_SIH = ROOT / "sim/sitl/px4-sih.yaml"
DEMO = ROOT / "missions/demo-facade.yaml"


def test_the_shipped_px4_sih_profile_sets_ekf2_noise_and_puts_home_back():
    profile = load_sitl_profile(PX4_SIH)
    assert profile == SitlProfile({"EKF2_ACC_NOISE": 1.0, "EKF2_GYR_NOISE": 0.1}, True, str(PX4_SIH))
    assert "EKF2_ACC_NOISE 1" in profile.describe() and "home put back" in profile.describe()


@pytest.mark.parametrize("text, problem", [
    ("parameters: {EKF2_ACC_NOISE: high}\n", "is not a number"),
    ("parameters: [EKF2_ACC_NOISE]\n", "is not a mapping of names"),
    ("restore_home: 1\n", "is not true or false"),
    ("restore_hom: true\n", "unknown keys ['restore_hom']"),
    ("- a\n", "is not a mapping"),
])
def test_a_wrong_profile_is_refused_naming_what_is_wrong(tmp_path, text, problem):
    path = tmp_path / "p.yaml"
    path.write_text(text)
    with pytest.raises(CompanionError) as err:
        load_sitl_profile(path)
    assert problem in err.value.problem and "sim/sitl/px4-sih.yaml" in err.value.fix


def test_a_missing_profile_names_the_option(tmp_path):
    with pytest.raises(CompanionError, match="cannot read the SITL profile") as err:
        load_sitl_profile(tmp_path / "none.yaml")
    assert "--sitl-profile" in err.value.fix


def _fly_options(*extra: str) -> dict:
    args = build_parser().parse_args(["fly", str(DEMO), *extra])
    return scan_flight_from_args(args).fly_options


def test_fly_passes_a_profile_only_when_asked():
    assert _fly_options()["sitl_profile"] is None
    assert _fly_options("--sitl", "--sitl-profile", str(PX4_SIH))["sitl_profile"].restore_home
    assert _fly_options("--sitl")["sitl_profile"] is None  # a simulator started for the flight is flown as a vehicle


def test_home_is_put_back_only_when_a_profile_asks_and_the_autopilot_moves_it():
    plan = plan_scan(load_mission(DEMO))
    px4 = plan.mavlink_items("px4")
    assert not home_watch_for(plan, px4, "px4").restore
    assert home_watch_for(plan, px4, "px4", restore_home=True).restore
    assert not home_watch_for(plan, plan.mavlink_items("ardupilot"), "ardupilot", restore_home=True).restore

"""sim/ardupilot_sitl.py, the parts that need no ArduPilot binary (CI has none)."""

from __future__ import annotations

import pymap3d
import pytest

from companion.errors import CompanionError
from sim.ardupilot_sitl import SitlParameters, find_binary


def test_a_gnss_offset_in_metres_becomes_arducopters_glitch_in_degrees():
    """SIM_GPS1_GLTCH is added to the receiver's latitude and longitude in DEGREES (SIM_GPS.cpp): 1.5 m north and
    1 m east at 37.57 deg must land 1.5 m north and 1 m east of the true position."""
    lat, lon = 37.56638, 126.97815
    lines = dict(line.split() for line in SitlParameters(gnss_offset_enu_m=(1.0, 1.5, 0.3)).lines(lat))
    n, e, _ = pymap3d.geodetic2ned(lat + float(lines["SIM_GPS1_GLTCH_X"]), lon + float(lines["SIM_GPS1_GLTCH_Y"]),
                                   0.0, lat, lon, 0.0)
    assert (float(n), float(e)) == pytest.approx((1.5, 1.0), abs=0.01)
    assert float(lines["SIM_GPS1_GLTCH_Z"]) == pytest.approx(0.3)
    assert SitlParameters().lines(lat) == []  # no offset: nothing written, the vehicle's defaults stand
    ranged = SitlParameters(forward_rangefinder=True).lines(lat)
    assert "RNGFND1_TYPE 100" in ranged and "RNGFND1_ORIENT 0" in ranged


def test_a_tree_without_a_sitl_build_is_named_with_the_fix(tmp_path):
    with pytest.raises(CompanionError) as e:
        find_binary(tmp_path)
    assert "no ArduCopter SITL binary" in e.value.problem and "sitl board" in e.value.fix

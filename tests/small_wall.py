"""Test helper: tests/data/small-wall.yaml as the SITL tests with live culling fly it, scan first.

The mission file keeps PX4's 121 s (simulated) hold above the wall for home to settle (``margins.home_settle_s``):
the camera and culling tests that read it as a plan need the real firmware's timing. The SITL tests about frames
and the spool (tests/test_onboard_sitl.py, tests/test_onboard_crash.py) are not about home: they fly it without the
hold on a simulated vehicle that keeps home still, both together as ``sim.rig.fly_at_once_with_still_home`` sets them
for recordings. Two thirds of their flight was that hold.
"""

from __future__ import annotations

from pathlib import Path

import yaml

from sim.rig import STILL_HOME

SMALL_WALL = Path(__file__).parent / "data" / "small-wall.yaml"


def small_wall_scan_at_once(directory: Path) -> tuple[Path, dict]:
    """``(mission file, simulator options)``: tests/data/small-wall.yaml written to ``directory`` with
    ``margins.home_settle_s`` 0, so its scan starts at once (about 55 s simulated from take-off to landing), and the
    options for a simulated vehicle that keeps home still (``SitlRig(sim_options=...)``), without which the mission
    needs its hold. A file, not a plan: the camera process and ``companion fly`` read a path."""
    spec = yaml.safe_load(SMALL_WALL.read_text())
    spec.setdefault("margins", {})["home_settle_s"] = 0.0
    path = Path(directory) / "small-wall-at-once.yaml"
    path.write_text(yaml.safe_dump(spec, sort_keys=False))
    return path, dict(STILL_HOME)

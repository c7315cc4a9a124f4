"""Test helper: tests/data/small-wall.yaml as the SITL tests with live culling fly it, scan first.

The mission file keeps PX4's 121 s (simulated) hold above the wall for home to settle (``margins.home_settle_s``):
the camera and culling tests that read it as a plan need the real firmware's timing. The SITL tests about frames
and the spool (tests/test_onboard_sitl.py, tests/test_onboard_crash.py) fly it on a simulator that keeps home where
it armed, so they drop the hold, as ``companion fly --sitl`` and the demo do (``planner.without_home_settle``): two
thirds of their flight was that hold.
"""

from __future__ import annotations

from pathlib import Path

import yaml

SMALL_WALL = Path(__file__).parent / "data" / "small-wall.yaml"


# What the simulated vehicle is told so that home stays where it armed, which a mission without the hold relies on
# (``SitlRig(sim_options=...)``). Empty: this simulator's PX4 flavour keeps home still unless asked to move it.
STILL_HOME_OPTIONS: dict = {}


def small_wall_scan_at_once(directory: Path) -> tuple[Path, dict]:
    """``(mission file, simulator options)``: tests/data/small-wall.yaml written to ``directory`` with
    ``margins.home_settle_s`` 0, so its scan starts at once (about 55 s simulated from take-off to landing), and the
    options for a simulated vehicle that keeps home still, the condition for flying it without the hold. A file, not
    a plan: the camera process and ``companion fly`` read a path."""
    spec = yaml.safe_load(SMALL_WALL.read_text())
    spec.setdefault("margins", {})["home_settle_s"] = 0.0
    path = Path(directory) / "small-wall-at-once.yaml"
    path.write_text(yaml.safe_dump(spec, sort_keys=False))
    return path, dict(STILL_HOME_OPTIONS)

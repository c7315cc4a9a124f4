"""``python -m sim <part> ...``: dispatches to a simulator part; each part's module is imported only when used."""

from __future__ import annotations

import importlib
import sys

# part name -> module with ``main(argv) -> int``
PARTS = {
    "vehicle": "sim.vehicle.cli",
    "camera": "sim.camera.live",
    "posebridge": "sim.pose_bridge",  # SIM_STATE of a SITL autopilot -> the camera's pose channel
    "external": "sim.external_rig",  # camera + pose bridge for an external autopilot SITL (real ArduPilot)
}


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if not argv or argv[0] not in PARTS:
        print(f"usage: python -m sim {{{','.join(PARTS)}}} [options]  (try: python -m sim vehicle --help)",
              file=sys.stderr)
        return 2
    return int(importlib.import_module(PARTS[argv[0]]).main(argv[1:]) or 0)


if __name__ == "__main__":
    sys.exit(main())

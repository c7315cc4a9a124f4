"""``companion restore``: put back the autopilot parameters an interrupted ``companion fly`` left changed.

Thin: the journal and the restore are ``companion/flight/param_journal.py`` and ``restore.py``; ``companion fly``
runs the same restore before every flight."""

from __future__ import annotations

import argparse
import asyncio
from pathlib import Path

from companion.flight.limits import FlightLimits
from companion.flight.param_journal import STATE_DIR_ENV
from companion.flight.restore import restore_vehicle

STATE_DIR_HELP = (f"where the parameter journal lives (default: ${STATE_DIR_ENV}, else $XDG_STATE_HOME/companion, "
                  "else ~/.local/state/companion)")


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("restore", help="put back the parameters an interrupted `companion fly` left changed on the "
                                       "vehicle (its parameter journal), then exit")
    p.add_argument("--connect", default=FlightLimits.connect_url,
                   help="MAVLink address of the vehicle, as for `companion fly`")
    p.add_argument("--connect-timeout", type=float, default=FlightLimits.connect_timeout_s,
                   help="seconds to wait for a heartbeat")
    p.add_argument("--state-dir", type=Path, help=STATE_DIR_HELP)
    p.set_defaults(func=run_restore)


def run_restore(args: argparse.Namespace) -> int:
    outcome = asyncio.run(restore_vehicle(args.connect, connect_timeout_s=args.connect_timeout,
                                          state=args.state_dir))
    print(outcome.summary())
    return 0

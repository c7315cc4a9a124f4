"""`companion demo`: the main job on the built-in default mission (grows into the full SITL scan)."""

from __future__ import annotations

import argparse
from pathlib import Path

from companion.mission.commands import DEFAULT_MISSION, format_estimates, plan_to_dir


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo", help="run the main job on the built-in demo mission")
    p.add_argument("--mission", type=Path, default=DEFAULT_MISSION, help="mission YAML (default: the demo facade)")
    p.add_argument("--out", type=Path, default=Path("out/demo"), help="output directory (default: out/demo)")
    p.set_defaults(func=run_demo)


def run_demo(args: argparse.Namespace) -> int:
    plan, written = plan_to_dir(args.mission, args.out / "plan")
    print(format_estimates(plan))
    print(f"plan: {len(written)} files in {args.out / 'plan'}")
    return 0

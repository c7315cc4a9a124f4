"""Thin command line: parses arguments and calls library functions; each area registers its own subcommands."""

from __future__ import annotations

import argparse
import importlib
import logging
import sys

from companion.errors import CompanionError

# Each module here defines ``register(subparsers)`` adding its subcommands; a subcommand's parser sets
# ``func`` (called with the parsed args; returns an exit code or None).
COMMAND_MODULES = [
    "companion.flight.commands",
    "companion.mission.commands",
    "companion.demo",
    "companion.onboard.commands",
    "companion.depth.commands",
    "companion.keyframes.commands",
    "companion.stitch.commands",
    "companion.viewer.commands",
    "sim.camera.commands",
]


def shared_group(subparsers, name: str, help: str):
    """Subcommands of a group several areas add to (``companion eval mask``, ``companion eval gate``): the first
    caller creates the group, later callers get the same sub-parser collection."""
    parser = subparsers._name_parser_map.get(name)  # noqa: SLF001 - argparse offers no public lookup
    if parser is None:
        parser = subparsers.add_parser(name, help=help)
    sub = getattr(parser, "_companion_sub", None)
    if sub is None:
        sub = parser.add_subparsers(dest=f"{name}_what", required=True)
        parser._companion_sub = sub
    return sub


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="companion",
        description="UAV facade inspection companion: plan and fly a constant-standoff facade scan, mask the "
        "background with a depth network, keep keyframes with a SIFT overlap gate, stitch the facade map.",
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    sub = parser.add_subparsers(dest="command", required=True)
    for name in COMMAND_MODULES:
        importlib.import_module(name).register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO, format="%(levelname)s %(name)s: %(message)s"
    )
    try:
        code = args.func(args)
    except CompanionError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    return int(code or 0)


if __name__ == "__main__":
    sys.exit(main())

"""Thin command line: parses arguments and calls library functions; each area registers its own subcommands.

The simulator's commands (``sim``, ``record``, ``demo``, ``eval``) are a plugin (``companion.plugins``):
``sim/commands.py`` registers them when the simulator package is installed, so companion never imports sim; without
it they say what is missing.
"""

from __future__ import annotations

import argparse
import logging
import sys

from companion import plugins
from companion.depth import commands as depth_commands
from companion.errors import CompanionError
from companion.export import commands as export_commands
from companion.flight import commands as flight_commands
from companion.mission import commands as mission_commands
from companion.onboard import commands as onboard_commands
from companion.site import commands as site_commands
from companion.stitch import commands as stitch_commands

# Each module here defines ``register(subparsers)`` adding its subcommands; a subcommand's parser sets
# ``func`` (called with the parsed args; returns an exit code or None).
COMMAND_MODULES = (onboard_commands, flight_commands, mission_commands, depth_commands, stitch_commands,
                   site_commands, export_commands)


def _missing_plugin(module: str):
    def run(args: argparse.Namespace) -> int:
        raise CompanionError(
            f"`companion {args.command}` is provided by the {module.split('.')[0]} package ({module}), which is not "
            "installed here",
            "install companion with its simulator (the companion wheel ships sim; in a checkout: pip install -e .)",
        )

    return run


def register_plugin(sub: argparse._SubParsersAction, module: str, commands: tuple[str, ...]) -> bool:
    """Register ``module``'s commands; when its package is not installed, register each command name as one that
    says so (instead of argparse's "invalid choice"). True if the plugin loaded."""
    package = module.split(".")[0]
    plugin = plugins.load_plugin(module)
    if plugin is None:
        for name in commands:
            # takes whatever follows (options included: no prefix character) so the error names what is missing
            p = sub.add_parser(name, help=f"(needs the {package} package, not installed)", add_help=False,
                               prefix_chars="\0")
            p.add_argument("rest", nargs="*")
            p.set_defaults(func=_missing_plugin(module))
        return False
    plugin.register(sub)
    return True


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="companion",
        description="UAV facade inspection companion: plan and fly a constant-standoff facade scan, mask the "
        "background with a depth network, keep keyframes with a SIFT overlap gate, stitch the facade map.",
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    sub = parser.add_subparsers(dest="command", required=True)
    for module in COMMAND_MODULES:
        module.register(sub)
    for name, commands in plugins.PLUGIN_MODULES.items():
        register_plugin(sub, name, commands)
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

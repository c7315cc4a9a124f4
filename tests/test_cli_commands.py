"""The command line: the README's command table lists exactly the parser's commands; the simulator's commands come
from sim as a plugin and say what is missing when sim is not installed; each command is registered once."""

from __future__ import annotations

import argparse
import re
from pathlib import Path

import pytest

from companion import cli, plugins
from companion.errors import CompanionError
from companion.plugins import provided

ROOT = Path(__file__).resolve().parents[1]


def subcommands(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    """A parser's subcommands by name (argparse keeps its sub-parser action among the parser's actions)."""
    actions = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]  # noqa: SLF001 (test only)
    return dict(actions[0].choices) if actions else {}


def readme_commands() -> dict[str, set[str]]:
    """Commands in README.md's command table: ``companion NAME sub1/sub2 ...`` -> {NAME: {sub1, sub2}}."""
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    table = text[text.index("| command | what it does |"):].split("\n\n")[0]
    found: dict[str, set[str]] = {}
    for cell in re.findall(r"^\| `companion ([^`]+)`", table, flags=re.MULTILINE):
        words = cell.split()
        subs = found.setdefault(words[0], set())
        if len(words) > 1 and re.fullmatch(r"[a-z]+(/[a-z]+)+", words[1]):
            subs.update(words[1].split("/"))
    return found


def test_the_readme_command_table_matches_the_parser():
    parser = cli.build_parser()
    commands = subcommands(parser)
    documented = readme_commands()
    assert set(documented) == set(commands), (
        f"in the parser, not the README: {sorted(set(commands) - set(documented))}; "
        f"in the README, not the parser: {sorted(set(documented) - set(commands))}"
    )
    for name, subs in documented.items():
        if subs:
            assert subs == set(subcommands(commands[name])), f"companion {name}: README lists {sorted(subs)}"


def test_the_simulator_commands_register_from_sim_once():
    import sim.commands

    assert plugins.PLUGIN_MODULES["sim.commands"] == sim.commands.COMMANDS
    commands = subcommands(cli.build_parser())
    for name in sim.commands.COMMANDS:
        parsers = [commands[name], *subcommands(commands[name]).values()]
        funcs = [p.get_default("func") for p in parsers if p.get_default("func") is not None]
        assert funcs and all(f.__module__.startswith("sim.") for f in funcs), name
    assert "record" not in subcommands(commands["sim"])  # `companion record`, not also `companion sim record`
    assert set(subcommands(commands["eval"])) == {"mask", "gate"}


def test_without_the_simulator_its_commands_name_what_is_missing(monkeypatch, capsys, tmp_path):
    monkeypatch.setattr(plugins, "PLUGIN_MODULES", {"simulator_not_installed.commands": ("demo", "eval")})
    assert cli.main(["demo", "--out", str(tmp_path / "demo")]) == 2
    err = capsys.readouterr().err
    assert "`companion demo` is provided by the simulator_not_installed package" in err
    assert "not installed" in err and "fix:" in err
    assert not (tmp_path / "demo").exists()
    assert cli.main(["plan", "demo-facade", "--out", str(tmp_path / "plan")]) == 0  # the rest still works


def test_a_broken_plugin_is_not_mistaken_for_a_missing_one(monkeypatch, tmp_path):
    (tmp_path / "brokenplugin").mkdir()
    (tmp_path / "brokenplugin" / "__init__.py").write_text("")
    (tmp_path / "brokenplugin" / "commands.py").write_text("import a_module_that_does_not_exist\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setattr(plugins, "PLUGIN_MODULES", {"brokenplugin.commands": ("demo",)})
    with pytest.raises(ModuleNotFoundError, match="a_module_that_does_not_exist"):
        cli.build_parser()


def test_a_need_nobody_provided_is_a_clear_error():
    with pytest.raises(CompanionError, match="needs the simulator package") as info:
        provided("no_such_need", "doing the impossible")
    assert "pip install" in info.value.fix


def test_a_shipped_mission_is_planned_by_name_and_an_unknown_name_is_refused(tmp_path, capsys):
    assert cli.main(["plan", "demo-facade", "--out", str(tmp_path / "plan")]) == 0
    assert (tmp_path / "plan" / "demo-facade.plan").is_file()
    with pytest.raises(SystemExit) as exit_info:
        cli.main(["plan", "no-such-mission", "--out", str(tmp_path / "other")])
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert "neither a file nor a shipped mission" in err and "demo-facade" in err
    assert not (tmp_path / "other").exists()


def test_fly_refuses_a_capture_it_cannot_run_before_anything_starts(tmp_path, capsys):
    assert cli.main(["fly", "demo-facade", "--capture", "sim"]) == 2
    assert "--capture needs --out DIR" in capsys.readouterr().err
    assert cli.main(["fly", "demo-facade", "--capture", "sim", "--out", str(tmp_path / "spool")]) == 2
    assert "--capture sim needs --sitl" in capsys.readouterr().err
    assert not (tmp_path / "spool").exists()


def test_fly_option_defaults_are_the_flight_librarys_defaults():
    """`companion fly`'s defaults come from companion.flight.limits, the same object fly_mission's keywords read."""
    import inspect

    from companion.flight.fly import fly_mission
    from companion.flight.limits import FLIGHT_DEFAULTS

    fly = subcommands(cli.build_parser())["fly"]
    options = {a.dest: a.default for a in fly._actions}  # noqa: SLF001 (test only)
    pairs = {"connect": "connect_url", "connect_timeout": "connect_timeout_s", "health_timeout": "health_timeout_s",
             "link_loss": "link_loss_s", "link_dead": "link_dead_s", "timeout": "flight_timeout_s",
             "rate": "telemetry_rate_hz", "end_action": "end_action", "stop_wait": "stop_wait_s"}
    keywords = inspect.signature(fly_mission).parameters
    for option, field in pairs.items():
        assert options[option] == getattr(FLIGHT_DEFAULTS, field) == keywords[field].default, option

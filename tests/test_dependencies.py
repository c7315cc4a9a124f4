"""Dependencies go one way: ``sim`` uses ``evaluation`` and ``companion``, ``evaluation`` uses ``companion``, never
the reverse (the product never imports its evaluation nor the simulator), and companion's own parts (subpackages and
top-level modules) import each other without a cycle. Read from the source (every import statement, including
those inside functions), so a hidden import cannot slip through."""

from __future__ import annotations

import ast
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "companion"
EVALUATION = ROOT / "evaluation"


def module_name(path: Path, root: Path = ROOT) -> str:
    parts = list(path.relative_to(root).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imports(path: Path, module: str | None = None) -> list[tuple[str, int]]:
    """(absolute module name, line) of every import in ``path``, relative ones resolved, plus literal names given to
    ``importlib.import_module`` / ``__import__``."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    package = (module or module_name(path)).split(".")
    if path.name != "__init__.py":
        package = package[:-1]
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [(alias.name, node.lineno) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[: len(package) - node.level + 1]
                found.append((".".join(base + ([node.module] if node.module else [])), node.lineno))
            else:
                found.append((node.module, node.lineno))
                found += [(f"{node.module}.{alias.name}", node.lineno) for alias in node.names]
        elif isinstance(node, ast.Call) and node.args and isinstance(node.args[0], ast.Constant):
            name = getattr(node.func, "attr", getattr(node.func, "id", ""))
            if name in ("import_module", "__import__") and isinstance(node.args[0].value, str):
                found.append((node.args[0].value, node.lineno))
    return found


def part_of(module: str) -> str | None:
    """The top-level part of companion a module belongs to (``companion.flight.fly`` -> ``flight``)."""
    parts = module.split(".")
    return parts[1] if parts[0] == "companion" and len(parts) > 1 else None


def part_graph() -> dict[str, dict[str, str]]:
    """part -> {imported part: where (file:line)}; a part's imports of itself are left out."""
    graph: dict[str, dict[str, str]] = defaultdict(dict)
    for path in sorted(PACKAGE.rglob("*.py")):
        source = part_of(module_name(path))
        for target, line in imports(path):
            target_part = part_of(target)
            is_part = target_part and ((PACKAGE / target_part).is_dir() or (PACKAGE / f"{target_part}.py").is_file())
            if source and is_part and target_part != source:
                graph[source].setdefault(target_part, f"{path.relative_to(ROOT)}:{line}")
    return graph


def find_cycle(graph: dict[str, dict[str, str]]) -> list[str] | None:
    state: dict[str, str] = {}
    stack: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = "open"
        stack.append(node)
        for nxt in sorted(graph.get(node, {})):
            if state.get(nxt) == "open":
                return stack[stack.index(nxt):] + [nxt]
            if nxt not in state and (cycle := visit(nxt)):
                return cycle
        stack.pop()
        state[node] = "done"
        return None

    for node in sorted(graph):
        if node not in state and (cycle := visit(node)):
            return cycle
    return None


def imports_of(package: Path, top: str) -> list[str]:
    """'file:line imports module' for every import of the top-level package ``top`` in ``package``'s files."""
    return [
        f"{path.relative_to(package.parent)}:{line} imports {target}"
        for path in sorted(package.rglob("*.py"))
        for target, line in imports(path, module_name(path, package.parent))
        if target == top or target.startswith(f"{top}.")
    ]


def test_companion_never_imports_sim():
    offending = imports_of(PACKAGE, "sim")
    assert not offending, "companion must not import sim (sim registers what it provides):\n" + "\n".join(offending)


def test_companion_never_imports_its_evaluation():
    """The product's behaviour cannot depend on synthetic scenes, evaluators or where the real photos are."""
    offending = imports_of(PACKAGE, "evaluation")
    assert not offending, "companion must not import evaluation:\n" + "\n".join(offending)
    named = [
        (str(path.relative_to(ROOT)), node.value)
        for path in sorted(PACKAGE.rglob("*.py"))
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8")))
        if isinstance(node, ast.Constant) and isinstance(node.value, str)
        and (node.value == "evaluation" or node.value.startswith("evaluation."))
    ]
    assert not named, f"a string naming an evaluation module is an import in disguise: {named}"


def test_evaluation_never_imports_sim():
    """sim's ``eval`` commands import evaluation; evaluation reaches simulator recordings only through the plugin
    hooks (companion.plugins.provided), as the product does."""
    offending = imports_of(EVALUATION, "sim")
    assert not offending, "evaluation must not import sim:\n" + "\n".join(offending)


def test_the_import_walk_finds_an_evaluation_import_in_a_function(tmp_path):
    package = tmp_path / "companion"
    package.mkdir()
    (package / "probe.py").write_text("import os\n\ndef f():\n    from evaluation.stitch import synthetic\n")
    (package / "clean.py").write_text("from companion.stitch import worker\n")
    assert imports_of(package, "evaluation") == ["companion/probe.py:4 imports evaluation.stitch",
                                                 "companion/probe.py:4 imports evaluation.stitch.synthetic"]


def test_companion_reaches_sim_only_through_the_named_plugin_hook():
    """The one place companion names sim is ``companion.plugins.PLUGIN_MODULES`` (an optional plugin, imported by
    name when installed); any other string naming a sim module would be an import in disguise."""
    named = []
    for path in sorted(PACKAGE.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Constant) and isinstance(node.value, str) and node.value.startswith("sim."):
                named.append((str(path.relative_to(ROOT)), node.value))
    assert named == [("companion/plugins.py", "sim.commands")], named


def test_no_import_cycle_between_the_parts_of_companion():
    graph = part_graph()
    assert graph["onboard"].keys() >= {"flight", "capture", "depth", "keyframes", "spool"}  # the walk sees imports
    cycle = find_cycle(graph)
    if cycle:
        hops = [f"{a} -> {b} ({graph[a][b]})" for a, b in zip(cycle, cycle[1:], strict=False)]
        raise AssertionError("import cycle between parts of companion:\n" + "\n".join(hops))


def test_the_cycle_finder_finds_a_cycle_and_the_walk_sees_imports_inside_functions(tmp_path):
    assert find_cycle({"a": {"b": ""}, "b": {"c": ""}, "c": {"a": ""}}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b": ""}, "b": {"c": ""}}) is None
    probe = tmp_path / "probe.py"
    probe.write_text("def f():\n    from sim.rig import SitlRig\n    import importlib\n"
                     "    importlib.import_module('sim.demo')\n")
    names = [name for name, _ in imports(probe, module="companion.probe")]
    assert "sim.rig" in names and "sim.demo" in names


def test_only_the_command_line_uses_site_and_only_its_engine_imports_dask():
    """``companion.site`` sits on top of the stitcher: no part of companion imports it but the command line (the
    stitcher must stay usable on the companion computer without it), and Dask is imported in one module only,
    ``site/engine.py`` (single-process mode and every other command run without Dask installed)."""
    graph = part_graph()
    users = {part for part, targets in graph.items() if "site" in targets}
    assert users == {"cli"}, users
    dask = [
        f"{path.relative_to(ROOT)}:{line}"
        for path in sorted(PACKAGE.rglob("*.py"))
        for target, line in imports(path)
        if target.split(".")[0] in ("dask", "distributed") and path != PACKAGE / "site" / "engine.py"
    ]
    assert not dask, dask
    assert set(graph["site"]) <= {"stitch", "spool", "keyframes", "files", "errors", "progress", "geo"}

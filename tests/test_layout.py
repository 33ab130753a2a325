"""The dependency rule of the README's layout section, checked on every import of every module.

cosim's rooms, from the bottom: the base (``cosim.errors``, ``cosim``), ``bus``, then ``log`` and
``plant`` (beside each other), ``scenario``, then ``run`` and ``analysis`` (beside each other),
the Python API (``cosim.api``), ``campaign``, and on top the command line (``cosim.cli``) and the
users' facade ``cosim.client``.
A room imports only rooms below it. The algorithms (``estimators``) and fault models (``faults``)
import of cosim only the registry of kinds (``cosim.kinds``, which imports nothing); a plant module
(``mjcf``) that and the bus signal type.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

from tests import sizes

ROOT = Path(__file__).resolve().parent.parent
BELOW = {
    "base": set(),
    "bus": {"base"},
    "log": {"base", "bus"},
    "plant": {"base", "bus"},
    "scenario": {"base", "bus", "plant"},
    "run": {"base", "bus", "log", "plant", "scenario"},
    "analysis": {"base", "bus", "log", "plant", "scenario"},
    "api": {"base", "bus", "log", "plant", "scenario", "run", "analysis"},
    "campaign": {"base", "bus", "log", "plant", "scenario", "run", "analysis", "api"},
    "baselines": {"base", "api"},  # plugins, as a user's: the plugin contract alone
    "top": {"base", "bus", "log", "plant", "scenario", "run", "analysis", "api", "campaign"},
}
OUTSIDE = {"estimators": ("cosim.kinds",), "faults": ("cosim.kinds",), "mjcf": ("cosim.kinds", "cosim.bus.signals")}


def room(module: str) -> str | None:
    """The room of a cosim module (None: not cosim's)."""
    parts = module.split(".")
    if parts[0] != "cosim":
        return None
    if len(parts) == 1 or parts[1] in ("errors", "__init__"):
        return "base"
    if parts[1] in ("cli", "client"):
        return "top"
    return parts[1] if parts[1] in BELOW else "base"  # cosim.api is the room "api"


def imports(path: Path, package: str) -> list[tuple[int, str]]:
    """Every module a file imports (at any level, lazy imports included), absolute."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                base = ".".join(
                    package.split(".")[: len(package.split(".")) - node.level + 1] + ([base] if base else [])
                )
            found += [(node.lineno, f"{base}.{alias.name}") for alias in node.names]
    return found


def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def cosim_modules() -> list[Path]:
    return sorted((ROOT / "cosim").rglob("*.py"))


@pytest.mark.parametrize("path", cosim_modules(), ids=lambda p: str(p.relative_to(ROOT)))
def test_a_room_imports_only_rooms_below_it(path):
    name = module_name(path)
    mine = room(name)
    bad = [
        f"line {line}: {target}"
        for line, target in imports(path, name)
        if (theirs := room(target)) is not None and theirs != mine and theirs not in BELOW[mine]
    ]
    assert not bad, f"{name} ({mine}) imports against the layout's rule: {'; '.join(bad)}"


@pytest.mark.parametrize("package", sorted(OUTSIDE))
def test_algorithms_faults_and_plant_modules_stay_out_of_cosim(package):
    for path in sorted((ROOT / package).rglob("*.py")):
        for line, target in imports(path, module_name(path)):
            if target.split(".")[0] in ("cosim", "scenarios") or (package != "mjcf" and target.split(".")[0] == "mjcf"):
                assert any(target.startswith(allowed) for allowed in OUTSIDE[package]), (
                    f"{path}:{line} imports {target}"
                )


def test_every_module_opens_with_a_sentence_saying_what_it_holds():
    for path in [
        *cosim_modules(),
        *sorted(ROOT.glob("estimators/*.py")),
        *sorted(ROOT.glob("faults/*.py")),
        *sorted(ROOT.glob("mjcf/*.py")),
    ]:
        doc = ast.get_docstring(ast.parse(path.read_text()))
        assert doc and doc.split("\n\n")[0].rstrip().endswith((".", ":", ")")), f"{path} has no opening sentence"


def test_the_rule_catches_an_import_against_it(tmp_path):
    """The check itself: an analysis module importing the runner is refused."""
    bad = tmp_path / "bad.py"
    bad.write_text("from cosim.run.runner import Run\nimport cosim.run.session\n")
    found = [room(target) for _, target in imports(bad, "cosim.analysis.bad")]
    assert found == ["run", "run"] and not {"run"} <= BELOW["analysis"]


def test_rooms_a_newcomer_reads_in_one_sitting():
    """No file over 600 lines in the product or its tests; no function over 60 lines in it but those
    ``sizes.LONG_FUNCTIONS_KEPT`` lists with their reasons, each of which is still that long
    (``python -m tests.sizes`` lists them)."""
    files = sizes.long_files()
    assert not files, [f"{s.where} ({s.lines} lines)" for s in files]
    functions = {s.where: s for s in sizes.long_functions()}
    assert not [s for where, s in functions.items() if where not in sizes.LONG_FUNCTIONS_KEPT], [
        f"{s.where}, line {s.line} ({s.lines} lines)"
        for where, s in functions.items()
        if where not in sizes.LONG_FUNCTIONS_KEPT
    ]
    assert not [where for where in sizes.LONG_FUNCTIONS_KEPT if where not in functions], "kept, yet no longer long"


def import_graph() -> dict[str, dict[str, int]]:
    """Every module of the project (the product, its scenarios and tests) → the project's modules it
    imports (at any level: lazy imports and those for type checking only included) → the line."""
    paths = {
        module_name(p): p for package in (*sizes.PRODUCT, "scenarios", "tests") for p in (ROOT / package).rglob("*.py")
    }
    graph: dict[str, dict[str, int]] = {}
    for name, path in paths.items():
        edges = graph.setdefault(name, {})
        for line, target in imports(path, name):
            while target not in paths and "." in target:  # a name imported from a module: the module
                target = target.rsplit(".", 1)[0]
            if target in paths and target != name:
                edges.setdefault(target, line)
    return graph


def import_cycles(graph: dict[str, dict[str, int]]) -> list[list[str]]:
    """The circles of ``graph``: its strongly connected components of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    cycles: list[list[str]] = []

    def visit(module: str) -> None:
        index[module] = low[module] = len(index)
        stack.append(module)
        for target in graph.get(module, {}):
            if target not in index:
                visit(target)
                low[module] = min(low[module], low[target])
            elif target in stack:
                low[module] = min(low[module], index[target])
        if low[module] == index[module]:
            component = []
            while not component or component[-1] != module:
                component.append(stack.pop())
            if len(component) > 1:
                cycles.append(sorted(component))

    for module in sorted(graph):
        if module not in index:
            visit(module)
    return cycles


def test_no_module_imports_itself_round_a_circle():
    """A shared name lives in the room both modules need, below them: no import circle, however
    indirect, lazy or for type checking only."""
    graph = import_graph()
    found = [
        " -> ".join(f"{m} (line {graph[m][n]})" for m, n in zip(cycle, [*cycle[1:], cycle[0]]) if n in graph[m])
        or str(cycle)
        for cycle in import_cycles(graph)
    ]
    assert not found, found


def test_the_circle_check_finds_a_circle_through_a_lazy_import(tmp_path):
    graph = {"a": {"b": 3}, "b": {"c": 5}, "c": {"a": 12}, "d": {"a": 1}}
    assert import_cycles(graph) == [["a", "b", "c"]]
    assert import_cycles({"a": {"b": 1}, "b": {}}) == []
    lazy = tmp_path / "lazy.py"
    lazy.write_text("def f():\n    from estimators.cofd import COFDDiagnosis\n")
    assert imports(lazy, "estimators.lazy") == [(2, "estimators.cofd.COFDDiagnosis")]


def test_the_codec_and_the_authentication_build_on_the_database_not_on_each_other():
    """``cosim.bus.dbc`` is the CAN database both use; neither imports the other (not even for types)."""
    for module, other in (("codec", "secoc"), ("secoc", "codec")):
        path = ROOT / "cosim" / "bus" / f"{module}.py"
        found = [target for _, target in imports(path, f"cosim.bus.{module}")]
        assert not [t for t in found if t.startswith(f"cosim.bus.{other}")], f"{module} imports {other}"
        assert any(t.startswith("cosim.bus.dbc") for t in found)


def test_the_docs_describe_the_project_not_its_tracker():
    """The README, the docs and the command line's help name no tracker issue ("issue 19", "#19")."""
    texts = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md")), *sorted((ROOT / "cosim" / "cli").glob("*.py"))]
    tracker = re.compile(r"\bissues? #?\d+|\(#\d+\)|\bunder another issue\b", re.IGNORECASE)
    found = [f"{p.relative_to(ROOT)}: {m.group(0)}" for p in texts for m in tracker.finditer(p.read_text())]
    assert not found, found


def test_the_architecture_page_names_every_room():
    page = (ROOT / "docs" / "architecture.md").read_text()
    rooms = [f"cosim.{p.name}" for p in sorted((ROOT / "cosim").iterdir()) if (p / "__init__.py").exists()]
    assert rooms and not [room for room in rooms if f"`{room}" not in page]

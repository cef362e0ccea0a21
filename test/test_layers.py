"""The package's layers read top to bottom: bench > tools > ros > io > core, no import runs back up,
no module imports itself round a circle (function-level imports included), and the outer layers
reach the core through its public face (regor_ros.core) only. What a user runs (tools/) never
needs the benchmark harness (bench/). Inside the gate the judge is the top:
the modules that measure ask it through the rules they are handed, never import it. And measured
figures live in results/, not in the code's docstrings, comments or parameter descriptions."""
import ast
import dataclasses
import io
import re
import tokenize
from pathlib import Path

import pytest
from conftest import REPO

PACKAGE = REPO / "regor_ros"
LAYERS = ["core", "io", "ros", "tools", "bench"]   # each may import the ones before it
CORE_INTERNALS_ALLOWED = {"regor_ros.io.map_cache"}   # it serialises the prepared map's internals
MAX_MODULE_LINES = 800


def _module(path: Path) -> str:
    parts = path.relative_to(REPO).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _type_checking_only(tree: ast.AST) -> set[int]:
    """The ids of the import nodes under ``if TYPE_CHECKING:`` (for annotations; never run)."""
    return {id(node) for block in ast.walk(tree)
            if isinstance(block, ast.If) and isinstance(block.test, ast.Name) and block.test.id == "TYPE_CHECKING"
            for statement in block.body for node in ast.walk(statement)}


def _imports(path: Path, at_run_time: bool = False):
    """Every module ``path`` imports (absolute names), wherever in the file the import is
    (``at_run_time``: not those for annotations only)."""
    module = _module(path)
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    tree = ast.parse(path.read_text())
    skipped = _type_checking_only(tree) if at_run_time else set()
    for node in ast.walk(tree):
        if id(node) in skipped:
            continue
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[:len(package.split(".")) - node.level + 1]
                name = ".".join(base + ([node.module] if node.module else []))
            else:
                name = node.module or ""
            if name.startswith("regor_ros"):
                yield name
                for alias in node.names:   # "from . import x" names a module (or a package)
                    named = PACKAGE.parent / (name + "." + alias.name).replace(".", "/")
                    if named.with_suffix(".py").exists() or (named / "__init__.py").exists():
                        yield f"{name}.{alias.name}"
        elif isinstance(node, ast.Import):
            yield from (a.name for a in node.names if a.name.startswith("regor_ros"))


def _graph():
    return {_module(p): set(_imports(p)) for p in PACKAGE.rglob("*.py")}


def _layer(module: str) -> int:
    parts = module.split(".")
    return LAYERS.index(parts[1]) if len(parts) > 1 and parts[1] in LAYERS else -1


def test_no_import_runs_back_up_a_layer():
    upward = [(m, i) for m, imports in _graph().items() for i in imports
              if _layer(m) >= 0 and _layer(i) > _layer(m)]
    assert not upward, f"imports that run back up (bench > tools > ros > io > core): {upward}"


def test_the_outer_layers_reach_the_core_through_its_face():
    inside = [(m, i) for m, imports in _graph().items() for i in imports
              if _layer(m) > 0 and i.startswith("regor_ros.core.") and m not in CORE_INTERNALS_ALLOWED]
    assert not inside, f"imports of core modules behind regor_ros.core: {inside}"


def test_no_module_imports_itself_round_a_circle():
    graph = _graph()
    packages = {m for m in graph if (PACKAGE.parent / m.replace(".", "/") / "__init__.py").exists()}
    edges = {m: {i for i in imports if i in graph and i not in packages and i != m}
             for m, imports in graph.items() if m not in packages}
    state, cycles = {}, []

    def visit(m, path):
        state[m] = "open"
        for n in edges.get(m, ()):
            if state.get(n) == "open":
                cycles.append(path[path.index(n):] + [n])
            elif n not in state:
                visit(n, path + [n])
        state[m] = "done"

    for m in edges:
        if m not in state:
            visit(m, [m])
    assert not cycles, f"import circles: {cycles}"


MEASURING = ["core/gate/visibility.py", "core/gate/rivals.py", "core/gate/measure.py", "core/gate/evidence.py",
             "core/gate/surface_evidence.py", "core/gate/slide.py", "core/gate/changed_world.py", "core/shake.py",
             "core/features.py"]


@pytest.mark.parametrize("name", MEASURING)
def test_the_modules_that_measure_import_no_judge(name):
    imported = set(_imports(PACKAGE / name, at_run_time=True))
    assert "regor_ros.core.gate.judge" not in imported, f"{name} imports the judge: hand it judge.Rules instead"


# a measured timing (0.21 s, 8.8 ms), a measured share (99.8 %) or a before -> after
MEASURED = re.compile(r"\b\d+\.\d+ ?(ms|s)\b(?!/)|\b\d+\.\d+ ?%|\d ?-> ?\d")


def _prose(path: Path):
    """(line, text) of every comment and docstring in ``path``."""
    source = path.read_text()
    for token in tokenize.generate_tokens(io.StringIO(source).readline):
        if token.type == tokenize.COMMENT:
            yield token.start[0], token.string
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            docstring = ast.get_docstring(node, clean=False)
            if docstring:
                yield node.body[0].lineno, docstring


def test_measured_figures_live_in_results_not_in_the_code():
    from regor_ros.core import RegorConfig
    from regor_ros.ros.parameters import NodeSettings
    found = [f"{path.relative_to(REPO)}:{line}: {match.group(0)}" for path in sorted(PACKAGE.rglob("*.py"))
             for line, text in _prose(path) for match in MEASURED.finditer(text)]
    descriptions = [(name, f.metadata["description"]) for name, _, f in RegorConfig().parameters()]
    descriptions += [(f.name, f.metadata["description"]) for f in dataclasses.fields(NodeSettings)]
    found += [f"parameter {name}: {match.group(0)}" for name, text in descriptions
              for match in MEASURED.finditer(text)]
    assert not found, "figures belong in results/ and doc/benchmarks.md: " + "; ".join(found)


def _console_scripts() -> set[str]:
    """The modules whose ``main`` setup.py installs as a command."""
    return set(re.findall(r'"[\w-]+ = ([\w.]+):main"', (REPO / "setup.py").read_text()))


def test_the_lab_reaches_the_package_through_its_public_names():
    """lab/ scripts load data and run benchmarks through regor_ros.core's face and the bench/
    harness; of a command's module they take its ``main`` only (run it as a user would)."""
    commands = _console_scripts()
    behind = []
    for path in sorted((REPO / "lab").glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("regor_ros"):
                names = {alias.name for alias in node.names}
                if node.module in commands:
                    fine = names == {"main"}
                else:
                    fine = node.module == "regor_ros.core" or node.module.startswith("regor_ros.bench.")
                if not fine:
                    behind.append(f"{path.name}: from {node.module} import {', '.join(sorted(names))}")
            elif isinstance(node, ast.Import) and any(a.name.startswith("regor_ros.") for a in node.names):
                behind.append(f"{path.name}: import {', '.join(a.name for a in node.names)}")
    assert not behind, f"lab scripts reaching behind the public face or into a command: {behind}"


def test_no_class_of_the_node_does_more_than_fifteen_things():
    crowded = [f"{path.name}:{node.name} ({methods})" for path in sorted((PACKAGE / "ros").glob("*.py"))
               for node in ast.walk(ast.parse(path.read_text())) if isinstance(node, ast.ClassDef)
               for methods in [sum(isinstance(n, ast.FunctionDef) for n in node.body)] if methods > 15]
    assert not crowded, f"split these into parts with one job each: {crowded}"


def test_no_module_is_longer_than_a_reader_holds():
    """One concept a module: a module past MAX_MODULE_LINES has grown two (kernels are split by
    what they compute, the gate by what it measures)."""
    long = [f"{path.relative_to(REPO)} ({n})" for path in sorted(PACKAGE.rglob("*.py"))
            for n in [len(path.read_text().splitlines())] if n > MAX_MODULE_LINES]
    assert not long, f"split these by concept: {long}"

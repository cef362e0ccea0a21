"""The package's layers read top to bottom: tools > ros > io > core, no import runs back up, no
module imports itself round a circle (function-level imports included), and ros/, io/ and tools/
reach the core through its public face (regor_ros.core) only."""
import ast
from pathlib import Path

from conftest import REPO

PACKAGE = REPO / "regor_ros"
LAYERS = ["core", "io", "ros", "tools"]   # each may import the ones before it
CORE_INTERNALS_ALLOWED = {"regor_ros.io.map_cache"}   # it serialises the prepared map's internals


def _module(path: Path) -> str:
    parts = path.relative_to(REPO).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imports(path: Path):
    """Every module ``path`` imports (absolute names), wherever in the file the import is."""
    module = _module(path)
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[:len(package.split(".")) - node.level + 1]
                name = ".".join(base + ([node.module] if node.module else []))
            else:
                name = node.module or ""
            if name.startswith("regor_ros"):
                yield name
                for alias in node.names:   # "from . import x" names a module
                    if (PACKAGE.parent / (name + "." + alias.name).replace(".", "/")).with_suffix(".py").exists():
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
    assert not upward, f"imports that run back up (tools > ros > io > core): {upward}"


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

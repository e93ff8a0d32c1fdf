"""No module of ``maniskill_pnp`` takes part in an import cycle (imports inside functions included).

The graph is read from the sources with :mod:`ast` (nothing is imported): an edge ``a -> b`` for every
``import maniskill_pnp.b`` / ``from maniskill_pnp.b import x`` in ``a``, at module level or inside a function or class
(only the body of an ``if TYPE_CHECKING:`` is skipped: it never runs). ``from maniskill_pnp.b import x`` points at the
module ``maniskill_pnp.b.x`` when that is a module, else at ``maniskill_pnp.b``; relative imports are resolved the same
way. Importing ``maniskill_pnp.b.c`` also runs the package ``maniskill_pnp.b``'s ``__init__``, so that is an edge too,
except to the importer's own packages: a submodule's implicit import of its own package (whose ``__init__`` may
import its submodules, as ``maniskill_pnp.tasks`` does) is how Python packages work, not a cycle. An explicit
``from maniskill_pnp.tasks import X`` in a submodule of ``maniskill_pnp.tasks`` is counted.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = "maniskill_pnp"
ROOT = Path(__file__).resolve().parents[1]


def package_modules(root: Path = ROOT, package: str = PACKAGE) -> dict[str, Path]:
    """Dotted module name -> source file of every module of ``package`` (a package is its ``__init__.py``)."""
    modules = {}
    for path in sorted((root / package).rglob("*.py")):
        parts = path.relative_to(root).with_suffix("").parts
        modules[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return modules


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def _import_nodes(node: ast.AST):
    """Every ``import`` / ``from ... import`` under ``node``, except in the body of an ``if TYPE_CHECKING:``."""
    for child in ast.iter_child_nodes(node):
        if isinstance(child, (ast.Import, ast.ImportFrom)):
            yield child
        elif isinstance(child, ast.If) and _is_type_checking(child.test):
            for other in child.orelse:
                yield from _import_nodes(ast.Module(body=[other], type_ignores=[]))
        else:
            yield from _import_nodes(child)


def imported_modules(name: str, path: Path, modules: dict[str, Path]) -> dict[str, int]:
    """The modules of the package that module ``name`` (file ``path``) imports: module name -> first line."""
    package = PACKAGE
    own_package = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
    found: dict[str, int] = {}

    def add(target: str, line: int) -> None:
        if target != name:
            found.setdefault(target, line)
        parts = target.split(".")
        for k in range(1, len(parts)):  # the packages whose __init__ importing the target runs, but the importer's own
            module = ".".join(parts[:k])
            if module in modules and module != name and not name.startswith(module + "."):
                found.setdefault(module, line)

    for node in _import_nodes(ast.parse(path.read_text(encoding="utf-8"), str(path))):
        if isinstance(node, ast.Import):
            for alias in node.names:
                target = alias.name
                while target not in modules and "." in target:
                    target = target.rsplit(".", 1)[0]
                if target.split(".")[0] == package:
                    add(target, node.lineno)
            continue
        if node.level:
            base = own_package[: len(own_package) - node.level + 1] + ([node.module] if node.module else [])
            base = ".".join(base)
        else:
            base = node.module or ""
        if base.split(".")[0] != package:
            continue
        for alias in node.names:
            submodule = f"{base}.{alias.name}"
            add(submodule if submodule in modules else base, node.lineno)
    return found


def import_graph(root: Path = ROOT) -> dict[str, dict[str, int]]:
    """Module -> {imported module: line} over the whole package."""
    modules = package_modules(root)
    return {name: imported_modules(name, path, modules) for name, path in modules.items()}


def import_cycles(graph: dict[str, dict[str, int]]) -> list[list[str]]:
    """The strongly connected components of more than one module (each sorted), i.e. the import cycles."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    cycles = []
    for start in graph:  # Tarjan's algorithm, iterative
        if start in index:
            continue
        work = [(start, iter(graph[start]))]
        index[start] = low[start] = len(index)
        stack.append(start)
        on_stack.add(start)
        while work:
            node, successors = work[-1]
            for succ in successors:
                if succ not in index:
                    index[succ] = low[succ] = len(index)
                    stack.append(succ)
                    on_stack.add(succ)
                    work.append((succ, iter(graph[succ])))
                    break
                if succ in on_stack:
                    low[node] = min(low[node], index[succ])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[node])
                if low[node] == index[node]:
                    component = []
                    while True:
                        member = stack.pop()
                        on_stack.discard(member)
                        component.append(member)
                        if member == node:
                            break
                    if len(component) > 1:
                        cycles.append(sorted(component))
    return sorted(cycles)


def _describe(cycle: list[str], graph: dict[str, dict[str, int]]) -> str:
    edges = [f"  {a} -> {b} (line {graph[a][b]})" for a in cycle for b in graph[a] if b in cycle]
    return " <-> ".join(cycle) + "\n" + "\n".join(edges)


def test_graph_sees_imports_inside_functions():
    graph = import_graph()
    # fcn.py imports the equivariant network inside make_pixel_q_network (e2cnn is slow to import).
    assert "maniskill_pnp.agents.pixel.equivariant" in graph["maniskill_pnp.agents.pixel.fcn"]
    assert "maniskill_pnp.scenes.meshes" in graph["maniskill_pnp.scenes.objects"]
    assert import_cycles({"a": {"b": 1}, "b": {"c": 1}, "c": {"a": 1}, "d": {"a": 1}}) == [["a", "b", "c"]]


@pytest.mark.parametrize("low, high", [
    ("maniskill_pnp.agents.pixel.equivariant", "maniskill_pnp.agents.pixel.fcn"),
    ("maniskill_pnp.scenes.meshes", "maniskill_pnp.scenes.objects"),
])
def test_one_way(low, high):
    """``high`` may import ``low``; ``low`` never imports ``high`` (what they share lives in a module below both)."""
    assert high not in import_graph()[low]


#: The package's layers, lowest first: a module imports from its own layer and the layers below it, never above.
LAYERS = ("planning", "cell", "scenes", "tasks", "agents", "bench", "cli")


def layer(module: str) -> int | None:
    """The rank of ``module``'s layer in :data:`LAYERS`, or None for the modules outside them (the package root,
    shared helpers such as ``cache`` and ``runtime``, the env adapters, the demo and the quickstart)."""
    parts = module.split(".")
    return LAYERS.index(parts[1]) if len(parts) > 1 and parts[1] in LAYERS else None


def test_layers_import_only_downwards():
    """planning <- cell (workspace, bin, heightmaps) <- scenes (objects, clutter, scene files) <- tasks (the envs) <-
    agents (learned and scripted) <- bench <- cli: nothing imports a layer above its own."""
    graph = import_graph()
    assert {module.split(".")[1] for module in graph if layer(module) is not None} == set(LAYERS)
    upward = [f"{a} -> {b} (line {line})" for a, targets in graph.items() for b, line in targets.items()
              if layer(a) is not None and layer(b) is not None and layer(b) > layer(a)]
    assert not upward, "imports from a higher layer:\n" + "\n".join(upward)
    assert layer("maniskill_pnp.agents.scripted.slide_oracle") > layer("maniskill_pnp.scenes.grasp_feasibility")


def test_no_import_cycles():
    graph = import_graph()
    cycles = import_cycles(graph)
    assert not cycles, "import cycles in maniskill_pnp:\n" + "\n".join(_describe(c, graph) for c in cycles)

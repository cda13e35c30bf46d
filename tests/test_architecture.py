"""The package's imports run one way: down the layer table, with no cycle between packages.

Every module of ``frictiongym/`` is parsed with :mod:`ast`; its imports of the package's own
modules, at module level and inside functions alike (relative ones resolved), become edges
between the package's parts (a subpackage such as ``frictiongym.envs``, or a top module such
as ``frictiongym.cli``). A string holding a module's dotted name (``"frictiongym.envs.rotary"``)
counts as an import too: the tables that import modules by name (``cli.TOOLS``, the env ids,
the lazy names) are seen, and a name imported from the root ``frictiongym`` is resolved through
the root's lazy-name table (``from frictiongym import register_envs`` imports
``frictiongym.envs``). Imports under ``if TYPE_CHECKING:`` are left out: they never run, and
annotations may name a higher layer's types. The package root ``frictiongym/__init__.py``
(which registers the Gymnasium ids) is no layer and is left out too.
"""

from __future__ import annotations

import ast
import re
from collections.abc import Iterator
from itertools import pairwise
from pathlib import Path

import frictiongym

PACKAGE = Path(frictiongym.__file__).parent
MODULE_NAME = re.compile(r"frictiongym(\.[a-z_]+)+")
#: The root's names imported on first use (``frictiongym.load_params``) -> their module.
ROOT_LAZY: dict[str, str] = frictiongym._LAZY

#: Layer of each part, lowest first. A part may import its own layer's parts or lower ones.
LAYERS: dict[str, int] = {
    "frictiongym._validation": 0,
    "frictiongym._ufunc": 0,
    "frictiongym._io": 0,
    "frictiongym._cluster": 0,
    "frictiongym.metrics": 0,
    "frictiongym.friction": 0,
    "frictiongym.data": 0,
    "frictiongym.plants": 1,
    "frictiongym.params": 1,
    "frictiongym.device_tables": 1,
    "frictiongym.device_file": 1,
    "frictiongym.devices": 1,
    "frictiongym.envs": 2,
    "frictiongym.hardware": 2,
    "frictiongym.controllers": 3,
    "frictiongym.benchmark": 4,
    "frictiongym.identification": 4,
    "frictiongym.tuning": 4,
    "frictiongym.residual": 4,
    "frictiongym.sim2real": 4,
    "frictiongym.sweep": 4,
    "frictiongym.loops": 4,
    "frictiongym.sb3": 3,
    "frictiongym.zoo": 4,
    "frictiongym.device_command": 4,
    "frictiongym.cli": 5,
}

#: Imports within one layer that still point up: the envs drive the hardware's backends.
SAME_LAYER_FORBIDDEN = {("frictiongym.hardware", "frictiongym.envs")}


def module_name(path: Path) -> str:
    parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def part_of(module: str) -> str | None:
    """Return the part (subpackage or top module) ``module`` belongs to; None for the root."""
    parts = module.split(".")
    return ".".join(parts[:2]) if len(parts) > 1 else None


def is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"
    )


def imports_of(path: Path) -> Iterator[tuple[str, int]]:
    """Yield (imported module, line) of each import of ``frictiongym`` in the file at ``path``."""
    module = module_name(path)
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    yield from imports_in(path.read_text(encoding="utf-8"), package)


def imports_in(source: str, package: str) -> Iterator[tuple[str, int]]:
    """Yield (imported module, line) of each import of ``frictiongym`` in a module's ``source``.

    ``package`` is the package relative imports start from.
    """
    tree = ast.parse(source)
    skipped: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and is_type_checking(node.test):
            skipped.update(id(child) for stmt in node.body for child in ast.walk(stmt))
    for node in ast.walk(tree):
        if id(node) in skipped:
            continue
        if isinstance(node, ast.Constant) and isinstance(node.value, str):
            names = [node.value] if MODULE_NAME.fullmatch(node.value) else []
        elif isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")
                anchor = anchor[: len(anchor) - node.level + 1]
                base = ".".join([*anchor, base] if base else anchor)
            names = [base]
            if base == "frictiongym":  # ``from frictiongym import envs`` imports frictiongym.envs
                names = [ROOT_LAZY.get(a.name, f"{base}.{a.name}") for a in node.names]
        else:
            continue
        for name in names:
            if name == "frictiongym" or name.startswith("frictiongym."):
                yield name, node.lineno


def import_edges() -> dict[tuple[str, str], list[str]]:
    """Return (importing part, imported part) -> the ``module:line`` places of those imports."""
    modules = sorted(PACKAGE.rglob("*.py"))
    parts = {part_of(module_name(path)) for path in modules} - {None}
    edges: dict[tuple[str, str], list[str]] = {}
    for path in modules:
        source = part_of(module_name(path))
        if source is None:
            continue
        for imported, line in imports_of(path):
            target = part_of(imported)
            if target == source or target not in parts:
                continue  # within the part, or the root (``from frictiongym import __version__``)
            where = f"{path.relative_to(PACKAGE.parent)}:{line}"
            edges.setdefault((source, target), []).append(where)
    return edges


def find_cycle(edges: set[tuple[str, str]]) -> list[str] | None:
    """Return one cycle of the graph (its parts, the first repeated at the end), or None."""
    graph: dict[str, list[str]] = {}
    for source, target in sorted(edges):
        graph.setdefault(source, []).append(target)
    state: dict[str, int] = {}  # 1: on the current path, 2: done
    path: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        path.append(node)
        for following in graph.get(node, []):
            if state.get(following) == 1:
                return [*path[path.index(following) :], following]
            if following not in state and (cycle := visit(following)):
                return cycle
        state[node] = 2
        path.pop()
        return None

    for node in sorted(graph):
        if node not in state and (cycle := visit(node)):
            return cycle
    return None


def upward(edges: dict[tuple[str, str], list[str]]) -> list[str]:
    """Return the places of imports that point up the layer table."""
    places = []
    for (source, target), where in sorted(edges.items()):
        if LAYERS[target] > LAYERS[source] or (source, target) in SAME_LAYER_FORBIDDEN:
            places += [
                f"{place}: {source} (layer {LAYERS[source]}) imports {target} "
                f"(layer {LAYERS[target]})"
                for place in where
            ]
    return places


def test_every_part_has_a_layer():
    parts = {part_of(module_name(path)) for path in PACKAGE.rglob("*.py")} - {None}
    assert parts <= LAYERS.keys(), f"give these a layer in LAYERS: {parts - LAYERS.keys()}"


def cycle_message(cycle: list[str], edges: dict[tuple[str, str], list[str]]) -> str:
    """Say the cycle and where each of its imports is (``file:line``)."""
    steps = [
        f"{source} -> {target} ({', '.join(edges[source, target])})"
        for source, target in pairwise(cycle)
    ]
    return "import cycle: " + "; ".join(steps)


def test_no_cycle_between_parts():
    edges = import_edges()
    cycle = find_cycle(set(edges))
    assert cycle is None, cycle_message(cycle, edges)


def test_no_import_points_up_the_layers():
    places = upward(import_edges())
    assert not places, "imports up the layer table:\n" + "\n".join(places)


def test_the_checks_find_a_cycle_and_an_upward_import():
    assert find_cycle({("a", "b"), ("b", "c"), ("c", "a")}) == ["a", "b", "c", "a"]
    assert find_cycle({("a", "b"), ("b", "c")}) is None
    places = upward({("frictiongym.friction", "frictiongym.cli"): ["friction/x.py:3"]})
    assert places == [
        "friction/x.py:3: frictiongym.friction (layer 0) imports frictiongym.cli (layer 5)"
    ]
    edges = {("a", "b"): ["a/x.py:3"], ("b", "a"): ["b/y.py:5", "b/z.py:1"]}
    assert cycle_message(["a", "b", "a"], edges) == (
        "import cycle: a -> b (a/x.py:3); b -> a (b/y.py:5, b/z.py:1)"
    )


def test_names_imported_from_the_root_resolve_through_its_lazy_table():
    source = "from frictiongym import register_envs, load_params, __version__\n"
    assert list(imports_in(source, "frictiongym.friction")) == [
        ("frictiongym.envs", 1),
        ("frictiongym.params", 1),
        ("frictiongym.__version__", 1),
    ]

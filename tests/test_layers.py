"""The package's import graph: no circles, and no arrow from a floor up to a floor above it.

Every ``import`` of a ``sppo_sb3`` module counts, wherever it stands (module level, inside a function, under
``TYPE_CHECKING``): an import deferred into a function is still an arrow. ``python tests/test_layers.py`` prints the
graph's figures: modules per floor, arrows, circles and upward arrows.
"""

from __future__ import annotations

import ast
from collections.abc import Iterator
from pathlib import Path

import pytest

PACKAGE_DIR = Path(__file__).resolve().parents[1] / "sppo_sb3"

#: the floors, lowest first: a module may import its own floor and the floors below it, never one above
FLOORS: tuple[tuple[str, ...], ...] = (
    ("sppo_sb3.common", "sppo_sb3.algorithms"),  # conventions, keys, the shared on-policy machinery, the list of algorithms
    ("sppo_sb3.envs",),  # the tasks' physics
    ("sppo_sb3.shield.base",),  # the shield's contract: ShieldingRule and its decisions
    ("sppo_sb3.shield.mujoco", "sppo_sb3.shield.learned", "sppo_sb3.shield.analysis"),  # engines, learned rules, analysis
    ("sppo_sb3.shield.tasks",),  # the built-in tasks' rules, on the engines
    # the registry behind shield="auto", the wrapper, what the learner is told of an intervention, saving and loading a
    # shielded model's rule, deployment with and without the shield; the shield's public names
    ("sppo_sb3.shield",),
    (  # the algorithms
        "sppo_sb3.sppo",
        "sppo_sb3.pdo",
        "sppo_sb3.cpo",
        "sppo_sb3.sailr",
        "sppo_sb3.csc",
        "sppo_sb3.saclag",
    ),
    (  # what uses the algorithms: the zoo, the CLIs, the package's front door
        "sppo_sb3",
        "sppo_sb3.zoo",
        "sppo_sb3.train",
        "sppo_sb3.enjoy",
        "sppo_sb3.record_video",
    ),
)


def module_name(path: Path) -> str:
    """``sppo_sb3.a.b`` for ``sppo_sb3/a/b.py`` (and ``sppo_sb3.a`` for ``sppo_sb3/a/__init__.py``)."""
    parts = list(path.relative_to(PACKAGE_DIR.parent).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def package_modules() -> dict[str, Path]:
    """Every module of the package, by dotted name."""
    return {module_name(path): path for path in sorted(PACKAGE_DIR.rglob("*.py"))}


def imported_names(path: Path, name: str) -> Iterator[str]:
    """The dotted names a module imports (``from a import b`` gives ``a.b``; relative imports resolved)."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            yield from (alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join([*anchor, *([node.module] if node.module else [])])
            yield base
            yield from (f"{base}.{alias.name}" for alias in node.names)


def import_graph() -> dict[str, set[str]]:
    """Arrows between the package's modules: ``graph[a]`` holds the modules ``a`` imports (itself excluded)."""
    modules = package_modules()
    graph: dict[str, set[str]] = {}
    for name, path in modules.items():
        targets = set()
        for imported in imported_names(path, name):
            if imported == "sppo_sb3" or imported.startswith("sppo_sb3."):
                while imported not in modules:  # ``from a.b import SomeClass``: the module is ``a.b``
                    imported = imported.rpartition(".")[0]
                targets.add(imported)
        graph[name] = targets - {name}
    return graph


def circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan's algorithm, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []
    for root in sorted(graph):
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = len(index)
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph[child]))))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
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
                    found.append(sorted(component))
    return found


def floor_of(module: str) -> int:
    """The floor of a module: that of the longest prefix listed in :data:`FLOORS`.

    :raises KeyError: the module is on no floor.
    """
    best = (-1, 0)
    for level, prefixes in enumerate(FLOORS):
        for prefix in prefixes:
            if (module == prefix or module.startswith(prefix + ".")) and len(prefix) > best[0]:
                best = (len(prefix), level)
    if best[0] < 0:
        raise KeyError(module)
    return best[1]


def upward_arrows(graph: dict[str, set[str]]) -> list[tuple[str, str]]:
    """Every import of a module on a higher floor than the importer's."""
    return sorted((a, b) for a, targets in graph.items() for b in targets if floor_of(b) > floor_of(a))


def test_every_module_is_on_a_floor() -> None:
    unplaced = []
    for module in import_graph():
        try:
            floor_of(module)
        except KeyError:
            unplaced.append(module)
    assert not unplaced, f"modules on no floor: {unplaced}; add them to FLOORS in tests/test_layers.py"


def test_no_import_circles() -> None:
    assert circles(import_graph()) == []


def test_no_upward_arrows() -> None:
    assert upward_arrows(import_graph()) == []


@pytest.mark.parametrize(
    ("graph", "expected"),
    [
        ({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}, [["a", "b", "c"]]),
        ({"a": {"b"}, "b": set(), "c": {"b"}}, []),
        ({"a": {"b"}, "b": {"a"}, "c": {"d"}, "d": {"c"}}, [["a", "b"], ["c", "d"]]),
    ],
)
def test_circles_are_found(graph: dict[str, set[str]], expected: list[list[str]]) -> None:
    """The check itself can fail: it finds the circles of small graphs."""
    assert sorted(circles(graph)) == expected


def test_upward_arrows_are_found() -> None:
    graph = {"sppo_sb3.common.costs": {"sppo_sb3.shield.wrapper"}, "sppo_sb3.shield.wrapper": {"sppo_sb3.common.costs"}}
    assert upward_arrows(graph) == [("sppo_sb3.common.costs", "sppo_sb3.shield.wrapper")]
    inside_the_shield = {"sppo_sb3.shield.base": {"sppo_sb3.shield.tasks.point"}, "sppo_sb3.shield.tasks.point": set()}
    assert upward_arrows(inside_the_shield) == [("sppo_sb3.shield.base", "sppo_sb3.shield.tasks.point")]


if __name__ == "__main__":
    graph = import_graph()
    for level, prefixes in enumerate(FLOORS):
        members = [module for module in graph if floor_of(module) == level]
        print(f"floor {level} ({', '.join(prefixes)}): {len(members)} modules")
    print(f"arrows: {sum(len(targets) for targets in graph.values())}")
    print(f"circles: {circles(graph)}")
    print(f"upward arrows: {upward_arrows(graph)}")

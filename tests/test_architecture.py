"""The package's structure: no import cycles, and subpackages that depend on each other in one direction.

Every import of a ``dsc_fmu`` module counts, those inside functions included: a cycle hidden in a
function is still a cycle.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

import dsc_fmu

PACKAGE = Path(dsc_fmu.__file__).parent

# What each part of the package may import from the package (besides itself and ``dsc_fmu.__version__``).
ALLOWED = {
    "errors": set(),
    "files": set(),
    "platforms": set(),
    "macho": set(),
    "identity": {"errors"},
    "models": set(),
    "fmu": {"models"},
    "registry": {"models", "errors"},
    "scenario": {"registry", "models", "errors"},
    "fmubuild": {"platforms", "macho", "registry", "fmu", "models", "errors", "files", "identity"},
    "cosim": {"platforms", "macho", "fmubuild", "registry", "scenario", "models", "errors", "files", "identity"},
    "study": {"platforms", "macho", "cosim", "fmubuild", "registry", "scenario", "models", "errors", "files", "identity"},
    "interop": {"platforms", "macho", "cosim", "fmubuild", "registry", "scenario", "models", "errors", "files", "identity"},
    "cli": {"platforms", "macho", "study", "interop", "cosim", "fmubuild", "registry", "scenario", "models", "errors",
            "files", "identity"},
    "__main__": {"cli"},
    "__init__": set(),
}
# Above the builder, only these build FMUs; the rest tell FMU builds apart through ``identity``.
BUILDERS = {"dsc_fmu.cosim.run", "dsc_fmu.study.sweep", "dsc_fmu.study.laws", "dsc_fmu.cli"}


def _module_name(path: Path) -> str:
    parts = ["dsc_fmu", *path.relative_to(PACKAGE).with_suffix("").parts]
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


MODULES = {_module_name(path): path for path in sorted(PACKAGE.rglob("*.py"))}


def _part(module: str) -> str:
    """The part of the package a module belongs to: a subpackage or a top-level module."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "__init__"


def _imports(module: str) -> set[str]:
    """The ``dsc_fmu`` modules that ``module`` imports, anywhere in its file."""
    path = MODULES[module]
    package = module if path.name == "__init__.py" else module.rsplit(".", 1)[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names if alias.name.split(".")[0] == "dsc_fmu")
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - node.level + 1]
                source = ".".join(base + ([node.module] if node.module else []))
            elif (node.module or "").split(".")[0] == "dsc_fmu":
                source = node.module
            else:
                continue
            for alias in node.names:  # ``from . import signals`` imports the module dsc_fmu...signals
                found.add(f"{source}.{alias.name}" if f"{source}.{alias.name}" in MODULES else source)
    return {name for name in found if name in MODULES and name != module}


GRAPH = {module: _imports(module) for module in MODULES}


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan)."""
    index, low, stack, on_stack, components = {}, {}, [], set(), []

    def visit(node):
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for other in graph[node]:
            if other not in index:
                visit(other)
                low[node] = min(low[node], low[other])
            elif other in on_stack:
                low[node] = min(low[node], index[other])
        if low[node] == index[node]:
            component = []
            while True:
                member = stack.pop()
                on_stack.discard(member)
                component.append(member)
                if member == node:
                    break
            if len(component) > 1:
                components.append(sorted(component))

    for node in graph:
        if node not in index:
            visit(node)
    return components


def test_the_graph_sees_imports_of_every_kind():
    """The graph finds relative, absolute, function-level and ``from . import module`` imports."""
    assert "dsc_fmu.cosim.signals" in GRAPH["dsc_fmu.cosim.wiring"]  # from . import signals
    assert "dsc_fmu.registry" in GRAPH["dsc_fmu.cosim.wiring"]  # from ..registry import ...
    assert "dsc_fmu.study.cluster" in GRAPH["dsc_fmu.study.execute"]  # inside a function
    assert "dsc_fmu.cli" in GRAPH["dsc_fmu.__main__"]


def test_the_cycle_finder_finds_a_cycle():
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


def test_no_import_cycles():
    assert _cycles(GRAPH) == []


@pytest.mark.parametrize("module", sorted(MODULES))
def test_dependencies_go_one_way(module):
    """Each module imports only from its own part of the package and the parts below it."""
    own = _part(module)
    wrong = sorted(m for m in GRAPH[module] if _part(m) not in ALLOWED[own] | {own, "__init__"})
    assert wrong == [], f"{module} ({own}) imports {wrong}; allowed: {sorted(ALLOWED[own])}"


def test_every_part_is_placed():
    assert {_part(module) for module in MODULES} <= set(ALLOWED)


@pytest.mark.parametrize("name", sorted(set(dsc_fmu.__all__) - {"__version__"}))
def test_the_package_exports_resolve(name):
    """``from dsc_fmu import <name>`` gives the object of the module that defines it."""
    module = __import__(dsc_fmu._EXPORTS[name], fromlist=[name])
    assert getattr(dsc_fmu, name) is getattr(module, name)


def _reachable(module: str) -> set[str]:
    """Every module that importing ``module`` may import, directly or not."""
    seen, todo = set(), [module]
    while todo:
        for other in GRAPH[todo.pop()] - seen:
            seen.add(other)
            todo.append(other)
    return seen


def test_only_the_modules_that_build_fmus_import_the_builder():
    """Identifying an FMU build needs ``identity``, not the builder (and with it pythonfmu): no module
    above the builder reaches it, directly or through others, but those that build FMUs."""
    above = {module for module in MODULES if _part(module) in ("cosim", "study", "interop", "cli")}
    reaching = {module for module in above - BUILDERS if any(_part(m) == "fmubuild" for m in _reachable(module))}
    assert reaching == set(), sorted(reaching)

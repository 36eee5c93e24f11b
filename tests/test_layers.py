"""The package's layer rule (README, "Package layout"): lower layers never import higher ones, no import cycles.

Imports are read with ``ast`` (nothing is imported), including imports inside functions and under
``TYPE_CHECKING``: a lazy import of a higher layer is still a dependency on it.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

import hqp_tpm

ROOT = Path(hqp_tpm.__file__).parent

#: Bottom-up; a module may import its own layer and the ones before it (README layout table).
LAYERS = ("errors", "data", "_jit", "solvers", "robot", "geometry", "references", "tasks", "control", "policies",
          "plants", "app", "testing")
RANK = {"errors": 0, "data": 0, "_jit": 0, **{name: i for i, name in enumerate(LAYERS) if i >= 3}}


def module_name(path: Path) -> str:
    parts = path.relative_to(ROOT.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


MODULES = {module_name(p): p for p in sorted(ROOT.rglob("*.py"))}


def layer(module: str) -> str | None:
    """Layer of a ``hqp_tpm`` module (None: the top-level package itself)."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else None


def _type_checking(node: ast.AST) -> bool:
    return isinstance(node, ast.If) and isinstance(node.test, ast.Name) and node.test.id == "TYPE_CHECKING"


def _runtime_nodes(tree: ast.AST):
    """Every node but those under ``if TYPE_CHECKING:`` (imports that never run)."""
    todo = [tree]
    while todo:
        node = todo.pop()
        yield node
        todo.extend(c for c in ast.iter_child_nodes(node) if not _type_checking(c))


def imports(module: str, top_level_only: bool = False, runtime: bool = False) -> set[str]:
    """``hqp_tpm`` modules imported by ``module`` (``from pkg import name``: the submodule if ``name`` is one);
    ``runtime``: without the imports under ``TYPE_CHECKING``."""
    path = MODULES[module]
    tree = ast.parse(path.read_text(), str(path))
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    nodes = tree.body if top_level_only else _runtime_nodes(tree) if runtime else ast.walk(tree)
    found = set()
    for node in nodes:
        if isinstance(node, ast.Import):
            found.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = package.split(".")
                base = ".".join(parts[: len(parts) - node.level + 1] + ([base] if base else []))
            for a in node.names:
                found.add(f"{base}.{a.name}" if f"{base}.{a.name}" in MODULES else base)
    return {m for m in found if m == "hqp_tpm" or m.startswith("hqp_tpm.")}


def test_every_subpackage_has_a_layer():
    unknown = {layer(m) for m in MODULES} - set(RANK) - {None}
    assert not unknown, f"subpackages without a layer: {sorted(unknown)}: add them to LAYERS and the README table"


@pytest.mark.parametrize("module", sorted(m for m in MODULES if layer(m) is not None))
def test_lower_layers_never_import_higher_ones(module):
    rank = RANK[layer(module)]
    # the top-level package (the lazy public API, __version__) counts as the app layer
    bad = sorted(m for m in imports(module) if RANK[layer(m) or "app"] > rank)
    assert not bad, f"{module} (layer {layer(module)!r}) imports the higher layer(s) {bad}"


@pytest.mark.parametrize("top_level_only", [True, False], ids=["at import", "in functions too"])
def test_no_import_cycles(top_level_only):
    """Depth-first search over the imports that run: at import time, and also those inside functions (a lazy import
    that closes a cycle is still two modules that need each other; only ``TYPE_CHECKING`` imports are left out).
    The modules a package's ``__init__`` re-exports are left out of the second graph (its lazy public API)."""
    graph = {m: imports(m, top_level_only=True) & set(MODULES) for m in MODULES} if top_level_only else \
        {m: imports(m, runtime=True) & set(MODULES) - {"hqp_tpm"} for m in MODULES if m != "hqp_tpm"}
    state: dict[str, int] = {}  # 1: on the current path, 2: done
    path: list[str] = []

    def visit(m):
        state[m] = 1
        path.append(m)
        for n in sorted(graph[m]):
            if state.get(n) == 1:
                raise AssertionError("import cycle: " + " -> ".join(path[path.index(n):] + [n]))
            if n not in state:
                visit(n)
        path.pop()
        state[m] = 2

    for m in sorted(graph):
        if m not in state:
            visit(m)


def test_the_import_parser_resolves_imports():
    """The parser resolves absolute and relative imports (so the rule above is not vacuous)."""
    assert "hqp_tpm.solvers.levels" in imports("hqp_tpm.tasks.base")
    assert imports("hqp_tpm.geometry.distances") >= {"hqp_tpm.geometry.obstacles", "hqp_tpm.geometry.witness"}


HEAVY = ("qpsolvers", "osqp", "proxsuite", "matplotlib", "meshcat", "example_robot_data", "tqdm", "scipy.spatial")


@pytest.mark.parametrize("statement", [
    "import hqp_tpm",
    "import hqp_tpm.solvers",
    "import hqp_tpm; hqp_tpm.Robot; hqp_tpm.Controller; hqp_tpm.DistanceField; hqp_tpm.Stack",
    "import hqp_tpm.policies, hqp_tpm.app.cli, hqp_tpm.app.runner",
])
def test_imports_are_cheap(statement, tmp_path):
    """Backends, plotting, the viewer and example-robot-data are imported where first used, not at import."""
    probe = f"{statement}\nimport sys\nprint(' '.join(m for m in {HEAVY!r} if m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", probe], cwd=tmp_path, capture_output=True, text=True, check=True)
    assert out.stdout.split() == [], f"{statement!r} imported {out.stdout.split()}"

"""Every third-party module the package imports is a declared dependency; the scenarios' QP backends are base ones."""

from __future__ import annotations

import ast
import re
import sys
from importlib.metadata import packages_distributions
from pathlib import Path

import pytest

import hqp_tpm
from hqp_tpm.app.scenario import load
from hqp_tpm.data import scenarios_dir
from hqp_tpm.solvers.cascaded_qp import PIP_PACKAGE

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib

ROOT = Path(hqp_tpm.__file__).parent
PYPROJECT = ROOT.parent / "pyproject.toml"

#: Modules whose distribution ``packages_distributions`` cannot see (installed under cmeel.prefix) or that
#: several distributions provide (example_robot_data: example-robot-data < 5, example-robot-data-loaders >= 5).
KNOWN = {"pinocchio": {"pin"}, "coal": {"coal"}, "example_robot_data": {"example-robot-data",
                                                                         "example-robot-data-loaders"},
         "proxsuite": {"proxsuite"}, "tomli": {"tomli"}, "distributed": {"distributed", "dask"}}


def _norm(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def _requirements(extra: str | None = None) -> dict[str, str]:
    """Declared requirement name -> its environment marker ('' if none)."""
    project = tomllib.loads(PYPROJECT.read_text())["project"]
    reqs = project["dependencies"] if extra is None else project["optional-dependencies"][extra]
    out = {}
    for req in reqs:
        spec, _, marker = req.partition(";")
        out[_norm(re.split(r"[<>=!~\[ ]", spec.strip(), maxsplit=1)[0])] = marker.strip()
    return out


def _names(nodes) -> set[str]:
    found = set()
    for node in nodes:
        if isinstance(node, ast.Import):
            found.update(a.name.split(".")[0] for a in node.names)
        elif isinstance(node, ast.ImportFrom) and not node.level:
            found.add(node.module.split(".")[0])
    return found - set(sys.stdlib_module_names) - {"hqp_tpm"}


def _imported_modules(where: str = "") -> set[str]:
    """Third-party top-level modules imported by the package (``where``: only under that subfolder)."""
    return set().union(*(_names(ast.walk(ast.parse(p.read_text(), str(p)))) for p in (ROOT / where).rglob("*.py")))


def _optional_modules() -> set[str]:
    """Modules imported inside ``try: ... except ImportError`` (optional features, declared in an extra)."""
    found = set()
    for path in ROOT.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Try) and any(
                    isinstance(h.type, ast.Name) and h.type.id in ("ImportError", "ModuleNotFoundError")
                    for h in node.handlers):
                found |= _names(n for stmt in node.body for n in ast.walk(stmt))
    return found


#: Application modules that import the app extra's packages at their top (only imported on use: figures,
#: replay, live viewer); nothing outside hqp_tpm/app imports them (test_library_never_imports_the_app_extra).
APP_MODULES_IMPORTING_THE_EXTRA = {"figures.py", "viewer_replay.py", "viewer_scene.py", "viewer_live.py",
                                   "viewer.py"}


def _top_level_names(path: Path) -> set[str]:
    """Third-party modules imported by ``path`` when it is imported (not inside a function)."""
    tree = ast.parse(path.read_text(), str(path))
    found = set()

    def visit(node):
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
                continue
            found.update(_names([child]))
            visit(child)

    visit(tree)
    return found


def _function_level_modules() -> set[str]:
    """Modules imported only inside functions, or at the top of the app modules that draw and view."""
    everywhere = set()
    for path in ROOT.rglob("*.py"):
        if path.parent.name == "app" and path.name in APP_MODULES_IMPORTING_THE_EXTRA:
            continue
        everywhere |= _top_level_names(path)
    return _imported_modules() - everywhere


pytestmark = pytest.mark.skipif(not PYPROJECT.is_file(), reason="needs the source tree (pyproject.toml)")


def test_every_imported_module_is_declared():
    """Base dependencies for the package; the testing extra for what only hqp_tpm.testing imports."""
    declared = _requirements()
    testing_only = _imported_modules("testing") - {m for p in ROOT.iterdir() if p.name != "testing"
                                                   for m in (_imported_modules(p.name) if p.is_dir() else ())}
    project = tomllib.loads(PYPROJECT.read_text())["project"]
    in_extras = set().union(*(_requirements(extra) for extra in project.get("optional-dependencies", {})))
    optional = _optional_modules()
    app_only = _function_level_modules()  # the application's lazy imports: the app extra may provide them
    dists = packages_distributions()
    missing = {}
    for module in sorted(_imported_modules()):
        provided_by = {_norm(d) for d in dists.get(module, ())} | KNOWN.get(module, set())
        assert provided_by, f"no installed distribution provides {module!r}: add it to KNOWN"
        if module in testing_only and provided_by & set(_requirements("testing")):
            continue
        if module in optional and provided_by & in_extras:
            continue
        if module in app_only and provided_by & set(_requirements("app")):
            continue
        if not provided_by & set(declared):
            missing[module] = sorted(provided_by)
    assert not missing, f"imported but not declared in pyproject.toml: {missing}"


def test_tomli_only_where_tomllib_is_missing():
    assert _requirements()["tomli"].replace('"', "'") == "python_version < '3.11'"


def test_scenario_backends_are_base_dependencies():
    """``make demo`` / ``make scenarios`` install the base package only: every bundled scenario must run with it."""
    declared = _requirements()
    backends = set()
    for path in sorted(scenarios_dir().glob("*.toml")):
        solver = load(path).solver
        if solver == "qp" or solver.startswith("qp:"):
            backends.add("proxqp" if solver == "qp" else solver.split(":", 1)[1])
    assert backends, "no scenario uses the QP (the check would be vacuous)"
    assert {_norm(PIP_PACKAGE[b]) for b in backends} <= set(declared), backends


def test_dev_installs_the_qp_and_testing_extras():
    """``make test`` installs ``.[dev]``: it must contain the extra backends the tests compare and the test tools."""
    assert set(_requirements("qp")) | set(_requirements("testing")) <= set(_requirements("dev"))


def test_library_never_imports_the_app_extra():
    """The base install (no extras) must import and solve: the app extra's packages are imported only by the
    application's figure and viewer modules, or inside functions (run in tests/test_wheel.py without them)."""
    extra = {_norm(r) for r in _requirements("app")}
    assert extra and not extra & set(_requirements()), "the app extra repeats base dependencies"
    dists = packages_distributions()
    modules = {m for m in _imported_modules() if {_norm(d) for d in dists.get(m, ())} & extra}
    assert {"matplotlib", "meshcat", "umsgpack", "tqdm"} <= modules, modules
    for path in ROOT.rglob("*.py"):
        if path.parent.name == "app" and path.name in APP_MODULES_IMPORTING_THE_EXTRA:
            continue
        assert not _top_level_names(path) & modules, f"{path.relative_to(ROOT)} imports the app extra at its top"


def test_import_and_solve_with_the_app_extra_blocked():
    """The same in this environment: the extra's modules made unimportable, the library imports, builds a
    scenario and runs it without figures, replay or progress bar; asking for figures names the extra."""
    import subprocess

    code = """
import sys
for m in ("matplotlib", "meshcat", "umsgpack", "tqdm"):
    sys.modules[m] = None
import numpy as np
import hqp_tpm
from hqp_tpm.app import build, scenario
x, _ = hqp_tpm.solve("sns_tpm", [hqp_tpm.Level(np.eye(2), np.ones(2))], 2, box=(-0.5 * np.ones(2), 0.5 * np.ones(2)))
assert np.allclose(x, [0.5, 0.5]), x  # the task scaled into the box
ctx = build.build_run(scenario.load("romeo_sns_tpm"))
for _ in range(3):
    ctx.controller.step()
out = sys.argv[1]
s = hqp_tpm.record("planar5_exact", out + "/a", steps=5, figures=False, replay=False)
assert s["steps"] == 5
try:
    hqp_tpm.record("planar5_exact", out + "/b", steps=5)
except hqp_tpm.HqpTpmError as exc:
    assert "pip install 'hqp-tpm[app]'" in str(exc) and "matplotlib" in str(exc), exc
else:
    raise SystemExit("figures without matplotlib did not fail")
assert not any(m in sys.modules and sys.modules[m] is not None for m in ("matplotlib", "meshcat", "tqdm"))
print("ok")
"""
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        out = subprocess.run([sys.executable, "-c", code, tmp], capture_output=True, text=True, timeout=600)
    assert out.returncode == 0 and out.stdout.strip() == "ok", out.stdout + out.stderr

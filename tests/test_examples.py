"""The downstream example project under examples/ runs its own test suite with hqp-tpm's pytest plugin."""

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "downstream_stack_check"


def test_downstream_example_project_passes_with_the_plugin_fixtures():
    from importlib.metadata import entry_points

    assert "hqp_tpm" in {e.name for e in entry_points(group="pytest11")}, (
        "the pytest11 entry point is not installed: reinstall the package (pip install -e '.[dev]')")
    run = subprocess.run([sys.executable, "-m", "pytest", "-p", "no:cacheprovider"], cwd=EXAMPLE,
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stdout + run.stderr
    # the plugin came through the pytest11 entry point, with the project's ini option
    assert "hqp-tpm " in run.stdout and "fixtures hqp_tpm_stack_check" in run.stdout
    assert "(solvers: tpm, nullspace, qp:proxqp, qp:daqp)" in run.stdout
    assert "5 passed" in run.stdout and "failed" not in run.stdout


def test_the_library_imports_without_hypothesis():
    code = """
import sys
sys.modules["hypothesis"] = None  # as if it were not installed
import hqp_tpm, hqp_tpm.testing
from hqp_tpm.testing import assert_solvers_agree, assert_task_derivatives
import numpy as np
assert assert_solvers_agree([(np.eye(2), np.ones(2))], ("tpm", "nullspace")).ok
try:
    import hqp_tpm.testing.strategies
except ImportError as e:
    assert "hqp-tpm[testing]" in str(e), e
else:
    raise SystemExit("strategies imported without hypothesis")
"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stdout + out.stderr


def test_the_fixture_reports_a_disagreement_with_the_table(tmp_path):
    (tmp_path / "test_loose.py").write_text('''
import numpy as np

def test_loose_qp(hqp_tpm_stack_check):
    rng = np.random.default_rng(0)
    levels = [(rng.standard_normal((m, 7)), rng.standard_normal(m)) for m in (3, 2, 3)]
    hqp_tpm_stack_check(levels, solver_options={"qp:proxqp": {"eps_abs": 1e-1}})
''')
    out = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "--hqp-tpm-solvers",
                          "tpm,qp:proxqp", "test_loose.py"], cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert out.returncode == 1, out.stdout + out.stderr
    assert "solvers disagree: tpm vs qp:proxqp" in out.stdout and "FAIL tpm vs qp:proxqp" in out.stdout
    assert "qp:daqp" not in out.stdout  # the solvers given on the command line
    assert "hqp_tpm_cases" in out.stdout and "load_case(" in out.stdout

"""The cascaded QP applies the analytic solvers' damping law to inequality levels too, and fails fast.

Without it, an acceleration-level stack EE position > pointing cone (inequality) > posture on the
LBR iiwa 7 ran away (|q| ~ 1e9 at t = 1.35 s with daqp and quadprog) while the damped TPM stayed bounded.
``HQP_TPM_QP_RUN_BACKENDS`` (comma separated) chooses the backends of the 2 s run: daqp by default (35 s
on a loaded 2-core machine); proxqp,daqp,quadprog,osqp for the full check (osqp alone takes ~130 s).
"""

import os
import time
from pathlib import Path

import numpy as np
import pytest
from threadpoolctl import threadpool_limits

from hqp_tpm.errors import SolverBudgetError
from hqp_tpm.solvers import Level, cascaded_qp, tpm

DAMPING = {"lambda_max": 0.05, "eps": 0.1}
SCENARIO = Path(__file__).parent / "data" / "iiwa_cone_acceleration.toml"
BACKENDS = os.environ.get("HQP_TPM_QP_RUN_BACKENDS", "daqp").split(",")


def cone_stack(rng, delta):
    """EE position (3 rows) > a cone row nearly in their span (projected sigma ~ delta), violated at 0 and
    after the EE level > posture (7 rows, 3 directions left: damped by lambda_max in TPM and the recursion)."""
    n = 7
    J1 = rng.standard_normal((3, n))
    Jc = rng.standard_normal(3) @ J1 + delta * rng.standard_normal(n)
    b1 = rng.standard_normal(3)
    lo = max(Jc @ np.linalg.pinv(J1) @ b1, 0.0) + abs(rng.standard_normal()) + 0.5  # violated after level 1
    return [(J1, b1), Level(Jc.reshape(1, -1), lower=[lo], upper=[np.inf]),
            (np.eye(n), rng.standard_normal(n))]


@pytest.mark.parametrize("backend", ["proxqp", "daqp", "quadprog", "osqp"])
def test_damped_inequality_level_equals_damped_tpm(backend):
    """A nearly singular active cone row: the damped cascade is the damped TPM (the old cascade stepped 1/sigma)."""
    rng = np.random.default_rng(4)
    tol = 1e-6 if backend == "osqp" else 1e-8
    for _ in range(20):
        levels = cone_stack(rng, 10.0 ** rng.uniform(-4, -1.5))
        x = cascaded_qp(levels, backend, **DAMPING)
        xt = tpm(levels, **DAMPING)
        assert np.abs(x - xt).max() <= tol * (1.0 + np.abs(xt).max()), (backend, np.abs(x - xt).max())


def test_a_level_over_its_time_budget_fails_fast_naming_the_level(monkeypatch):
    import qpsolvers

    real = qpsolvers.solve_problem

    def slow(problem, solver, **kw):
        t = time.process_time()
        while time.process_time() - t < 0.05:  # CPU time: the budget counts this process's CPU seconds
            pass
        return real(problem, solver, **kw)

    monkeypatch.setattr(qpsolvers, "solve_problem", slow)
    levels = [(np.eye(3)[:1], [1.0]), (np.eye(3)[1:], [1.0, 2.0])]
    with pytest.raises(SolverBudgetError, match=r"level 0: backend 'daqp' spent .* CPU, .* time budget of 0.01 s"):
        cascaded_qp(levels, "daqp", time_budget=0.01)
    assert np.allclose(cascaded_qp(levels, "daqp", time_budget=None), [1.0, 1.0, 2.0])


def run_iiwa(solver: str, duration: float = 2.0):
    from hqp_tpm.app import build, scenario

    data = scenario.read(SCENARIO)
    data["scenario"]["solver"] = solver
    data["scenario"]["duration"] = duration
    sc = scenario.parse(data, SCENARIO)
    _robot, ctrl, tasks, _policy = build.build(sc)
    ee = tasks["ee"]
    worst = 0.0
    with threadpool_limits(1):
        for _ in range(sc.steps):
            t0 = time.perf_counter()
            ctrl.step()
            worst = max(worst, time.perf_counter() - t0)
            assert np.abs(ctrl.q).max() < 100.0, f"{solver}: runaway at t = {ctrl.t:.3f}"
    return float(np.linalg.norm(ee.error(ctrl.state, ee.reference(ctrl.t)[0]))), worst


@pytest.fixture(scope="module")
def tpm_final_error():
    return run_iiwa("tpm")[0]


@pytest.mark.parametrize("backend", BACKENDS)
def test_iiwa_cone_stack_runs_two_seconds_with_every_backend(backend, tpm_final_error):
    """2 s at acceleration level; the final EE error within 1 mm of TPM's; every level within its 1 s budget."""
    err, worst = run_iiwa(f"qp:{backend}")
    assert abs(err - tpm_final_error) <= 1e-3, (backend, err, tpm_final_error)

"""Cascaded QP (lexicographic reference) against TPM, bounded least squares and its own guarantees."""

from pathlib import Path

import numpy as np
import pytest
import qpsolvers
from conftest import random_stack, rel_diff
from hypothesis import given, settings
from scipy.optimize import lsq_linear

from hqp_tpm.errors import BoxError, ShapeError, SolverFailedError, SolverNotAvailableError
from hqp_tpm.solvers import Level, tpm
from hqp_tpm.solvers.cascaded_qp import CascadeInfo, cascaded_qp
from hqp_tpm.testing.strategies import dependent_singular_stack as dependent_stack
from hqp_tpm.testing.strategies import full_rank_stacks

#: Agreement with TPM on feasible equality stacks: interior-point / active-set backends to 1e-8,
#: OSQP (first order) at its own tolerance.
TOL = {"proxqp": 1e-8, "daqp": 1e-8, "quadprog": 1e-8, "osqp": 1e-5}
BACKENDS = [s for s in TOL if s in qpsolvers.available_solvers]
EXACT = [s for s in ("proxqp", "daqp", "quadprog") if s in BACKENDS]


def feasible_stacks():
    """l = 1..6 levels of m_i = 1..4 rows, n up to 20, sum m_i <= n (full row rank), and an rng."""
    return full_rank_stacks(max_n=20, max_levels=6, max_rows=4)


def first_residual(levels, x):
    J, b = levels[0]
    return np.linalg.norm(J @ x - b)


# ----------------------------------------------------------------------------------------
# Equality stacks: the cascade is the lexicographic minimum-norm solution, i.e. TPM.
# ----------------------------------------------------------------------------------------
@pytest.mark.parametrize("solver", BACKENDS)
@settings(max_examples=100, deadline=None)
@given(data=feasible_stacks())
def test_feasible_equality_stack_equals_tpm(solver, data):
    levels, rng = data
    assert rel_diff(cascaded_qp(levels, solver), tpm(levels)) < TOL[solver]
    x0 = rng.standard_normal(levels[0][0].shape[1])
    assert rel_diff(cascaded_qp(levels, solver, x0=x0), tpm(levels, x0=x0)) < TOL[solver]


@pytest.mark.parametrize("solver", BACKENDS)
@pytest.mark.parametrize("seed", range(40))
def test_dependent_and_conflicting_stack_equals_tpm(solver, seed):
    levels = dependent_stack(np.random.default_rng(seed))
    x_tpm = tpm(levels)
    x, info = cascaded_qp(levels, solver, return_info=True)
    tol = 1e-7 if solver in EXACT else 1e-5
    assert abs(info.residuals[0] - first_residual(levels, x_tpm)) < tol
    assert rel_diff(x, x_tpm) < tol


def test_info_reports_residuals_and_backend():
    rng = np.random.default_rng(0)
    levels = [(rng.standard_normal((2, 5)), rng.standard_normal(2)), (rng.standard_normal((4, 5)), np.ones(4))]
    x, info = cascaded_qp(levels, "quadprog", return_info=True)
    assert isinstance(info, CascadeInfo) and info.solver == "quadprog" and info.qp_count >= 2
    np.testing.assert_allclose(info.residuals, [np.linalg.norm(J @ x - b) for J, b in levels], atol=1e-12)
    assert info.residuals[0] < 1e-9 < info.residuals[1]  # 6 rows on 5 columns: the lower level conflicts


def test_empty_stack_is_x0_clipped_to_the_box():
    x = cascaded_qp([], n=3, x0=np.array([1.0, 2.0, -3.0]), lower=-1.5, upper=1.5)
    np.testing.assert_allclose(x, [1.0, 1.5, -1.5], atol=1e-9)


# ----------------------------------------------------------------------------------------
# Inequality levels.
# ----------------------------------------------------------------------------------------
@pytest.mark.parametrize("solver", BACKENDS)
@pytest.mark.parametrize("seed", range(10))
def test_bound_slack_at_the_optimum_changes_nothing(solver, seed):
    rng = np.random.default_rng(seed)
    levels = random_stack(rng, 9, [2, 3, 2])
    x = tpm(levels)
    Jc = rng.standard_normal((2, 9))
    bound = Level(Jc, lower=Jc @ x - rng.uniform(0.1, 1, 2), upper=Jc @ x + rng.uniform(0.1, 1, 2))
    for at in range(4):
        stack = levels[:at] + [bound] + levels[at:]
        assert rel_diff(cascaded_qp(stack, solver), x) < TOL[solver]


@pytest.mark.parametrize("solver", BACKENDS)
@pytest.mark.parametrize("seed", range(10))
@pytest.mark.parametrize("side", ["lower", "upper"])
def test_violated_bound_is_met_exactly(solver, seed, side):
    """The task below pulls ``c x`` past the bound: the optimum sits on it, the rest is solved as TPM."""
    rng = np.random.default_rng(seed)
    n = 8
    c, J = rng.standard_normal((1, n)), rng.standard_normal((3, n))
    bound, sign = rng.standard_normal(), (1.0 if side == "lower" else -1.0)
    b = rng.standard_normal(3)
    level = Level(c, lower=bound) if side == "lower" else Level(c, upper=bound)
    stack = [level, (np.vstack([c, J]), np.concatenate([[bound - sign], b]))]
    x, info = cascaded_qp(stack, solver, return_info=True)
    tol = 1e-9 if solver in EXACT else 1e-6
    assert abs(c[0] @ x - bound) < tol and info.residuals[0] < tol
    assert rel_diff(x, tpm([(c, [bound]), (J, b)])) < TOL[solver]


@pytest.mark.parametrize("solver", BACKENDS)
@pytest.mark.parametrize("seed", range(10))
def test_infeasible_lower_inequality_level_keeps_higher_levels(solver, seed):
    rng = np.random.default_rng(seed)
    J1, b1 = rng.standard_normal((3, 7)), rng.standard_normal(3)
    J3, b3 = rng.standard_normal((2, 7)), rng.standard_normal(2)
    # the inequality asks J1[0] x in [b1[0] + 1, b1[0] + 2]: impossible while level 0 holds
    stack = [(J1, b1), Level(J1[:1], lower=[b1[0] + 1.0], upper=[b1[0] + 2.0]), (J3, b3)]
    x, info = cascaded_qp(stack, solver, return_info=True)
    tol = 1e-8 if solver in EXACT else 1e-5
    assert info.residuals[0] < tol
    assert abs(info.residuals[1] - 1.0) < tol
    assert rel_diff(x, tpm([(J1, b1), (J3, b3)])) < TOL[solver]


@pytest.mark.parametrize("solver", BACKENDS)
def test_inequality_level_with_equal_bounds_is_an_equality(solver):
    rng = np.random.default_rng(3)
    levels = random_stack(rng, 6, [2, 3])
    J, b = levels[0]
    stack = [Level(J, lower=b, upper=b), levels[1]]
    assert rel_diff(cascaded_qp(stack, solver), tpm(levels)) < TOL[solver]


# ----------------------------------------------------------------------------------------
# Hard box (joint limits).
# ----------------------------------------------------------------------------------------
@pytest.mark.parametrize("solver", BACKENDS)
@pytest.mark.parametrize("seed", range(40))
def test_box_is_met_and_first_level_is_bounded_least_squares(solver, seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(3, 12))
    m = int(rng.integers(1, n + 3))
    J, b = rng.standard_normal((m, n)), 5 * rng.standard_normal(m)
    lo, up = -rng.uniform(0.1, 1, n), rng.uniform(0.1, 1, n)
    stack = [(J, b), (rng.standard_normal((2, n)), rng.standard_normal(2))]
    x, info = cascaded_qp(stack, solver, lower=lo, upper=up, return_info=True)
    assert np.all(x >= lo - 1e-9) and np.all(x <= up + 1e-9)
    best = lsq_linear(J, b, bounds=(lo, up), method="bvls", tol=1e-14).x
    tol = 1e-8 if solver in EXACT else 1e-6
    assert info.residuals[0] <= np.linalg.norm(J @ best - b) + tol * max(1.0, np.linalg.norm(b))


@pytest.mark.parametrize("solver", BACKENDS)
def test_box_holding_zero_that_no_task_hits_changes_nothing(solver):
    rng = np.random.default_rng(7)
    levels = random_stack(rng, 10, [3, 2], scale=1e-2)
    x = tpm(levels)
    assert rel_diff(cascaded_qp(levels, solver, lower=-1.0, upper=1.0), x) < TOL[solver]


def test_pinned_joint_stays_at_its_value():
    rng = np.random.default_rng(1)
    levels = random_stack(rng, 5, [2, 2])
    lo, up = np.full(5, -2.0), np.full(5, 2.0)
    lo[2] = up[2] = 0.3  # a locked joint: lower == upper
    x = cascaded_qp(levels, "quadprog", lower=lo, upper=up)
    assert x[2] == pytest.approx(0.3, abs=1e-12)


@pytest.mark.parametrize("seed", range(100))
def test_backends_agree_on_mixed_stacks_with_a_box(seed):
    """Equality and inequality levels under joint limits: no reference but each other."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(3, 15))
    levels = []
    for _ in range(int(rng.integers(1, 5))):
        m = int(rng.integers(1, 4))
        J = rng.standard_normal((m, n))
        if rng.random() < 0.4:
            low = rng.standard_normal(m)
            levels.append(Level(J, lower=low, upper=low + rng.uniform(0, 2, m)))
        else:
            levels.append((J, 2 * rng.standard_normal(m)))
    box = (-rng.uniform(0.1, 1, n), rng.uniform(0.1, 1, n))
    xs = {s: cascaded_qp(levels, s, lower=box[0], upper=box[1]) for s in EXACT}
    ref = xs[EXACT[0]]
    for s, x in xs.items():
        assert rel_diff(x, ref) < 1e-6, s


# ----------------------------------------------------------------------------------------
# Errors.
# ----------------------------------------------------------------------------------------
def test_unknown_backend_names_the_value_and_the_installed_ones():
    with pytest.raises(SolverNotAvailableError, match="no_such_qp") as err:
        cascaded_qp([(np.eye(2), np.ones(2))], "no_such_qp")
    assert "proxqp" in str(err.value) and "pip install proxsuite" in str(err.value)


def test_known_but_missing_backend_says_what_to_install():
    missing = [s for s in ("clarabel", "cvxopt", "highs", "piqp", "scs") if s not in qpsolvers.available_solvers]
    if not missing:
        pytest.skip("every candidate backend is installed")
    with pytest.raises(SolverNotAvailableError, match="pip install"):
        cascaded_qp([(np.eye(2), np.ones(2))], missing[0])


@pytest.mark.parametrize("lower, upper, match", [
    ([0.0, 1.0, 0.0], [1.0, 0.5, 1.0], r"lower\[1\] = 1.0 > upper\[1\] = 0.5"),
    ([0.0, 0.0], [1.0, 1.0, 1.0], "shape"),
    ([0.0, np.nan, 0.0], None, r"lower\[1\] is NaN"),
])
def test_malformed_box_raises_box_error(lower, upper, match):
    with pytest.raises(BoxError, match=match):
        cascaded_qp([(np.eye(3), np.ones(3))], lower=lower, upper=upper)


def test_mismatched_shapes_raise_shape_error():
    with pytest.raises(ShapeError):
        cascaded_qp([(np.eye(3), np.ones(3)), (np.ones((2, 4)), np.ones(2))])
    with pytest.raises(ShapeError):
        cascaded_qp([(np.eye(3), np.ones(2))])
    with pytest.raises(ShapeError):
        cascaded_qp([(np.eye(3), np.ones(3))], x0=np.ones(4))


def test_backend_without_solution_raises_solver_failed(monkeypatch):
    def no_solution(problem, solver, **options):
        return qpsolvers.Solution(problem)  # found is None: no solution

    monkeypatch.setattr(qpsolvers, "solve_problem", no_solution)
    met = Level(np.eye(3)[:1], lower=-1.0, upper=1.0)  # met at x = 0: needs no QP
    with pytest.raises(SolverFailedError, match=r"level 1.*'daqp'"):
        cascaded_qp([met, (np.eye(3)[1:], [1.0, 2.0])], "daqp", fallback=())


@pytest.mark.parametrize("backend", ["proxqp", "daqp", "quadprog"])
def test_damped_cascade_equals_damped_tpm(backend):
    """With the damping law applied to each level's free part, the cascade is the damped recursion (= TPM)."""
    rng = np.random.default_rng(11)
    damping = {"lambda_max": 0.05, "eps": 0.1}
    for _ in range(30):
        n = 12
        J1, J2 = rng.standard_normal((3, n)), rng.standard_normal((2, n))
        near = np.vstack([J1[1] + 1e-3 * rng.standard_normal(n), rng.standard_normal(n)])
        dep = np.vstack([J1[0] + J2[1], rng.standard_normal(n)])
        levels = [(J, 10 * rng.standard_normal(J.shape[0])) for J in (J1, J2, near, dep, J2.copy())]
        x0 = rng.standard_normal(n)
        x = cascaded_qp(levels, solver=backend, x0=x0, **damping)
        assert np.abs(x - tpm(levels, x0=x0, **damping)).max() < 1e-8


def test_romeo_level_that_needs_many_proxqp_iterations():
    """A real Romeo stack (romeo_sns_tpm solved by the cascade, step 3221, one BLAS thread) whose
    third level takes ProxQP about 1,300 iterations: it must be solved by ProxQP itself, and agree with DAQP.

    Damped and boxed, the cascade is defined only up to where each level leaves the directions its objective
    does not see (any point of them is optimal for the level; the damped levels below start from it): the
    backends' commands differ by ~1e-5 here while every level's residual agrees to 1e-6 relative.
    """
    data = np.load(Path(__file__).parent / "data" / "romeo_step3221_levels.npz")
    levels = [Level(data[f"J{i}"], data[f"b{i}"], name=str(data[f"name{i}"])) for i in range(5)]
    kw = {"lower": data["lower"], "upper": data["upper"], "lambda_max": float(data["lambda_max"]),
          "eps": float(data["eps"])}
    x, info = cascaded_qp(levels, "proxqp", return_info=True, **kw)
    assert ((x >= kw["lower"]) & (x <= kw["upper"])).all() and info.fallbacks == ()
    xd, info_d = cascaded_qp(levels, "daqp", return_info=True, **kw)
    np.testing.assert_allclose(info.residuals, info_d.residuals, rtol=1e-6, atol=1e-9)
    assert np.abs(x - xd).max() < 1e-4

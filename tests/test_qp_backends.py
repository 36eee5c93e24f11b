"""QP backends on the suite's boxed draws in any units, their time limits and the automatic fallback.

The measurement behind these (failure and disagreement rates, CPU time per level on thousands of draws):
``benchmarks/qp_backends.py``. Here a fixed seeded set: the SNS draws of
:func:`~hqp_tpm.testing.stacks.random_problem` (box containing 0, infinite sides, locked joints, conflicting
and inequality levels), as drawn and in other units.
"""

import numpy as np
import pytest
import qpsolvers
from conftest import rel_diff

from hqp_tpm.errors import SolverBudgetError, SolverFailedError
from hqp_tpm.solvers import Level
from hqp_tpm.solvers.cascaded_qp import cascaded_qp
from hqp_tpm.testing.stacks import random_problem

BACKENDS = [s for s in ("proxqp", "daqp", "quadprog", "osqp") if s in qpsolvers.available_solvers]
EXACT = [s for s in ("proxqp", "daqp", "quadprog") if s in BACKENDS]
#: Agreement between backends on a boxed draw (no analytic reference): active-set / proximal 1e-6, OSQP 1e-5.
RTOL = {"proxqp": 1e-6, "daqp": 1e-6, "quadprog": 1e-6, "osqp": 1e-5}
SCALES = [1e-6, 1e-3, 1e3, 1e6]
DRAWS = 60


def in_units(levels, lo, up, units: str, c: float):
    """``J``: J and b times c (same solution); ``b``: targets, inequality bounds and box times c (solution times c)."""
    fJ = c if units == "J" else 1.0
    out = [Level(fJ * lv.J, lower=c * lv.lower, upper=c * lv.upper) if isinstance(lv, Level)  # inequalities
           else (fJ * lv[0], c * lv[1]) for lv in levels]
    return (out, lo, up) if units == "J" else (out, c * lo, c * up)


def solve(levels, solver, lo, up, damping):
    """The backend alone (no fallback): a typed failure fails the test."""
    x, info = cascaded_qp(levels, solver, lower=lo, upper=up, return_info=True, fallback=(), **damping)
    assert info.fallbacks == ()
    return x


@pytest.mark.parametrize("kind", ["full_rank", "any"])
@pytest.mark.parametrize("units", ["J", "b"])
def test_every_backend_solves_every_level_in_any_units(kind, units):
    """On 60 seeded draws per kind, each in units 1e-6..1e6 (J and b, or targets and box): every backend
    solves every level itself, stays in the box, and agrees with the others and with the draw in its own
    units. Before the QPs were handed to the backends in units of order 1, daqp, proxqp and osqp failed
    (typed) on levels of these draws at 1e6 and 1e-6, proxqp spent seconds on some, and active-set
    backends returned other commands (multipliers that were rounding noise pinned bounds)."""
    for i in range(DRAWS):
        levels, lo, up, damping = random_problem(np.random.default_rng([7, i]), kind)
        c = SCALES[i % len(SCALES)]
        scaled, slo, sup = in_units(levels, lo, up, units, c)
        back = 1.0 if units == "J" else c
        ref = solve(levels, "daqp", lo, up, damping)
        for s in BACKENDS:
            x = solve(scaled, s, slo, sup, damping) / back
            assert (x >= lo - 1e-9 * (1 + np.abs(lo))).all() and (x <= up + 1e-9 * (1 + np.abs(up))).all(), (i, s)
            assert rel_diff(x, ref) < RTOL[s], (i, s, c)


@pytest.mark.parametrize("seed", [3, 4, 10, 11, 14, 16, 20, 21])
def test_daqp_solves_nearly_dependent_boxed_levels(seed):
    """:func:`~hqp_tpm.testing.stacks.nearly_dependent_stack` draws (a row within 1e-11..1e-3 of the rows
    above, cond up to 1e10) with a :func:`~hqp_tpm.testing.stacks.box_for` box, on which DAQP returned no
    solution (17 of seeds 0..39 before, 1 now: seed 34; on 6 others its residuals and quadprog's differ, and
    neither is a reference there): it solves them alone and its residuals equal quadprog's level by level."""
    from hqp_tpm.solvers import tpm
    from hqp_tpm.testing.stacks import box_for, nearly_dependent_stack

    rng = np.random.default_rng([4, seed])
    levels, _ = nearly_dependent_stack(rng, 1e10)
    n = levels[0][0].shape[1]
    lo, up = box_for(rng, tpm(levels), n)
    x, info = cascaded_qp(levels, "daqp", lower=lo, upper=up, return_info=True, fallback=())
    _, info_q = cascaded_qp(levels, "quadprog", lower=lo, upper=up, return_info=True, fallback=())
    assert (x >= lo - 1e-9 * np.abs(lo)).all() and (x <= up + 1e-9 * np.abs(up)).all()
    np.testing.assert_allclose(info.residuals, info_q.residuals, rtol=1e-6, atol=1e-9 * np.abs(up).max())


def test_osqp_and_daqp_get_the_level_time_left_as_their_time_limit(monkeypatch):
    """A backend that can stop itself is told the level's remaining budget, so one call cannot overrun it."""
    seen = []
    solve_problem = qpsolvers.solve_problem

    def spy(problem, solver, **options):
        seen.append((solver, options.get("time_limit")))
        return solve_problem(problem, solver, **options)

    monkeypatch.setattr(qpsolvers, "solve_problem", spy)
    levels, lo, up, _ = random_problem(np.random.default_rng(3), "any")
    for s in ("osqp", "daqp"):
        if s in BACKENDS:
            cascaded_qp(levels, s, lower=lo, upper=up, time_budget=0.5)
    assert seen and all(0.0 < limit <= 0.5 for _, limit in seen), seen


def test_a_backend_over_the_budget_fails_fast_naming_the_level_without_fallback(monkeypatch):
    """The budget covers the fallback backends too: over it, the cascade stops at once, naming the level."""
    import time

    solve_problem = qpsolvers.solve_problem

    def slow_osqp(problem, solver, **options):
        if solver == "osqp":
            t = time.process_time()
            while time.process_time() - t < 0.05:
                pass
            return qpsolvers.Solution(problem)  # no solution, after spending the budget
        return solve_problem(problem, solver, **options)

    monkeypatch.setattr(qpsolvers, "solve_problem", slow_osqp)
    levels = [(np.eye(3)[:1], [1.0]), (np.eye(3)[1:], [1.0, 2.0])]
    with pytest.raises(SolverBudgetError, match=r"level 0: backend 'osqp' spent .* time budget of 0.01 s"):
        cascaded_qp(levels, "osqp", time_budget=0.01)


def test_fallback_solves_the_level_and_says_which_backend_did(monkeypatch):
    """OSQP returning no solution on every level: the default fallback (proxqp first) solves each level, the
    result is the fallback's own, and ``CascadeInfo.fallbacks`` names level and backend; ``fallback=()``
    stops with the typed error naming the level."""
    solve_problem = qpsolvers.solve_problem

    def no_osqp(problem, solver, **options):
        if solver == "osqp":
            return qpsolvers.Solution(problem)
        return solve_problem(problem, solver, **options)

    monkeypatch.setattr(qpsolvers, "solve_problem", no_osqp)
    levels, lo, up, damping = random_problem(np.random.default_rng(11), "any")
    x, info = cascaded_qp(levels, "osqp", lower=lo, upper=up, return_info=True, **damping)
    assert info.solver == "osqp" and info.fallbacks
    assert all(backend == "proxqp" and where.startswith("level ") for where, backend in info.fallbacks)
    np.testing.assert_array_equal(x, cascaded_qp(levels, "proxqp", lower=lo, upper=up, **damping))
    with pytest.raises(SolverFailedError, match=r"level \d+.*backend 'osqp' returned no solution"):
        cascaded_qp(levels, "osqp", lower=lo, upper=up, fallback=(), **damping)
    x, info = cascaded_qp(levels, "osqp", lower=lo, upper=up, return_info=True, fallback=("daqp",), **damping)
    assert {b for _, b in info.fallbacks} == {"daqp"}

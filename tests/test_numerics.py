"""Numerics of the solvers on ill-conditioned and badly scaled stacks (issue: two ways to solve one stack).

* SNS-TPM's fast path, its literal path and an extended-precision run of Algorithm 1 of papers/002
  (``mp_algorithm1``, 50 digits) on stacks with nearly dependent levels, cond(J) up to 1e10;
* the recursive null space (orthonormal basis) meets every level of a full-rank ill-conditioned stack;
* rank decisions relative to the data: a stack and the same stack in other units (J, b scaled by
  1e-11..1e6, or b and the box scaled) give the same answer, scaled.

The number of extended-precision draws is ``HQP_TPM_MP_DRAWS`` (default 100; each costs ~0.2 s).
"""

import os

import mpmath
import numpy as np
import pytest
from conftest import rel_diff
from mp_algorithm1 import rank_tol as mp_rank_tol
from mp_algorithm1 import sns_tpm_mp
from threadpoolctl import threadpool_limits

from hqp_tpm.solvers import Level, cascaded_qp, nullspace, tpm, tpm_reference
from hqp_tpm.solvers.sns import sns, sns_tpm, sns_tpm_reference
from hqp_tpm.testing.stacks import box_for, nearly_dependent_stack

MP_DRAWS = int(os.environ.get("HQP_TPM_MP_DRAWS", "100"))
EPS = np.finfo(float).eps


@pytest.fixture(autouse=True, scope="module")
def _one_blas_thread():
    with threadpool_limits(1):
        yield


def agreement_tol(cond: float) -> float:
    """Relative agreement expected of two backward-stable double solutions: 1e-6, or ``1e3 eps cond``
    above cond = 4.5e9 (the forward error of any double-precision solve grows as ``eps cond``)."""
    return max(1e-6, 1e3 * EPS * cond)


def test_the_reference_restates_the_library_tolerance():
    from hqp_tpm.solvers.damping import rank_tol

    for norm, size in ((1.0, 7), (3e5, 40), (1e-9, 3)):
        assert mp_rank_tol(norm, size) == pytest.approx(rank_tol(norm, size), rel=1e-15)


def mp_min_norm(levels):
    """``J^+ b`` of a full-row-rank stack in 50 digits: what every level of TPM / the recursion must meet."""
    J = np.vstack([J for J, _ in levels])
    b = np.concatenate([b for _, b in levels])
    with mpmath.workdps(50):
        Jm = mpmath.matrix(J.tolist())
        y = mpmath.lu_solve(Jm * Jm.T, mpmath.matrix(b.tolist()))
        return np.array([float(v) for v in Jm.T * y])


# ----------------------------------------------------------------------------------------
# Point 1: SNS-TPM fast path = literal path = extended-precision Algorithm 1, cond(J) <= 1e10.
# ----------------------------------------------------------------------------------------
@pytest.mark.parametrize("chunk", range(4))
def test_sns_tpm_agrees_with_extended_precision_on_nearly_dependent_stacks(chunk):
    rng = np.random.default_rng(1200 + chunk)
    checked = ties = 0
    worst = []
    for _ in range(max(1, MP_DRAWS // 4)):
        levels, cond = nearly_dependent_stack(rng)
        n = levels[0][0].shape[1]
        lo, up = box_for(rng, tpm(levels), n)
        x, info = sns_tpm(levels, lo, up, return_info=True)
        xr, info_r = sns_tpm_reference(levels, lo, up, return_info=True)
        xm, sat, scale, margin = sns_tpm_mp(levels, lo, up)
        if margin < 1e-9:  # a decision of the exact run is within 1e-9 of a tie: either branch is right
            ties += 1
            continue
        checked += 1
        tol = agreement_tol(cond)
        assert info.saturated == info_r.saturated == sat, (cond, info, info_r, sat)
        assert abs(info.scale - scale) <= tol and abs(info_r.scale - scale) <= tol
        assert rel_diff(x, xm) <= tol, (cond, rel_diff(x, xm))
        assert rel_diff(xr, xm) <= tol, (cond, rel_diff(xr, xm))
        worst.append(rel_diff(x, xm) / tol)
    assert checked >= 0.8 * (checked + ties)


# ----------------------------------------------------------------------------------------
# Point 2: the recursion (and TPM) meet every level of a full-rank, ill-conditioned stack.
# ----------------------------------------------------------------------------------------
def test_nullspace_keeps_the_last_level_of_a_nearly_dependent_stack():
    """cond 3e6: the literal projector update lost the last level (residual ~0.1)."""
    rng = np.random.default_rng(7)
    n = 8
    J1 = rng.standard_normal((3, n))
    J2 = rng.standard_normal((2, n))
    J3 = np.vstack([J1[0] + J2[1] + 1e-6 * rng.standard_normal(n), rng.standard_normal(n)])
    levels = [(J1, rng.standard_normal(3)), (J2, rng.standard_normal(2)), (J3, rng.standard_normal(2))]
    J = np.vstack([J for J, _ in levels])
    assert 1e6 < np.linalg.cond(J) < 1e7
    xm = mp_min_norm(levels)
    for x in (nullspace(levels), tpm(levels), tpm_reference(levels)):
        for Ji, bi in levels:
            assert np.linalg.norm(Ji @ x - bi) <= 1e-8 * max(1.0, np.linalg.norm(bi))
        assert rel_diff(x, xm) <= 1e-8


@pytest.mark.parametrize("seed", range(4))
def test_tpm_and_nullspace_meet_ill_conditioned_full_rank_stacks(seed):
    """Every level met and the exact minimum-norm solution reached, by TPM (both paths) and the recursion."""
    rng = np.random.default_rng(300 + seed)
    for _ in range(50):
        levels, cond = nearly_dependent_stack(rng)
        xm = mp_min_norm(levels)
        tol = agreement_tol(cond)
        for name, x in (("nullspace", nullspace(levels)), ("tpm", tpm(levels)), ("ref", tpm_reference(levels))):
            assert rel_diff(x, xm) <= tol, (name, cond, rel_diff(x, xm))
            for Ji, bi in levels:  # backward stable: residual at the rounding level of ||J|| ||x||
                assert np.linalg.norm(Ji @ x - bi) <= 1e-10 * (1.0 + np.linalg.norm(Ji) * np.linalg.norm(x)), name


# ----------------------------------------------------------------------------------------
# Point 3: units do not change the answer (rank decisions relative to the data).
# ----------------------------------------------------------------------------------------
def dependent_stack(rng, n=7):
    """Three levels, one row of the third exactly dependent on the first two (a rank loss by construction)."""
    J1 = rng.standard_normal((2, n))
    J2 = rng.standard_normal((2, n))
    J3 = np.vstack([J1[0] - 2.0 * J2[1], rng.standard_normal(n)])
    return [(J1, rng.standard_normal(2)), (J2, rng.standard_normal(2)), (J3, rng.standard_normal(2))]


SCALES = [1e-11, 1e-6, 1e-3, 1e3, 1e5, 1e6]


@pytest.mark.parametrize("seed", range(10))
@pytest.mark.parametrize("c", SCALES)
def test_units_do_not_change_the_analytic_solutions(seed, c):
    """``(c J, c b)`` has the solution of ``(J, b)``; with an exactly dependent row the old absolute 1e-10
    tolerance returned |x| ~ 1e14 at c = 1e5 and x = 0 at c = 1e-11."""
    levels = dependent_stack(np.random.default_rng(seed))
    scaled = [(c * J, c * b) for J, b in levels]
    for solver in (tpm, tpm_reference, nullspace):
        x = solver(levels)
        assert rel_diff(solver(scaled), x) <= 1e-9, solver.__name__
    # and each level may have its own units
    per_level = [(10.0 ** (3 * k) * c * J, 10.0 ** (3 * k) * c * b) for k, (J, b) in enumerate(levels)]
    assert rel_diff(tpm(per_level), tpm(levels)) <= 1e-9
    assert rel_diff(nullspace(per_level), nullspace(levels)) <= 1e-9


@pytest.mark.parametrize("seed", range(10))
@pytest.mark.parametrize("c", SCALES)
def test_units_do_not_change_sns(seed, c):
    """SNS-TPM (both paths) and the multi-task SNS: ``(c J, c b)`` the same command; ``(J, c b)`` under the
    box scaled by ``c`` the command scaled by ``c``."""
    rng = np.random.default_rng(seed)
    levels = dependent_stack(rng)
    n = levels[0][0].shape[1]
    lo, up = box_for(rng, tpm(levels), n)
    ref = {f.__name__: f(levels, lo, up) for f in (sns_tpm, sns_tpm_reference)}
    ref["sns"] = sns(levels, lo, up)[0]
    units_J = [(c * J, c * b) for J, b in levels]
    units_b = [(J, c * b) for J, b in levels]
    for f in (sns_tpm, sns_tpm_reference):
        assert rel_diff(f(units_J, lo, up), ref[f.__name__]) <= 1e-8, f.__name__
        assert rel_diff(f(units_b, c * lo, c * up) / c, ref[f.__name__]) <= 1e-8, f.__name__
    assert rel_diff(sns(units_J, lo, up)[0], ref["sns"]) <= 1e-8
    assert rel_diff(sns(units_b, c * lo, c * up)[0] / c, ref["sns"]) <= 1e-8


@pytest.mark.parametrize("solver", ["proxqp", "daqp", "quadprog"])
@pytest.mark.parametrize("c", [1e-6, 1e-3, 1e3, 1e6])
def test_units_do_not_change_the_cascaded_qp(solver, c):
    """The cascade of ``(c J, c b)``, an exactly dependent row included, is the cascade of ``(J, b)``."""
    levels = dependent_stack(np.random.default_rng(5))
    x = cascaded_qp(levels, solver)
    xs = cascaded_qp([Level(c * J, c * b) for J, b in levels], solver)
    assert np.abs(xs).max() < 1e3 * (1.0 + np.abs(x).max())
    assert rel_diff(xs, x) <= 1e-6
    assert rel_diff(x, tpm(levels)) <= 1e-6


# ----------------------------------------------------------------------------------------
# Point 7: SNS-TPM on stacks with more rows than joints keeps the first level (this library's extension).
# ----------------------------------------------------------------------------------------
def whole_body_like(rng):
    """A hold (2 rows, small target) > a task (3 rows) > a posture on every joint: m = n + 5 > n."""
    n = int(rng.integers(5, 12))
    levels = [(rng.standard_normal((2, n)), 0.1 * rng.standard_normal(2)),
              (rng.standard_normal((3, n)), rng.standard_normal(3)), (np.eye(n), rng.standard_normal(n))]
    c = np.abs(tpm(levels)).max()
    return levels, -rng.uniform(0.1, 1.0, n) * c, rng.uniform(0.1, 1.0, n) * c


@pytest.mark.parametrize("seed", range(3))
def test_sns_tpm_keeps_the_first_level_when_only_lower_ones_cannot_fit(seed):
    """The literal rank test (rank(JW) < m, always true when m > n) stopped at the first saturation with a
    uniform scale: the first level missed by up to 90 % on 300 of 300 draws where the multi-task SNS meets it."""
    rng = np.random.default_rng(700 + seed)
    for _ in range(25):
        levels, lo, up = whole_body_like(rng)
        J1, b1 = levels[0]
        xs = sns(levels, lo, up)[0]
        if np.linalg.norm(J1 @ xs - b1) > 1e-9 * np.linalg.norm(b1):
            continue  # the box does not even allow the first level
        for f in (sns_tpm, sns_tpm_reference):
            x = f(levels, lo, up)
            assert np.all(x >= lo - 1e-9) and np.all(x <= up + 1e-9)
            assert np.linalg.norm(J1 @ x - b1) <= 1e-8 * np.linalg.norm(b1), f.__name__
        x, info = sns_tpm(levels, lo, up, return_info=True)
        xr, info_r = sns_tpm_reference(levels, lo, up, return_info=True)
        assert info.saturated == info_r.saturated and rel_diff(x, xr) < 1e-9


@pytest.mark.parametrize("seed", range(3))
def test_sns_tpm_with_m_at_most_n_is_the_papers_algorithm(seed):
    """Full-row-rank stacks (m <= n): the extension is not used, the result is the extended-precision
    Algorithm 1 of papers/002 (well-conditioned draws; the ill-conditioned ones are point 1's test)."""
    rng = np.random.default_rng(800 + seed)
    for _ in range(10):
        n = int(rng.integers(4, 10))
        sizes = [2, 1, int(rng.integers(1, n - 2))]
        levels = [(rng.standard_normal((k, n)), rng.standard_normal(k)) for k in sizes]
        lo, up = box_for(rng, tpm(levels), n)
        x, info = sns_tpm(levels, lo, up, return_info=True)
        xm, sat, scale, margin = sns_tpm_mp(levels, lo, up)
        if margin < 1e-9:
            continue
        assert info.saturated == sat and abs(info.scale - scale) < 1e-9 and rel_diff(x, xm) < 1e-9

"""TPM (eqs. (7)-(11), (12), (14) of papers/000) against the recursive null space (5)-(6)."""

import warnings

import numpy as np
import pytest
from conftest import random_stack, rel_diff
from hypothesis import given, settings
from hypothesis import strategies as st

from hqp_tpm.errors import MagnitudeError, NonFiniteError, ShapeError
from hqp_tpm.solvers import Level, nullspace, tpm, tpm_factors, tpm_reference
from hqp_tpm.testing.strategies import dependent_stack, full_rank_stacks

DAMPING = {"lambda_max": 0.05, "eps": 0.1}




@settings(max_examples=300, deadline=None)
@given(full_rank_stacks())
def test_tpm_equals_nullspace_full_rank(data):
    levels, rng = data
    x_tpm = tpm(levels)
    assert rel_diff(x_tpm, nullspace(levels)) < 1e-9
    assert rel_diff(x_tpm, tpm_reference(levels)) < 1e-9
    x0 = rng.standard_normal(levels[0][0].shape[1])
    assert rel_diff(tpm(levels, x0=x0), nullspace(levels, x0=x0)) < 1e-9


@settings(max_examples=300, deadline=None)
@given(full_rank_stacks())
def test_full_rank_stack_is_met_exactly_and_F_is_identity(data):
    levels, _ = data
    x = tpm(levels)
    for J, b in levels:
        assert np.allclose(J @ x, b, atol=1e-8 * max(1.0, np.abs(b).max()))
    f = tpm_factors(levels)
    np.testing.assert_allclose(f.F, np.eye(f.F.shape[0]), atol=1e-12)


@pytest.mark.parametrize("seed", range(200))
@pytest.mark.parametrize("damping", [{}, DAMPING], ids=["exact", "damped"])
def test_tpm_equals_nullspace_dependent_and_conflicting(seed, damping):
    levels = dependent_stack(np.random.default_rng(seed))
    x = tpm(levels, **damping)
    assert rel_diff(x, nullspace(levels, **damping)) < 1e-9
    assert rel_diff(x, tpm_reference(levels, **damping)) < 1e-9


@pytest.mark.parametrize("seed", range(100))
def test_singular_task_exact_tpm_equals_nullspace(seed):
    """A task singular by itself (two parallel rows), levels after it: TPM and the recursion agree, damped too (the
    paper-literal ``tpm_reference`` gives the singular level a direction it does not use: not compared here)."""
    levels = dependent_stack(np.random.default_rng(seed), singular_within=True)
    assert rel_diff(tpm(levels), nullspace(levels)) < 1e-9
    assert rel_diff(tpm(levels, **DAMPING), nullspace(levels, **DAMPING)) < 1e-9


@pytest.mark.parametrize("seed", range(50))
def test_more_rows_than_columns(seed):
    """m > n: padded QR; the answer is the lexicographic minimum-norm one, like the recursion."""
    rng = np.random.default_rng(seed)
    levels = random_stack(rng, 5, [3, 2, 3, 2])
    x = tpm(levels)
    assert x.shape == (5,)
    assert rel_diff(x, nullspace(levels)) < 1e-9
    assert rel_diff(x, tpm_reference(levels)) < 1e-9
    # the first two levels fill the 5 joints: both met, the rest cannot move them
    J12 = np.vstack([levels[0][0], levels[1][0]])
    b12 = np.concatenate([levels[0][1], levels[1][1]])
    assert np.allclose(J12 @ x, b12, atol=1e-9)


def test_higher_priority_unaffected_by_conflict():
    rng = np.random.default_rng(3)
    J1 = rng.standard_normal((2, 4))
    levels = [(J1, np.array([1.0, -2.0])), (J1[:1], np.array([5.0]))]  # conflicting lower task
    x = tpm(levels)
    np.testing.assert_allclose(J1 @ x, [1.0, -2.0], atol=1e-12)


def planar_tips(lengths, q, k):
    """Position Jacobian (2 x 6) of the tip of the first k links of a planar arm."""
    phi = np.cumsum(q)
    J = np.zeros((2, len(q)))
    for j in range(k):
        for i in range(k):
            if i >= j:
                J[0, j] -= lengths[i] * np.sin(phi[i])
                J[1, j] += lengths[i] * np.cos(phi[i])
    return J


def test_planar_six_link_random_test_of_the_tpm_paper():
    """reference/romeo_four_tasks.md: 10,000 random planar 6-link arms, three 2-D tip tasks."""
    rng = np.random.default_rng(2016)
    worst = 0.0
    for _ in range(10_000):
        lengths = rng.uniform(0.1, 1.0, 6)
        q = rng.uniform(-np.pi, np.pi, 6)
        levels = [(planar_tips(lengths, q, k), rng.uniform(-100, 100, 2)) for k in (6, 4, 2)]
        worst = max(worst, rel_diff(tpm(levels), nullspace(levels)))
    assert worst < 1e-9


def test_inequality_rows_enter_while_violated():
    J = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    Jc = np.array([[0.0, 0.0, 1.0]])
    eq = (J, np.array([1.0, 2.0]))
    inactive = Level(Jc, lower=[-1.0], upper=[1.0])  # x = 0 satisfies it: left out
    violated = Level(Jc, lower=[0.5])  # x = 0 violates it: target = 0.5
    np.testing.assert_allclose(tpm([eq, inactive]), [1.0, 2.0, 0.0])
    np.testing.assert_allclose(tpm([eq, violated]), [1.0, 2.0, 0.5])
    np.testing.assert_allclose(nullspace([eq, violated]), [1.0, 2.0, 0.5])
    forced = Level(Jc, lower=[-0.25], upper=[3.0], active=[True])  # explicit mask: nearest finite bound
    np.testing.assert_allclose(tpm([eq, forced]), [1.0, 2.0, -0.25])


def test_acceleration_level_nullspace_term_is_invisible_to_tasks():
    """eq. (14): (I - J#J) qdd0 changes no task acceleration, and equals the recursion's P_l qdd0."""
    rng = np.random.default_rng(7)
    levels = random_stack(rng, 7, [3, 1, 1])
    J = np.vstack([lv[0] for lv in levels])
    qd = rng.standard_normal(7)
    qdd0 = -5.0 * qd  # eq. (15) with D = 5 I
    a = tpm(levels, x0=qdd0)
    np.testing.assert_allclose(J @ a, J @ tpm(levels), atol=1e-12)
    assert rel_diff(a, nullspace(levels, x0=qdd0)) < 1e-12
    f = tpm_factors(levels)
    np.testing.assert_allclose(a - tpm(levels), f.nullspace_term(qdd0, J), atol=1e-12)


def test_empty_stack_gives_zero_or_the_nullspace_motion():
    assert np.array_equal(tpm([], n=3), np.zeros(3))
    assert np.array_equal(tpm([], n=3, x0=np.ones(3)), np.ones(3))
    with pytest.raises(ShapeError, match="empty"):
        tpm([])


@pytest.mark.parametrize(
    ("levels", "error", "match"),
    [
        ([(np.ones((2, 3)), np.ones(3))], ShapeError, r"shape \(3,\), expected \(2,\)"),
        ([(np.ones((2, 3)), np.ones(2)), (np.ones((1, 4)), np.ones(1))], ShapeError, "4 columns, expected n = 3"),
        ([(np.array([[1.0, np.nan]]), np.ones(1))], NonFiniteError, "J holds NaN"),
        ([(np.ones((1, 2)), [np.inf])], NonFiniteError, "b holds non-finite"),
        ([np.ones((3, 2))], ShapeError, "must be a Level or a"),
    ],
)
def test_bad_stacks_raise_typed_errors(levels, error, match):
    for solve in (tpm, nullspace, tpm_reference):
        with pytest.raises(error, match=match):
            solve(levels)


@given(st.integers(0, 2**32 - 1))
@settings(max_examples=300, deadline=None)
def test_row_targets_one_row_equals_the_array_rule(seed):
    """The float path of one-row inequality targets makes the same choice as the vectorized rule."""
    from hqp_tpm.solvers.levels import row_targets

    rng = np.random.default_rng(seed)
    vals = np.concatenate([rng.standard_normal(6), [0.0, -0.0, np.inf, -np.inf]])
    lo, up = np.sort(rng.choice(vals, size=2))[:, None]
    one = row_targets(lo, up)
    two = row_targets(np.repeat(lo, 2), np.repeat(up, 2))  # the array path
    assert one.shape == (1,) and np.array_equal(one, two[:1])


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_deferred_levels_checked_once_stacked(bad):
    """``defer_finite`` levels (the tasks' levels) are checked on the stacked rows: a sum of squares first,
    the entries themselves when that sum fails. A NaN or inf is named with its level and entry; rows too large
    for the solvers' norms (a sum of squares above ``MAX_SUMSQ``) are a MagnitudeError naming the level."""
    rng = np.random.default_rng(3)
    J1, J2 = rng.standard_normal((2, 5)), rng.standard_normal((3, 5))
    b1, b2 = rng.standard_normal(2), rng.standard_normal(3)
    for scale in (1.0, 1e150):                                 # solved as the same stack, scaled
        levels = [Level(scale * J1, scale * b1, name="top", defer_finite=True),
                  Level(scale * J2, scale * b2, name="low", defer_finite=True)]
        np.testing.assert_allclose(tpm(levels), tpm([(J1, b1), (J2, b2)]), rtol=1e-10, atol=1e-12)
    for scale in (1e153, 1e160):                               # sums of squares above 1e304, or overflowing
        huge = [Level(J1, b1, name="top", defer_finite=True), Level(scale * J2, b2, name="low", defer_finite=True)]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)        # (numpy's overflow warning at 1e160)
            with pytest.raises(MagnitudeError, match=r"level 'low': J reaches [0-9.]+e\+1[56]\d: its sum of "
                                                     r"squares exceeds 1e\+304"):
                tpm(huge)
            with pytest.raises(MagnitudeError, match="level 'top': b reaches"):
                tpm([Level(J1, scale * b1, name="top"), (J2, b2)])  # (checked when the level is made)
    for lv in (Level(J1, lower=np.full(2, 1e160), name="ineq"),      # an inequality level's active targets
               Level(J1, lower=np.full(2, 1e160), name="ineq", defer_finite=True)):
        with pytest.raises(MagnitudeError, match=r"level 'ineq': b of its active rows \(their bounds\) reaches 1e"):
            tpm([lv, (J2, b2)])
    np.testing.assert_allclose(J1 @ tpm([Level(J1, lower=np.full(2, 1e150), name="ineq"), (J2, b2)]), 1e150,
                               rtol=1e-12)                         # 1e150: solved (the top level exactly)
    many = [Level(np.full((1, 1), 9e151), np.zeros(1), name=str(i), defer_finite=True) for i in range(30_000)]
    with warnings.catch_warnings():                               # every level within bounds, their sum overflows
        warnings.simplefilter("ignore", RuntimeWarning)
        with pytest.raises(MagnitudeError, match=r"the sum of squares of the 30000 stacked levels overflows"):
            tpm(many)
    J2b = J2.copy()
    J2b[2, 4] = bad
    levels = [Level(J1, b1, name="top", defer_finite=True), Level(J2b, b2, name="low", defer_finite=True)]
    with pytest.raises(NonFiniteError, match=r"level 'low': J holds NaN or inf at \[\[2, 4\]\]"):
        tpm(levels)
    b1b = b1.copy()
    b1b[1] = bad
    levels = [Level(J1, b1b, name="top", defer_finite=True), Level(J2, b2, name="low", defer_finite=True)]
    with pytest.raises(NonFiniteError, match="level 'top'"):
        tpm(levels)


def test_sumsq_is_the_sum_of_squares():
    """``levels.sumsq`` (BLAS ``ddot``, the finiteness and magnitude tests' sum): ``a @ a`` of the entries for
    contiguous, strided, 2-D and empty arrays; inf on overflow without numpy's warning; NaN and inf propagate."""
    from hqp_tpm.solvers.levels import sumsq

    rng = np.random.default_rng(4)
    for a in (rng.standard_normal(38), rng.standard_normal((38, 27)), rng.standard_normal(20)[::3],
              rng.standard_normal((6, 9))[:, 2:5], np.zeros(0), np.zeros((0, 4))):
        f = a.ravel()
        assert abs(sumsq(a) - f @ f) <= 1e-14 * max(1.0, f @ f)
    with warnings.catch_warnings():
        warnings.simplefilter("error")                         # no RuntimeWarning
        assert sumsq(np.array([1e200, 1.0])) == np.inf
    assert np.isnan(sumsq(np.array([1.0, np.nan]))) and sumsq(np.array([-np.inf, 0.5])) == np.inf

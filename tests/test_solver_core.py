"""The solver core on the stacks where the paper's TPM as written is not the strict-priority answer.

* A level that is singular by itself, or repeats (or depends on) the levels above, followed by more levels: the
  unpivoted QR of ``J^T`` (eq. (8) of papers/000) gives it a direction it does not use, and the levels below lose
  it. ``tpm`` hands such a stack to the exact recursion (``hqp_tpm.solvers.tpm`` module doc); it must equal the
  lexicographic optimum (the cascaded QP) and the recursion.
* Levels in different units: every rank decision is taken on each level's own scale, so multiplying a level's
  ``(J_i, b_i)`` by any factor in 1e-8 .. 1e8 changes neither TPM's nor SNS-TPM's answer (undamped).
* Input the solvers cannot carry is a typed error, never NaN out or a ZeroDivisionError.

Each family failed on main 0d7b885.
"""

import numpy as np
import pytest
from conftest import rel_diff
from mp_algorithm1 import sns_tpm_mp

from hqp_tpm.errors import MagnitudeError, ParameterError
from hqp_tpm.solvers import cascaded_qp, nullspace, sns, sns_tpm, sns_tpm_reference, tpm

SMALL = [  # (levels, the strict-priority answer)
    ([([[0.0]], [1.0]), ([[1.0]], [1.0])], [1.0]),
    ([([[1.0, 0.0]], [1.0]), ([[1.0, 0.0]], [2.0]), ([[1.0, 1.0]], [0.0])], [1.0, -1.0]),
    ([([[1.0, 0.0, 0.0]], [1.0]), ([[0.0, 0.0, 0.0]], [1.0]), ([[1.0, 1.0, 0.0]], [3.0])], [1.0, 2.0, 0.0]),
]


@pytest.mark.parametrize("case", range(len(SMALL)))
def test_small_singular_and_repeated_stacks_are_exact(case):
    levels, expected = SMALL[case]
    n = len(expected)
    wide = 10.0 * np.ones(n)
    for x in (tpm(levels), nullspace(levels), sns_tpm(levels, -wide, wide), sns_tpm_reference(levels, -wide, wide)):
        np.testing.assert_allclose(x, expected, atol=1e-12)


def singular_then_more(rng, kind):
    """A first level, then a level repeating it with another target (``repeated``), a level with a zero row
    (``zero_row``) or one whose rows are dependent among themselves (``dependent``), then one or two more levels."""
    n = int(rng.integers(3, 9))
    m1 = int(rng.integers(1, n))
    J1 = rng.standard_normal((m1, n))
    levels = [(J1, rng.standard_normal(m1))]
    if kind == "repeated":
        levels.append((J1.copy(), rng.standard_normal(m1)))
    elif kind == "zero_row":
        J2 = rng.standard_normal((2, n))
        J2[int(rng.integers(2))] = 0.0
        levels.append((J2, rng.standard_normal(2)))
    else:
        r = rng.standard_normal((1, n))
        levels.append((np.vstack([r, 2.0 * r]), rng.standard_normal(2)))
    for _ in range(int(rng.integers(1, 3))):
        k = int(rng.integers(1, n + 1))
        levels.append((rng.standard_normal((k, n)), rng.standard_normal(k)))
    return levels


@pytest.mark.parametrize("kind", ["repeated", "zero_row", "dependent"])
def test_tpm_after_a_singular_or_repeated_level_is_the_lexicographic_optimum(kind):
    rng = np.random.default_rng({"repeated": 11, "zero_row": 12, "dependent": 13}[kind])
    for _ in range(60):
        levels = singular_then_more(rng, kind)
        x = tpm(levels)
        assert rel_diff(x, nullspace(levels)) < 1e-9
        x_qp = cascaded_qp(levels, solver="daqp")
        assert rel_diff(x, x_qp) < 1e-6, (levels, x, x_qp)
        damped = {"lambda_max": 0.05, "eps": 0.1}
        assert rel_diff(tpm(levels, **damped), nullspace(levels, **damped)) < 1e-9
        wide = 1e3 * np.ones(x.size)  # no bound reached: SNS-TPM is TPM
        assert rel_diff(sns_tpm(levels, -wide, wide), x) < 1e-9


def per_level_units(rng, levels):
    return [(c * J, c * b) for (J, b), c in zip(levels, 10.0 ** rng.uniform(-8, 8, len(levels)), strict=True)]


@pytest.mark.parametrize("seed", range(4))
def test_levels_in_different_units_do_not_change_tpm_or_sns_tpm(seed):
    """Each level's ``(J_i, b_i)`` times its own factor 10^U(-8, 8): the same commands (undamped). Stacks with a
    saturating box, m <= n (the paper's rank test) and m > n (a posture level last), rank-deficient ones too."""
    rng = np.random.default_rng(100 + seed)
    for _ in range(25):
        n = int(rng.integers(4, 9))
        sizes = [int(k) for k in rng.integers(1, 4, int(rng.integers(2, 5)))]
        levels = [(rng.standard_normal((k, n)), rng.standard_normal(k)) for k in sizes]
        if rng.random() < 0.3:
            levels.append((np.eye(n), rng.standard_normal(n)))
        if rng.random() < 0.3:
            J, b = levels[0]
            levels.insert(1, (J.copy(), b + 1.0))
        x = tpm(levels)
        lo, up = -0.6 * np.abs(x).max() * np.ones(n), 0.5 * np.abs(x).max() * np.ones(n)
        ref = sns_tpm(levels, lo, up)
        for _ in range(3):
            scaled = per_level_units(rng, levels)
            assert rel_diff(tpm(scaled), x) < 1e-8
            assert rel_diff(sns_tpm(scaled, lo, up), ref) < 1e-7
            assert rel_diff(sns_tpm_reference(scaled, lo, up), ref) < 1e-7


def test_levels_in_different_units_against_extended_precision():
    """SNS-TPM on per-level units against Algorithm 1 of papers/002 in 50 digits (m <= n, full-rank stacks whose
    box binds; draws where a decision is a tie at 1e-9 are left out)."""
    rng = np.random.default_rng(7)
    checked = 0
    for _ in range(80):
        n = 7
        levels = [(rng.standard_normal((k, n)), rng.standard_normal(k)) for k in (2, 2, 2)]
        levels = per_level_units(rng, levels)
        x = tpm(levels)
        up = 0.6 * np.abs(x).max() * np.ones(n)
        x_mp, sat, s, margin = sns_tpm_mp(levels, -up, up)
        if margin < 1e-9:
            continue
        x_f, info = sns_tpm(levels, -up, up, return_info=True)
        assert info.saturated == sat
        assert np.linalg.norm(x_f - x_mp) <= 1e-6 * max(1.0, np.linalg.norm(x_mp))
        checked += 1
    assert checked >= 40


@pytest.mark.parametrize("solver", ["tpm", "nullspace", "sns_tpm", "sns", "qp"])
def test_inputs_the_solvers_cannot_carry_are_typed_errors(solver):
    rng = np.random.default_rng(0)
    J = rng.standard_normal((2, 4))
    box = (-np.ones(4), np.ones(4))
    call = {"tpm": lambda lv, **k: tpm(lv, **k), "nullspace": lambda lv, **k: nullspace(lv, **k),
            "sns_tpm": lambda lv, **k: sns_tpm(lv, *box, **k), "sns": lambda lv, **k: sns(lv, *box, **k),
            "qp": lambda lv, **k: cascaded_qp(lv, **k)}[solver]
    with pytest.raises(MagnitudeError, match="level '0'.*scale the level up"):  # all-NaN or ZeroDivisionError before
        call([(1e-300 * J, [1e-300, 2e-300]), (J, [1.0, 2.0])])
    with pytest.raises(ParameterError, match="complex"):                  # the imaginary part was dropped
        call([(J + 1j, [1.0, 2.0])])
    if solver != "qp":
        for bad in (np.nan, -1.0, np.inf):                                 # accepted by sns and sns_tpm before
            with pytest.raises(ParameterError, match="lambda_max"):
                call([(J, [1.0, 2.0])], lambda_max=bad, eps=0.1)
            with pytest.raises(ParameterError, match="eps"):
                call([(J, [1.0, 2.0])], lambda_max=0.05, eps=bad)

"""Random stacks and boxes from a numpy generator: the draws the library's tests and campaigns use.

Each builder consumes ``rng`` in a fixed order, so a seed names a stack. The hypothesis strategies of
:mod:`hqp_tpm.testing.strategies` draw seeds and sizes and call these; ``hqp-tpm campaign``
(:mod:`hqp_tpm.app.sweep`) replays the SNS draws of :func:`random_problem` by seed. Public through
:mod:`hqp_tpm.testing.stacks`; kept here, with the solvers, so that every layer may use them.

=============================  =========================================================================
``random_stack``               independent Gaussian levels with the given row counts
``dependent_stack``            exactly dependent, nearly dependent (1e-3) and repeated (conflicting) tasks,
                               optionally a level singular by itself -- TPM == recursion to 1e-9, exact
                               or damped (tests/test_tpm.py)
``dependent_singular_stack``   a dependent row, a singular level and a repeated task: the cascaded QP
                               == TPM (tests/test_cascaded_qp.py)
``nearly_dependent_stack``     full row rank, a lower level within ``delta`` (1e-11..1e-3) of the levels
                               above, cond(J) up to ``max_cond``
``random_problem``             a stack and a box containing 0 (kinds ``full_rank``, ``any``, ``damped``):
                               the SNS draws (tests/test_sns.py)
``box_without_zero``           the same box with 30 % of the joints shifted so that 0 may leave it
``box_for``                    a box containing 0 that cuts a given command
=============================  =========================================================================
"""

from __future__ import annotations

import numpy as np

from hqp_tpm.solvers.levels import Level

#: The damping the ``damped`` kind of :func:`random_problem` uses.
DAMPING = {"lambda_max": 0.05, "eps": 0.1}


def random_stack(rng, n, sizes, scale=1.0):
    """Independent Gaussian levels ``(J_i, b_i)`` with the given row counts (``b`` times ``scale``)."""
    return [(rng.standard_normal((m, n)), scale * rng.standard_normal(m)) for m in sizes]


def dependent_stack(rng, n=12, singular_within=False):
    """Stacks whose tasks are linearly dependent on higher ones, nearly so, or in conflict.

    ``[J1 (3 rows), J2 (2), Jnear (2), Jdep (2), Jsame (= J2)]``, targets 10 x Gaussian; with
    ``singular_within`` a level of two parallel rows is inserted third. A damped pivot comes before the
    exactly singular ones: after an exactly singular pivot the recursion's projected Jacobian has other
    singular values than the TPM pivot, so a damping law on sigma_min acts differently (README, 'Where
    TPM and the recursion differ'). ``n`` >= 12 keeps the stack within the proven range.
    """
    J1 = rng.standard_normal((3, n))
    J2 = rng.standard_normal((2, n))
    Jdep = np.vstack([J1[0] + J2[1], rng.standard_normal(n)])  # exactly dependent row
    Jnear = np.vstack([J1[1] + 1e-3 * rng.standard_normal(n), rng.standard_normal(n)])  # nearly dependent
    Jsame = J2.copy()  # the same task again with another target: a pure conflict
    levels = [J1, J2, Jnear, Jdep, Jsame]
    if singular_within:
        Js = rng.standard_normal((2, n))
        Js[1] = 2.0 * Js[0]
        levels.insert(2, Js)
    return [(J, 10 * rng.standard_normal(J.shape[0])) for J in levels]


def dependent_singular_stack(rng, n=12):
    """A lower task dependent on a higher one, the same task with another target, a singular task:
    ``[J1 (3), J2 (2), Js (2 parallel rows), Jdep (2), J2 again]``."""
    J1, J2 = rng.standard_normal((3, n)), rng.standard_normal((2, n))
    Jdep = np.vstack([J1[0] + J2[1], rng.standard_normal(n)])
    Js = rng.standard_normal((2, n))
    Js[1] = 2.0 * Js[0]
    return [(J, 10 * rng.standard_normal(J.shape[0])) for J in (J1, J2, Js, Jdep, J2.copy())]


def nearly_dependent_stack(rng, max_cond: float = 1e10):
    """A full-row-rank stack (sum m_i <= n) with the rows of a lower level within ``delta`` of the rows above.

    Level ``k`` (random, below the first) gets rows ``C J_above + delta E`` for its first 1..m_k rows,
    ``delta`` log-uniform in [1e-11, 1e-3]; the draw is redone until cond(J) <= ``max_cond``.
    Returns ``(levels, cond)``.
    """
    while True:
        n = int(rng.integers(3, 13))
        l = int(rng.integers(2, 5))
        sizes = [int(rng.integers(1, 4)) for _ in range(l)]
        while sum(sizes) > n:
            sizes.pop()
        if len(sizes) < 2:
            continue
        Js = [rng.standard_normal((k, n)) for k in sizes]
        k = int(rng.integers(1, len(sizes)))
        above = np.vstack(Js[:k])
        delta = 10.0 ** rng.uniform(-11, -3)
        r = int(rng.integers(1, sizes[k] + 1))
        Js[k][:r] = rng.standard_normal((r, above.shape[0])) @ above + delta * rng.standard_normal((r, n))
        J = np.vstack(Js)
        cond = np.linalg.cond(J)
        if cond <= max_cond:
            levels = [(Ji, rng.standard_normal(Ji.shape[0])) for Ji in Js]
            return levels, float(cond)


def box_for(rng, x, n):
    """A box containing 0 that cuts the unconstrained command ``x`` (``lo < 0 < up``)."""
    c = np.abs(x).max() + 1e-300
    lo = -rng.uniform(0.05, 1.2, n) * c
    up = rng.uniform(0.05, 1.2, n) * c
    return lo, up


def random_problem(rng, kind):
    """A random stack and a box containing 0 (a velocity box of a state inside its limits).

    kinds: ``full_rank`` (sum m_i <= n, cond(J) <= 1e3), ``any`` (may have m > n, repeated/conflicting
    tasks, inequality levels), ``damped`` (any, with the damped TPM pivots). Returns
    ``(levels, lower, upper, damping)``; the box sides are uniform in [0, 1.2] max|x_tpm|, 5 % infinite,
    3 % of the joints locked.
    """
    from hqp_tpm.solvers.tpm import tpm

    n = int(rng.integers(2, 16))
    l = int(rng.integers(1, 5))
    sizes = [int(rng.integers(1, 5)) for _ in range(l)]
    if kind == "full_rank":
        while sum(sizes) > n:
            sizes.pop()
        sizes = sizes or [min(n, 2)]
    scale = float(rng.choice([1e-2, 1.0, 100.0]))
    levels = random_stack(rng, n, sizes, scale=scale)
    for _ in range(20):  # full rank and not nearly singular: cond(J) <= 1e3 (round-off stays ~1e-13 relative)
        if kind != "full_rank" or np.linalg.cond(np.vstack([J for J, _ in levels])) <= 1e3:
            break
        levels = random_stack(rng, n, sizes, scale=scale)
    if kind != "full_rank":
        if rng.random() < 0.3:  # the same task again, another target: a conflict
            J, b = levels[0]
            levels.append((J.copy(), b + rng.standard_normal(b.size)))
        if rng.random() < 0.3:  # an inequality level, some rows active
            m = int(rng.integers(1, 4))
            lo = rng.standard_normal(m)
            levels.insert(int(rng.integers(0, len(levels) + 1)),
                          Level(rng.standard_normal((m, n)), lower=lo, upper=lo + np.abs(rng.standard_normal(m))))
    damping = DAMPING if kind == "damped" else {}
    c = np.abs(tpm(levels, **damping)).max() + 1e-300
    lo = -rng.uniform(0.0, 1.2, n) * c
    up = rng.uniform(0.0, 1.2, n) * c
    lo[rng.random(n) < 0.05] = -np.inf
    up[rng.random(n) < 0.05] = np.inf
    locked = rng.random(n) < 0.03
    lo[locked] = up[locked] = 0.0
    return levels, lo, up, damping


def box_without_zero(rng, lo, up):
    """Shift the box of 30 % of the joints so that some no longer contain 0 (braking, recovery)."""
    n = lo.size
    width = np.nan_to_num(up - lo, posinf=1.0)
    shift = np.where(rng.random(n) < 0.3, rng.uniform(-0.5, 0.5, n) * width, 0.0)
    return lo + shift, up + shift

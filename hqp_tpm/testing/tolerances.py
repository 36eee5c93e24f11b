"""The tolerances :func:`~hqp_tpm.testing.assert_solvers_agree` uses, and the ranges they are guaranteed on.

Two solutions ``x_a`` and ``x_b`` of the same problem agree when

    ``||x_a - x_b||_2 <= atol + rtol * max(||x_a||_2, ||x_b||_2)``

with, by default, ``atol = rtol`` (so the test is ``rel_diff <= rtol`` for commands of norm >= 1, as
in the library's own tests) and ``rtol = max(base(a, b), COND_FACTOR * eps * cond)``: ``base`` is the
accuracy of the less accurate of the two solvers on a well-conditioned stack (:data:`BASE_RTOL`) and
``cond`` the stack's effective condition number (:func:`~hqp_tpm.testing.agreement.conditioning`):
the forward error of any backward-stable double-precision solve grows as ``eps * cond``.

Residual orderings (a boxed QP against SNS-TPM, TPM against a boxed QP) hold level by level up to
``max(ORDER_RTOL, rtol) * (1 + max|J_k|) * (1 + max|x|)`` (the QP's KKT tolerance, scaled); the first
level where the lexicographic optimum is better by more than ``EQUAL_RTOL`` (same scale) decides; box
bounds hold up to ``BOX_RTOL * (1 + |bound|)``.

:data:`GUARANTEES` lists, for each equivalence, the stacks on which the library's own tests prove
it; outside these ranges a failure of the assertion may be a limitation, not a bug.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

EPS = float(np.finfo(float).eps)

#: Relative accuracy of each solver on well-conditioned stacks (the library's property tests).
BASE_RTOL = {"tpm": 1e-9, "nullspace": 1e-9, "sns_tpm": 1e-9, "sns": 1e-9, "sns_tpm_reference": 1e-9,
             "qp:proxqp": 1e-8, "qp:daqp": 1e-8, "qp:quadprog": 1e-8, "qp:osqp": 1e-5}

#: Relative accuracy assumed for a QP backend not listed in :data:`BASE_RTOL`.
OTHER_QP_RTOL = 1e-6

#: Two QP backends on a stack with a binding box (no analytic reference; test_cascaded_qp).
BOXED_QP_RTOL = 1e-6

#: The forward-error growth ``COND_FACTOR * eps * cond`` (1e-6 at cond 4.5e9).
COND_FACTOR = 1e3

#: Residual orderings: the QP's KKT tolerance, relative.
ORDER_RTOL = 1e-7

#: Residual orderings: two residuals closer than this (relative, same scale) are equal, and the next level
#: decides; a difference beyond it in favour of the lexicographic optimum decides the order.
EQUAL_RTOL = 1e-9

#: Box bounds: relative slack.
BOX_RTOL = 1e-9


def base_rtol(solver: str) -> float:
    """Relative accuracy of ``solver`` on a well-conditioned stack."""
    name = "qp:proxqp" if solver == "qp" else solver
    if name in BASE_RTOL:
        return BASE_RTOL[name]
    return OTHER_QP_RTOL


def agreement_rtol(a: str, b: str, cond: float, *, boxed_qp: bool = False) -> float:
    """Default relative tolerance between solvers ``a`` and ``b`` on a stack of effective condition ``cond``."""
    base = max(base_rtol(a), base_rtol(b))
    if boxed_qp:
        base = max(base, BOXED_QP_RTOL)
    cond = float(cond) if np.isfinite(cond) else 1.0 / EPS
    return max(base, COND_FACTOR * EPS * cond)


@dataclass(frozen=True)
class Guarantee:
    """An equivalence and the stacks it is proven on (by the tests named in ``tests``)."""

    relation: str
    rtol: float
    stacks: str
    cond_max: float
    scales: tuple[float, float]
    tests: str


#: What the library's own tests prove (and so what a user may rely on).
GUARANTEES: tuple[Guarantee, ...] = (
    Guarantee("tpm == nullspace (exact and damped)", 1e-9,
              "1-10 levels of 1-6 rows, n <= 40, full row rank; exactly dependent, nearly dependent (1e-3) "
              "and conflicting levels at n = 12; m > n", 1e3, (1e-2, 1e2), "tests/test_tpm.py"),
    Guarantee("tpm == nullspace == the exact minimum-norm solution (50 digits), ill-conditioned",
              COND_FACTOR * EPS * 1e10,
              "nearly dependent levels (rows of a lower level within 1e-11..1e-3 of the span above), n = 3-12, "
              "full row rank; agreement max(1e-6, 1e3 eps cond)", 1e10, (1e-11, 1e6), "tests/test_numerics.py"),
    Guarantee("sns_tpm == sns_tpm_reference == Algorithm 1 in 50 digits, ill-conditioned", COND_FACTOR * EPS * 1e10,
              "the same nearly dependent stacks with a box cutting the TPM solution (ties within 1e-9 left out); "
              "agreement max(1e-6, 1e3 eps cond)", 1e10, (1e-11, 1e6), "tests/test_numerics.py"),
    Guarantee("tpm == nullspace == the lexicographic optimum after a singular or repeated level", 1e-6,
              "a level repeating the one above with another target, a level with a zero row or two dependent "
              "rows, then 1-2 more levels, n = 3-8 (tpm == nullspace to 1e-9, exact and damped; == the cascaded "
              "QP (daqp) to 1e-6); the paper-literal tpm_reference is not the optimum there: it gives the "
              "singular level a direction it does not use", 1e3, (1.0, 1.0), "tests/test_solver_core.py"),
    Guarantee("tpm and sns_tpm unchanged by each level's units (undamped)", 1e-7,
              "each level's (J_i, b_i) times its own factor 10^U(-8, 8); 2-5 levels of 1-3 rows, n = 4-8, "
              "repeated levels, a final posture (m > n), a binding box; sns_tpm against Algorithm 1 in 50 digits "
              "to 1e-6 (m <= n, ties within 1e-9 left out). With damping, lambda_max and eps are in each "
              "level's units", 1e3, (1e-8, 1e8), "tests/test_solver_core.py"),
    Guarantee("cascaded QP == tpm (equality stacks, no box)", 1e-8,
              "1-6 levels of 1-4 rows, n <= 20, full row rank; dependent and conflicting levels "
              "(proxqp, daqp, quadprog; osqp to 1e-5); scaled stacks 1e-6..1e6", 1e3, (1e-6, 1e6),
              "tests/test_cascaded_qp.py, tests/test_numerics.py"),
    Guarantee("qp backends agree with a binding box", BOXED_QP_RTOL,
              "1-4 mixed equality/inequality levels of 1-3 rows, n = 3-14, box in [-1, -0.1] x [0.1, 1] "
              "(not on ill-conditioned stacks: there backends fail or differ)", 1e3, (1.0, 1.0),
              "tests/test_cascaded_qp.py"),
    Guarantee("sns_tpm == tpm when the box contains the tpm solution", 1e-12,
              "random_problem kinds full_rank / any / damped: 1-4 levels of 1-4 rows, n = 2-15, inequality "
              "levels, conflicts", 1e3, (1e-2, 1e2), "tests/test_sns.py"),
    Guarantee("lexicographic residual order: qp <= sns_tpm, sns (binding box)", ORDER_RTOL,
              "the same draws with boxes that bind, contain 0, have infinite and locked joints",
              1e3, (1e-2, 1e2), "tests/test_sns.py"),
)

"""Recursive null-space solution, eqs. (5)-(6) of papers/000 (and (13) at acceleration level).

``x_i = x_{i-1} + (J_i P_{i-1})# (b_i - J_i x_{i-1})``, ``P_i = P_{i-1} - (J_i P_{i-1})# J_i P_{i-1}``
with ``x_0 = 0``, ``P_0 = I``. The pseudo-inverses use the same (optionally damped) law as
the TPM pivots (:mod:`hqp_tpm.solvers.damping`); the projectors use the exact
pseudo-inverse, so ``P_l = I - J^+ J`` and ``x0`` adds ``P_l x0`` (eq. (14)).
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from hqp_tpm.solvers.damping import check_damping, check_x0, pinv
from hqp_tpm.solvers.levels import as_levels, equality_stack


def nullspace(levels: Iterable, *, lambda_max: float = 0.0, eps: float = 0.0,
              x0: np.ndarray | None = None, n: int | None = None) -> np.ndarray:
    """Solve a prioritized stack by recursive null-space projection (eqs. (5)-(6))."""
    lv = as_levels(levels, n)
    n = lv[0].n if lv else n
    lambda_max, eps = check_damping(lambda_max, eps)
    x0 = check_x0(x0, n)
    x = np.zeros(n)
    P = np.eye(n)
    for J, b in equality_stack(lv):
        JP = J @ P
        x = x + pinv(JP, lambda_max, eps) @ (b - J @ x)        # eq. (5)
        P = P - pinv(JP) @ JP                                  # eq. (6)
    if x0 is not None:
        x = x + P @ x0                # eq. (14)
    return x

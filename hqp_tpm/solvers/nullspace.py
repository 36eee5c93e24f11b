"""Recursive null-space solution, eqs. (5)-(6) of papers/000 (and (13) at acceleration level).

``x_i = x_{i-1} + (J_i P_{i-1})# (b_i - J_i x_{i-1})`` with ``x_0 = 0``, ``P_0 = I``, computed on an
orthonormal basis ``Z_{i-1}`` of the null space of the levels above (``P_{i-1} = Z Z^T``):

* ``(J_i P_{i-1})# = Z (J_i Z)#`` (exact for an orthonormal ``Z``), so each step is a pseudo-inverse
  of the small ``m_i x r`` matrix ``J_i Z``, with the same (optionally damped) law as the TPM pivots
  (:mod:`hqp_tpm.solvers.damping`; the singular values of ``J_i Z`` are those of ``J_i P_{i-1}``);
* ``Z_i = Z_{i-1} N_i`` with ``N_i`` an orthonormal basis of the null space of ``J_i Z_{i-1}`` (SVD,
  rank tolerance :func:`hqp_tpm.solvers.damping.rank_tol` relative to ``||J_i||``), so ``P_l = I - J^+ J``
  and ``x0`` adds ``Z_l Z_l^T x0`` (eq. (14)).

This is the reference the TPM fast path is proven against. The literal projector update
``P_i = P_{i-1} - (J_i P_{i-1})# J_i P_{i-1}`` of eq. (6) computes the same projector in exact
arithmetic but is not kept: ``P_i`` drifts from a projector by round-off at every level (``P^2 != P``),
and on nearly dependent stacks the last levels are lost (top-level residuals of 1e-1 where this
recursion and TPM reach 1e-14, at cond(J) = 3e6).
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from hqp_tpm.solvers.damping import check_damping, check_x0, inverted_singular_values, rank_tol
from hqp_tpm.solvers.levels import as_levels, equality_stack


def projected_step(J: np.ndarray, Z: np.ndarray, lambda_max: float, eps: float,
                   tol: float) -> tuple[np.ndarray, np.ndarray]:
    """``(Z (J Z)#, Z N)``: the (damped) ``(J P)#`` with ``P = Z Z^T`` and the next null-space basis.

    ``N`` is an orthonormal basis of the null space of ``J Z`` (singular values at or below ``tol`` count
    as zero). The damping law sees the ``min(m, n)`` singular values of ``J P``: those of ``J Z`` and zeros.
    """
    m = J.shape[0]
    if Z.shape[1] == 0 or m == 0:
        return np.zeros((Z.shape[0], m)), Z
    U, s, Vt = np.linalg.svd(J @ Z, full_matrices=True)
    k = s.size
    pad = np.zeros(max(min(J.shape) - k, 0))
    inv = inverted_singular_values(np.concatenate([s, pad]), lambda_max, eps, tol)[:k]
    G = Z @ ((Vt[:k].T * inv) @ U[:, :k].T)
    return G, Z @ Vt[int((s > tol).sum()):].T


def nullspace(levels: Iterable, *, lambda_max: float = 0.0, eps: float = 0.0,
              x0: np.ndarray | None = None, n: int | None = None) -> np.ndarray:
    """Solve a prioritized stack by recursive null-space projection (eqs. (5)-(6), module doc)."""
    lv = as_levels(levels, n)
    n = lv[0].n if lv else n
    lambda_max, eps = check_damping(lambda_max, eps)
    x0 = check_x0(x0, n)
    pairs = equality_stack(lv)
    size = max(sum(J.shape[0] for J, _ in pairs), n)
    x = np.zeros(n)
    Z = np.eye(n)
    for J, b in pairs:
        G, Z_next = projected_step(J, Z, lambda_max, eps, rank_tol(np.linalg.norm(J), size))
        x = x + G @ (b - J @ x)                               # eq. (5): Z (J Z)# (b - J x)
        Z = Z_next                                            # eq. (6): P = Z Z^T
    if x0 is not None:
        x = x + Z @ (Z.T @ x0)                                # eq. (14)
    return x

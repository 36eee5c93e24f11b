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

from hqp_tpm.solvers import _compiled
from hqp_tpm.solvers.damping import check_damping, check_x0, inverted_singular_values
from hqp_tpm.solvers.levels import as_levels, equality_stack


def projected_step(J: np.ndarray, Z: np.ndarray, lambda_max: float, eps: float,
                   tol: float) -> tuple[np.ndarray, np.ndarray]:
    """``(Z (J Z)#, Z N)``: the (damped) ``(J P)#`` with ``P = Z Z^T`` and the next null-space basis.

    ``N`` is an orthonormal basis of the null space of ``J Z`` (singular values at or below ``tol`` count
    as zero). The damping law sees the ``m`` singular values of TPM's pivot ``R_ii`` (``m x m``): those of
    ``J Z`` and zeros, one for each row beyond the ``Z.shape[1]`` directions left (so a level with more rows
    than the joints left to it is damped as singular, as TPM's padded pivot is).
    """
    m = J.shape[0]
    if Z.shape[1] == 0 or m == 0:
        return np.zeros((Z.shape[0], m)), Z
    U, s, Vt = np.linalg.svd(J @ Z, full_matrices=True)
    k = s.size
    pad = np.zeros(max(m - k, 0))
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
    if not pairs:
        return np.zeros(n) if x0 is None else x0.copy()
    J = np.concatenate([J for J, _ in pairs])
    b = np.concatenate([b for _, b in pairs])
    return nullspace_stacked(J, b, tuple(J.shape[0] for J, _ in pairs), n, lambda_max, eps, x0)


def nullspace_stacked(J: np.ndarray, b: np.ndarray, sizes, n: int, lambda_max: float = 0.0, eps: float = 0.0,
                      x0: np.ndarray | None = None) -> np.ndarray:
    """:func:`nullspace` of a stack already stacked and checked (``J`` m x n, ``b``, ``sizes`` the levels' row
    counts, damping and ``x0`` valid): eqs. (5)-(6) on the orthonormal bases ``Z``, then (14), by the one kernel
    :func:`hqp_tpm.solvers._compiled.recursion` (compiled when numba is on; the same steps as
    :func:`projected_step`)."""
    return _compiled.recursion(J, b, tuple(sizes), n, lambda_max, eps, x0)

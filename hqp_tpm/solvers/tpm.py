"""Task Priority Matrix (TPM): ``x = J# F b`` (eqs. (7)-(11) of papers/000).

* :func:`tpm_reference` follows the paper literally: QR of ``J^T`` (8), ``Fbar = R`` (9),
  Steps 2-4 block by block with the pivot pseudo-inverses, ``F = Fbar^T`` (10) and
  ``J# = Q pinv(R^T)`` (11); :func:`tpm_factors` returns its ``Q``, ``R``, ``F`` and ``J#`` for inspection.
* :func:`tpm` / :func:`tpm_stacked` make one call (:func:`hqp_tpm.solvers._compiled._tpm`, Python calling the
  kernels, each compiled when numba is on and a stack first takes it): the factorization's kernels (``m <= n``:
  the Householder QR of ``J^T``, each pivot certified regular or decided and damped by the SVD of its block,
  ``x = Q R^{-T} F b``; ``m > n`` with rank ``n`` reached before the last level: the shortcut of
  :mod:`hqp_tpm.solvers._fullrank`, damped pivots factorized) and, on a stack they do not take, the recursion.
  ``HQP_TPM_COMPILED=0``: the same source as Python.

**Exact on every stack.** Steps 2-4 on the pivots are a forward substitution: with every pivot invertible
(regular, or damped with ``sigma_min > tol``), ``x = Q R^{-T} F b = Q y`` with ``y_i = D_i^T (b_i - sum_{j<i}
R_ji^T y_j)``, ``D_i`` the (damped) inverse of ``R_ii``; ``Q_i`` spans the directions the levels above leave to
level ``i`` (``J_i Q_i = R_ii^T``), so this is the recursion of :mod:`hqp_tpm.solvers.nullspace` on the basis ``Q``.
A *singular* pivot (level ``i`` loses rank in what the levels above leave: a zero row, a level repeating or
depending on the ones above, more rows than joints left) breaks this: the unpivoted QR of eq. (8) hands the
level ``m_i`` directions although it uses fewer, and the levels below lose the others (``[0] x = 1`` then
``[1] x = 1`` gives ``x = 0``, the strict-priority answer is 1). The paper's algorithm as written
(:func:`tpm_reference`) keeps that limit; :func:`tpm` hands such a stack to the recursion
(:func:`hqp_tpm.solvers._compiled._recursion`), whose per-level SVD keeps only the directions the level
uses and returns the rest to the levels below: the lexicographic minimum-norm solution undamped, and the same
damping law as the pivots (``m_i`` singular values, zeros for the directions missing) when damped. Rank
decisions are relative to each level's own rows (:mod:`hqp_tpm.solvers.damping`), so a level's units do not
change them.

At acceleration level the same call gives ``qdd = J# F (pdd - Jdot qd)`` (12); pass
``x0 = qdd_0`` to add the null-space term ``(I - J# J) qdd_0`` of (14).

If the stack has more rows than columns (``m > n``) the reference pads the Jacobian with zero columns up to
``m``: the minimum-norm solution has zeros there and they are dropped. ``tests/test_compiled.py`` and
``tests/test_fullrank.py`` prove the kernels equal to the reference where its pivots are regular,
``tests/test_solver_core.py`` the recursion's answer where they are not.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla

from hqp_tpm.errors import NonFiniteError, ShapeError
from hqp_tpm.solvers import _compiled
from hqp_tpm.solvers.damping import check_damping, pinv, pinv_times, rank_tol
from hqp_tpm.solvers.levels import stacked


@dataclass(frozen=True)
class TPMFactors:
    """The pieces of one TPM solve, for inspection: ``J^T = Q R`` (economic) and ``F``.

    ``sizes`` are the row counts ``m_i`` of the (active) levels, ``n`` the command size.
    ``Jpinv`` is ``J# = Q pinv(R^T)`` restricted to the first ``n`` rows.
    """

    Q: np.ndarray
    R: np.ndarray
    F: np.ndarray
    Jpinv: np.ndarray
    sizes: tuple[int, ...]
    n: int

    def solve(self, b: np.ndarray) -> np.ndarray:
        """``J# F b`` for a stacked right-hand side ``b``."""
        return self.Jpinv @ (self.F @ b)

    def nullspace_term(self, x0: np.ndarray, J: np.ndarray) -> np.ndarray:
        """``(I - J# J) x0``: the joint-space term of eq. (14) of papers/000."""
        return x0 - self.Jpinv @ (J @ x0)


def _stack(levels, n):
    _, J, b, sizes, n = stacked(levels, n)
    return J, b, sizes, n


def _qr_of_transpose(J: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Economic QR of ``J^T`` (eq. (8)); ``J`` padded with zero columns when ``m > n``."""
    m, n = J.shape
    JT = J.T if m <= n else np.vstack([J.T, np.zeros((m - n, m))])
    Q, R = sla.qr(JT, mode="economic", check_finite=False)
    return Q, R


def _offsets(sizes):
    return np.concatenate([[0], np.cumsum(sizes)]).astype(int)


# ----------------------------------------------------------------------------------------
# Reference path: the paper's steps, one by one.
# ----------------------------------------------------------------------------------------
def _reference_factors(J, sizes, n, lambda_max, eps):
    """``(Q, R, F)`` of papers/000: the QR of ``J^T`` (8, padded when ``m > n``), ``Fbar = R`` (9), Steps 2-4 with
    the pivot pseudo-inverses (rank tolerance relative to each level's rows), ``F = Fbar^T`` (10)."""
    size = max(J.shape[0], n)                                   # rank tolerances: damping.rank_tol
    Q, R = _qr_of_transpose(J)                                  # eq. (8)
    Fbar = R.copy()                                             # Step 1, eq. (9)
    off = _offsets(sizes)
    for i in range(len(sizes)):                                 # Step 4: for every task
        rows = slice(off[i], off[i + 1])
        Rii = Fbar[rows, rows].copy()
        tol = rank_tol(np.linalg.norm(J[rows]), size)           # relative to the level's rows
        Fbar[rows, :] = pinv(Rii, lambda_max, eps, tol) @ Fbar[rows, :]   # Step 2
        if i > 0:                                                          # Step 3
            above = slice(0, off[i])
            Fbar[above, :] -= Fbar[above, rows] @ Fbar[rows, :]
    return Q, R, Fbar.T                                         # Step 5, eq. (10)


def tpm_reference(levels: Iterable, *, lambda_max: float = 0.0, eps: float = 0.0,
                  x0: np.ndarray | None = None, n: int | None = None) -> np.ndarray:
    """TPM solution computed literally as in papers/000 Sec. II (readable, slow)."""
    J, b, sizes, n = _stack(levels, n)
    if not sizes:
        return np.zeros(n) if x0 is None else np.array(x0, dtype=float)
    m = J.shape[0]
    Q, R, F = _reference_factors(J, sizes, n, lambda_max, eps)
    tol = rank_tol(np.linalg.norm(J), max(m, n))               # relative to the stack
    y = F @ b
    if x0 is not None:                                          # eq. (14): x0 + J# (F b - J x0)
        Jfull = J if m <= n else np.hstack([J, np.zeros((m, m - n))])
        x0p = np.concatenate([np.asarray(x0, float), np.zeros(max(0, m - n))])
        return (x0p + Q @ pinv_times(R.T, y - Jfull @ x0p, tol=tol))[:n]
    return (Q @ pinv_times(R.T, y, tol=tol))[:n]                # eqs. (7) / (12), (11): J# = Q pinv(R^T)


def tpm_factors(levels: Iterable, *, lambda_max: float = 0.0, eps: float = 0.0,
                n: int | None = None) -> TPMFactors:
    """Q, R, F and J# of the stack, as :func:`tpm_reference` computes them (for inspection)."""
    J, _b, sizes, n = _stack(levels, n)
    m = J.shape[0]
    if m == 0:
        return TPMFactors(np.zeros((n, 0)), np.zeros((0, 0)), np.zeros((0, 0)), np.zeros((n, 0)), (), n)
    Q, R, F = _reference_factors(J, sizes, n, lambda_max, eps)
    Jpinv = (Q @ pinv(R.T, tol=rank_tol(np.linalg.norm(J), max(m, n))))[:n]
    return TPMFactors(Q, R, F, Jpinv, tuple(sizes), n)


# ----------------------------------------------------------------------------------------
# The solver: one call (hqp_tpm.solvers._compiled._tpm, calling the kernels).
# ----------------------------------------------------------------------------------------
def tpm(levels: Iterable, *, lambda_max: float = 0.0, eps: float = 0.0,
        x0: np.ndarray | None = None, n: int | None = None) -> np.ndarray:
    """Solve a prioritized stack with the Task Priority Matrix: ``x = J# F b`` (eq. (7)).

    ``levels``: highest priority first, each a ``(J, b)`` pair or a :class:`Level`
    (inequality rows enter while active, see :mod:`hqp_tpm.solvers.levels`).
    ``lambda_max > 0`` with ``eps`` switches on the damped pivot pseudo-inverse.
    ``x0`` adds the null-space term ``(I - J# J) x0`` (eq. (14)).
    ``n`` is required only when ``levels`` is empty.
    """
    J, b, sizes, n = _stack(levels, n)
    lambda_max, eps = check_damping(lambda_max, eps)
    if x0 is not None:
        x0 = np.asarray(x0, dtype=float).reshape(-1)
        if x0.shape != (n,):
            raise ShapeError(f"x0 has {x0.size} entries, expected n = {n}")
        if not np.isfinite(x0).all():
            raise NonFiniteError(f"x0 holds non-finite values: {x0}")
    if not sizes:
        return np.zeros(n) if x0 is None else x0.copy()
    return tpm_stacked(J, b, sizes, n, lambda_max, eps, x0)


def tpm_stacked(J: np.ndarray, b: np.ndarray, sizes, n: int, lambda_max: float = 0.0, eps: float = 0.0,
                x0: np.ndarray | None = None, kernel_status: int | None = None) -> np.ndarray:
    """:func:`tpm` of a stack already stacked and checked: ``J`` (m x n, m >= 1) and ``b`` finite floats,
    ``sizes`` the row counts of the levels, damping and ``x0`` valid. No validation (the compiled step,
    :mod:`hqp_tpm.control._planned_step`, checks once at construction and the arrays once per step).

    One kernel (:func:`hqp_tpm.solvers._compiled.tpm`): the factorization's kernels first (the full-rank shortcut
    when ``m > n``, else ``x = Q R^{-T} F b``), the recursion on a stack they do not take (module doc: the same
    answer where both apply, the exact one where a pivot is singular). ``kernel_status``: what the factorization's
    kernel already answered on these arrays (``DECLINED`` or ``UNDECIDED``, from a caller that ran it fused with
    other work): the recursion runs; ``PIVOT_SVD``: the kernel that decides every pivot by its block's SVD."""
    if kernel_status is None or kernel_status == _compiled.PIVOT_SVD:
        return _compiled.tpm(J, b, sizes, n, lambda_max, eps, x0, pivot_svd=kernel_status is not None)
    return _compiled.recursion(J, b, sizes, n, lambda_max, eps, x0)

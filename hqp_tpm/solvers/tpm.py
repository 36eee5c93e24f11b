"""Task Priority Matrix (TPM): ``x = J# F b`` (eqs. (7)-(11) of papers/000).

Two paths compute the same numbers:

* :func:`tpm_reference` follows the paper literally: QR of ``J^T`` (8), ``Fbar = R`` (9),
  Steps 2-4 block by block with the pivot pseudo-inverses, ``F = Fbar^T`` (10) and
  ``J# = Q pinv(R^T)`` (11).
* :func:`tpm` / :func:`tpm_factors` are the fast path. When every pivot block ``R_ii`` is
  invertible and undamped, Gauss-Jordan elimination turns ``Fbar`` into the identity, so
  ``F = I`` and ``x = Q R^{-T} b`` by one triangular solve; otherwise it runs the same
  elimination on the pivot blocks only. ``tests/test_tpm.py`` proves the two paths equal.

At acceleration level the same call gives ``qdd = J# F (pdd - Jdot qd)`` (12); pass
``x0 = qdd_0`` to add the null-space term ``(I - J# J) qdd_0`` of (14).

If the stack has more rows than columns (``m > n``) the Jacobian is padded with zero
columns up to ``m``: the minimum-norm solution has zeros there and they are dropped.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla
from scipy.linalg import lapack

from hqp_tpm.errors import NonFiniteError, ShapeError
from hqp_tpm.solvers.damping import RANK_TOL, inverted_singular_values, pinv
from hqp_tpm.solvers.levels import as_levels, equality_stack


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
    lv = as_levels(levels, n)
    n = lv[0].n if lv else n
    pairs = equality_stack(lv)
    if not pairs:
        return np.zeros((0, n)), np.zeros(0), (), n
    J = np.vstack([p[0] for p in pairs])
    b = np.concatenate([p[1] for p in pairs])
    return J, b, tuple(p[0].shape[0] for p in pairs), n


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
def tpm_reference(levels: Iterable, *, lambda_max: float = 0.0, eps: float = 0.0,
                  x0: np.ndarray | None = None, n: int | None = None) -> np.ndarray:
    """TPM solution computed literally as in papers/000 Sec. II (readable, slow)."""
    J, b, sizes, n = _stack(levels, n)
    if not sizes:
        return np.zeros(n) if x0 is None else np.array(x0, dtype=float)
    m = J.shape[0]
    Q, R = _qr_of_transpose(J)                                  # eq. (8)
    Fbar = R.copy()                                             # Step 1, eq. (9)
    off = _offsets(sizes)
    for i in range(len(sizes)):                                 # Step 4: for every task
        rows = slice(off[i], off[i + 1])
        Rii = Fbar[rows, rows].copy()
        Fbar[rows, :] = pinv(Rii, lambda_max, eps) @ Fbar[rows, :]   # Step 2
        if i > 0:                                                     # Step 3
            above = slice(0, off[i])
            Fbar[above, :] -= Fbar[above, rows] @ Fbar[rows, :]
    F = Fbar.T                                                  # Step 5, eq. (10)
    Jpinv = Q @ pinv(R.T)                                       # eq. (11), undamped
    x = Jpinv @ (F @ b)                                         # eq. (7) / (12)
    if x0 is not None:                                          # eq. (14)
        Jfull = J if m <= n else np.hstack([J, np.zeros((m, m - n))])
        x0p = np.concatenate([np.asarray(x0, float), np.zeros(max(0, m - n))])
        x = x + x0p - Jpinv @ (Jfull @ x0p)
    return x[:n]


# ----------------------------------------------------------------------------------------
# Fast path.
# ----------------------------------------------------------------------------------------
def tpm_factors(levels: Iterable, *, lambda_max: float = 0.0, eps: float = 0.0,
                n: int | None = None) -> TPMFactors:
    """Q, R, F and J# of the stack (same numbers as :func:`tpm_reference`)."""
    J, _b, sizes, n = _stack(levels, n)
    return _factors(J, sizes, n, lambda_max, eps)


def _factors(J, sizes, n, lambda_max, eps) -> TPMFactors:
    m = J.shape[0]
    if m == 0:
        return TPMFactors(np.zeros((n, 0)), np.zeros((0, 0)), np.zeros((0, 0)), np.zeros((n, 0)), (), n)
    Q, R = _qr_of_transpose(J)
    off = _offsets(sizes)
    # pivot SVDs decide between the identity shortcut and the general elimination
    pivots = []
    regular = True
    for i in range(len(sizes)):
        rows = slice(off[i], off[i + 1])
        U, s, Vt = np.linalg.svd(R[rows, rows])
        pivots.append((U, s, Vt))
        if s[-1] <= RANK_TOL or (lambda_max > 0.0 and s[-1] < eps):
            regular = False
    if regular:
        F = np.eye(m)
        Jpinv = sla.solve_triangular(R, Q.T, check_finite=False).T  # (R^{-1} Q^T)^T = Q R^{-T}
    else:
        Fbar = R.copy()
        for i, (U, s, Vt) in enumerate(pivots):
            rows = slice(off[i], off[i + 1])
            # the pivot block of row i is untouched by earlier steps: its SVD is R_ii's
            Fbar[rows, off[i]:] = ((Vt.T * inverted_singular_values(s, lambda_max, eps)) @ U.T) @ Fbar[rows, off[i]:]
            if i > 0:
                Fbar[: off[i], off[i]:] -= Fbar[: off[i], rows] @ Fbar[rows, off[i]:]
        F = Fbar.T
        Jpinv = Q @ pinv(R.T)
    return TPMFactors(Q, R, F, Jpinv[:n], tuple(sizes), n)


def _pivot_smin(block: np.ndarray) -> float:
    """Smallest singular value of a pivot block (1x1 in closed form)."""
    if block.shape[0] == 1:
        return abs(block[0, 0])
    return np.linalg.svd(block, compute_uv=False)[-1]


def _pivot_inverse(block: np.ndarray, smin: float, lambda_max: float, eps: float) -> np.ndarray:
    """(Damped) pseudo-inverse of a pivot block: triangular inverse when regular, else the SVD law."""
    if block.shape[0] == 1:
        return np.array([[inverted_singular_values(np.array([smin]), lambda_max, eps)[0] * np.sign(block[0, 0])]])
    if smin > RANK_TOL and not (lambda_max > 0.0 and smin < eps):
        return lapack.dtrtri(block, lower=0)[0]  # exact inverse of the upper-triangular pivot
    U, sv, Vt = np.linalg.svd(block)
    return (Vt.T * inverted_singular_values(sv, lambda_max, eps)) @ U.T


def _solve(J: np.ndarray, b: np.ndarray, sizes, n: int, lambda_max: float, eps: float, x0):
    """Fast ``J# F b (+ (I - J#J) x0)``: LAPACK QR, pivots only, triangular solves (no explicit J#)."""
    m = J.shape[0]
    JT = J.T if m <= n else np.vstack([J.T, np.zeros((m - n, m))])
    qr, tau, _, _ = lapack.dgeqrf(JT)
    R = np.triu(qr[:m, :m])
    Q, _, _ = lapack.dorgqr(qr, tau)
    Q = Q[:, :m]
    off = _offsets(sizes)
    blocks = [slice(off[i], off[i + 1]) for i in range(len(sizes))]
    smins = [_pivot_smin(R[r, r]) for r in blocks]
    singular = min(smins) <= RANK_TOL
    regular = [sm > RANK_TOL and not (lambda_max > 0.0 and sm < eps) for sm in smins]
    if all(regular):
        y = b                                                         # Steps 2-4 give F = I
    else:
        Fbar = R.copy()                                               # Step 1
        for i, r in enumerate(blocks):
            D = _pivot_inverse(R[r, r], smins[i], lambda_max, eps)    # R_ii untouched by earlier steps
            Fbar[r, off[i]:] = D @ Fbar[r, off[i]:]                   # Step 2
            if i > 0:
                Fbar[: off[i], off[i]:] -= Fbar[: off[i], r] @ Fbar[r, off[i]:]  # Step 3
        y = Fbar.T @ b                                                # F b, Step 5
    if singular:
        z = pinv(R.T) @ y
    else:
        z, _ = lapack.dtrtrs(R, y, lower=0, trans=1)                  # R^{-T} y
    x = Q @ z                                                         # eq. (11)
    if x0 is not None:
        x0p = x0 if m <= n else np.concatenate([x0, np.zeros(m - n)])
        Jx0 = JT.T @ x0p
        w = pinv(R.T) @ Jx0 if singular else lapack.dtrtrs(R, Jx0, lower=0, trans=1)[0]
        x = x + x0p - Q @ w                                           # eq. (14)
    return x[:n]


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
    if x0 is not None:
        x0 = np.asarray(x0, dtype=float).reshape(-1)
        if x0.shape != (n,):
            raise ShapeError(f"x0 has {x0.size} entries, expected n = {n}")
        if not np.isfinite(x0).all():
            raise NonFiniteError(f"x0 holds non-finite values: {x0}")
    if not sizes:
        return np.zeros(n) if x0 is None else x0.copy()
    return _solve(J, b, sizes, n, lambda_max, eps, x0)

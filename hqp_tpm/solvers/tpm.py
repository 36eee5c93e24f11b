"""Task Priority Matrix (TPM): ``x = J# F b`` (eqs. (7)-(11) of papers/000).

Two paths compute the same numbers:

* :func:`tpm_reference` follows the paper literally: QR of ``J^T`` (8), ``Fbar = R`` (9),
  Steps 2-4 block by block with the pivot pseudo-inverses, ``F = Fbar^T`` (10) and
  ``J# = Q pinv(R^T)`` (11).
* :func:`tpm` / :func:`tpm_factors` are the fast path. When every pivot block ``R_ii`` is
  invertible and undamped, Gauss-Jordan elimination turns ``Fbar`` into the identity, so
  ``F = I`` and ``x = Q R^{-T} b`` by one triangular solve; otherwise it runs the same
  elimination on the pivot blocks only. Whether a pivot is regular is decided on its smallest
  singular value, as in the reference, but a norm bound spares the SVD in most cases. The
  factorization (:class:`_Factorization`) is shared with :func:`hqp_tpm.solvers.sns.sns_tpm`,
  which needs ``x`` and ``F`` of the same stack. ``tests/test_tpm.py`` proves the paths equal.

At acceleration level the same call gives ``qdd = J# F (pdd - Jdot qd)`` (12); pass
``x0 = qdd_0`` to add the null-space term ``(I - J# J) qdd_0`` of (14).

If the stack has more rows than columns (``m > n``) the Jacobian is padded with zero
columns up to ``m``: the minimum-norm solution has zeros there and they are dropped. When such a
stack reaches rank ``n`` before its last level (a final posture level), :func:`tpm` takes the
shortcut of :mod:`hqp_tpm.solvers._fullrank` instead (same numbers, no padding, no SVD of ``R^T``).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla
from scipy.linalg import lapack

from hqp_tpm.errors import NonFiniteError, ShapeError
from hqp_tpm.solvers._fullrank import solve_past_rank
from hqp_tpm.solvers.damping import (
    RANK_TOL,
    check_damping,
    inverted_singular_value,
    inverted_singular_values,
    pinv,
)
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
_UPPER: dict[int, np.ndarray] = {}


def _triu(A: np.ndarray) -> np.ndarray:
    """Upper triangle of a square block (``np.triu`` with a cached mask: several times cheaper)."""
    k = A.shape[0]
    mask = _UPPER.get(k)
    if mask is None:
        mask = _UPPER[k] = np.triu(np.ones((k, k), dtype=bool))
    return A * mask


def _regular(smin: float, lambda_max: float, eps: float) -> bool:
    """A pivot whose smallest singular value is (at least) ``smin`` is inverted exactly: invertible, undamped."""
    return smin > RANK_TOL and not (lambda_max > 0.0 and smin < eps)


def _smin_lower_bound(Rinv: np.ndarray) -> float:
    """``sigma_min(R) >= 1/||R^-1||_F``: a certificate from a triangular inverse, without an SVD."""
    flat = Rinv.ravel("K")
    return 1.0 / np.sqrt(flat @ flat)


def _pivot(block: np.ndarray, lambda_max: float, eps: float):
    """``(D, regular, singular)``: the (damped) pseudo-inverse of an upper-triangular pivot block.

    Regular pivots (:func:`_regular`) get their exact triangular inverse. The decision is the reference
    path's, on ``sigma_min``, but the SVD is needed only when :func:`_smin_lower_bound` cannot decide.
    """
    if block.shape[0] == 1:
        r = block[0, 0]
        smin = abs(r)
        if _regular(smin, lambda_max, eps):
            return np.array([[1.0 / r]]), True, False
        inv = inverted_singular_value(smin, lambda_max, eps)
        return np.array([[inv if r >= 0.0 else -inv]]), False, smin <= RANK_TOL
    R = _triu(block)
    Rinv, info = lapack.dtrtri(R, lower=0)
    if info == 0 and _regular(_smin_lower_bound(Rinv), lambda_max, eps):
        return Rinv, True, False
    U, sv, Vt, _ = lapack.dgesdd(R)
    if _regular(sv[-1], lambda_max, eps):
        return Rinv, True, False
    return (Vt.T * inverted_singular_values(sv, lambda_max, eps)) @ U.T, False, sv[-1] <= RANK_TOL


def _pivots(qr: np.ndarray, off: list[int], lambda_max: float, eps: float) -> list:
    """:func:`_pivot` of every pivot block, the regular ones from one triangular inverse of all of ``R``.

    The diagonal blocks of ``R^{-1}`` are the ``R_ii^{-1}``; a block whose bound proves it regular takes
    its block of ``R^{-1}``, any other block (damped, singular or undecided) goes through :func:`_pivot`.
    With fewer than 3 blocks, or a nearly singular ``R`` (dependent tasks), the whole inverse does not pay.
    """
    m = off[-1]
    Rinv = None
    if len(off) > 3 and np.abs(np.diagonal(qr)[:m]).min() > 1e3 * RANK_TOL:
        Rinv, info = lapack.dtrtri(_triu(qr[:m, :m]), lower=0)
        Rinv = Rinv if info == 0 else None
    out = []
    for a, e in zip(off, off[1:], strict=False):
        if Rinv is not None:
            D = Rinv[a:e, a:e]
            bound = abs(qr[a, a]) if e - a == 1 else _smin_lower_bound(D)  # 1 x 1: sigma_min itself
            if _regular(bound, lambda_max, eps):
                out.append((D, True, False))
                continue
        out.append(_pivot(qr[a:e, a:e], lambda_max, eps))
    return out


class _Factorization:
    """``J^T = Q R`` of a stacked ``J`` (LAPACK, compact form) and the pivot pseudo-inverses.

    ``regular``: every pivot is invertible and undamped, so Steps 2-4 give ``F = I``;
    ``singular``: some pivot (hence ``R``) is singular and ``J# = Q pinv(R^T)`` needs the SVD.
    """

    __slots__ = ("J", "m", "n", "qr", "tau", "off", "pivots", "regular", "singular", "_Fbar", "_Q")

    def __init__(self, J: np.ndarray, sizes, n: int, lambda_max: float, eps: float):
        m = J.shape[0]
        self.J, self.m, self.n = J, m, n
        JT = J.T if m <= n else np.vstack([J.T, np.zeros((m - n, m))])  # zero columns when m > n
        self.qr, self.tau, _, _ = lapack.dgeqrf(JT)                      # eq. (8)
        off = [0]
        for k in sizes:
            off.append(off[-1] + k)
        self.off = off
        self.pivots = _pivots(self.qr, off, lambda_max, eps)
        self.regular = all(p[1] for p in self.pivots)
        self.singular = any(p[2] for p in self.pivots)
        self._Fbar = self._Q = None

    def Fbar(self) -> np.ndarray:
        """Steps 1-4 of papers/000 on the pivot blocks: ``Fbar`` with ``F = Fbar^T`` (10)."""
        if self._Fbar is None:
            off = self.off
            Fbar = _triu(self.qr[: self.m, : self.m])                    # Step 1
            for i, (D, _, _) in enumerate(self.pivots):                  # R_ii untouched by earlier steps
                a, e = off[i], off[i + 1]
                Fbar[a:e, a:] = D @ Fbar[a:e, a:]                        # Step 2
                if i > 0:
                    Fbar[:a, a:] -= Fbar[:a, a:e] @ Fbar[a:e, a:]        # Step 3
            self._Fbar = Fbar
        return self._Fbar

    def F(self) -> np.ndarray:
        return np.eye(self.m) if self.regular else self.Fbar().T

    def F_times(self, b: np.ndarray) -> np.ndarray:
        """``F b`` (``b`` itself when ``F = I``)."""
        return b if self.regular else self.Fbar().T @ b

    def Q(self) -> np.ndarray:
        if self._Q is None:
            self._Q = lapack.dorgqr(self.qr, self.tau)[0][:, : self.m]
        return self._Q

    def R(self) -> np.ndarray:
        return _triu(self.qr[: self.m, : self.m])

    def pinv_times(self, y: np.ndarray) -> np.ndarray:
        """``J# y = Q R^{-T} y`` (eq. (11)), padded rows included when ``m > n``."""
        if self.singular:
            z = pinv(self.R().T) @ y
        else:
            z, _ = lapack.dtrtrs(self.qr[: self.m, : self.m], y, lower=0, trans=1)  # upper triangle read
        return self.Q() @ z

    def pinv_matrix(self) -> np.ndarray:
        """``J#`` (first ``n`` rows)."""
        if self.singular:
            Jp = self.Q() @ pinv(self.R().T)
        else:
            Jp = lapack.dtrtrs(self.qr[: self.m, : self.m], self.Q().T, lower=0)[0].T  # (R^-1 Q^T)^T
        return Jp[: self.n]

    def solve(self, b: np.ndarray, x0: np.ndarray | None = None) -> np.ndarray:
        """``J# F b``, plus ``(I - J# J) x0`` when given (eq. (14)), as ``x0 + J# (F b - J x0)``."""
        y = self.F_times(b)
        if x0 is None:
            return self.pinv_times(y)[: self.n]
        x = self.pinv_times(y - self.J @ x0)
        return x[: self.n] + x0


def tpm_factors(levels: Iterable, *, lambda_max: float = 0.0, eps: float = 0.0,
                n: int | None = None) -> TPMFactors:
    """Q, R, F and J# of the stack (same numbers as :func:`tpm_reference`)."""
    J, _b, sizes, n = _stack(levels, n)
    m = J.shape[0]
    if m == 0:
        return TPMFactors(np.zeros((n, 0)), np.zeros((0, 0)), np.zeros((0, 0)), np.zeros((n, 0)), (), n)
    fac = _Factorization(J, sizes, n, lambda_max, eps)
    return TPMFactors(fac.Q(), fac.R(), fac.F(), fac.pinv_matrix(), tuple(sizes), n)


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
                x0: np.ndarray | None = None) -> np.ndarray:
    """:func:`tpm` of a stack already stacked and checked: ``J`` (m x n, m >= 1) and ``b`` finite floats,
    ``sizes`` the row counts of the levels, damping and ``x0`` valid. No validation (the lean step,
    :mod:`hqp_tpm.control.lean`, checks once at construction and the arrays once per step)."""
    if J.shape[0] > n:  # rank n reached before the last level: hqp_tpm.solvers._fullrank (x0 has no effect)
        x = solve_past_rank(J, b, sizes, n, lambda_max, eps)
        if x is not None:
            return x
    return _Factorization(J, sizes, n, lambda_max, eps).solve(b, x0)

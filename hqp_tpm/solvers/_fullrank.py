"""TPM of a stack that reaches full rank ``n`` before its last level (private to :mod:`hqp_tpm.solvers`).

When the stacked Jacobian has more rows than columns (``m > n``), :func:`hqp_tpm.solvers.tpm.tpm` pads it
with zero columns and goes through singular pivots and an SVD of the padded ``R^T``. That is the common
case of a stack ending with a posture level (6 + 7 rows on the 7-joint arm). Its result is simpler:

* let levels ``1 .. k-1`` (``m1 <= n`` rows) have regular pivots and level ``k`` cross the rank:
  ``m1 < n <= m1 + m_k``; ``J_<k^T = Q1 R1`` (one ``dgeqrf``) and ``Z`` the orthonormal basis of its
  null space, from the same Householder reflectors (``Q = [Q1 Z]``);
* the pivot of level ``k`` in the padded factorization is ``R_kk`` with ``R_kk^T = (J_k Z) W``, ``W``
  with orthonormal rows: its singular values are those of ``A = J_k Z`` (``m_k x r``, ``r = n - m1``)
  and ``m_k - r`` zeros; so its (damped) pseudo-inverse is ``W^T A#`` with the same damping law;
* Steps 2-4 then give ``x = x1 + Z A# (b_k - J_k x1)`` with ``x1 = Q1 R1^{-T} b_<k``: the least-squares
  solution of level ``k`` in the remaining null space;
* when ``A`` has full column rank the stack has rank ``n``: every later level's pivot is zero up to
  rounding (it acts in an empty null space) and its ``b`` does not reach ``x``; ``(I - J# J) x0 = 0``.

:func:`solve_past_rank` returns that ``x``, or ``None`` when it cannot certify the conditions under which
the general path would take the same decisions (a pivot of levels ``< k`` not provably regular and
undamped, ``A`` without a clear full column rank, a smallest singular value of the stack near the rank
tolerance): then the caller takes the general path. ``tests/test_fullrank.py`` checks it against
:func:`hqp_tpm.solvers.tpm.tpm_reference` at 1e-12.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.linalg import lapack

from hqp_tpm.solvers._kernels import triu

try:  # relative rank tolerances (damping.rank_tol), when present; else the absolute RANK_TOL
    from hqp_tpm.solvers.damping import rank_tol as _rank_tol
except ImportError:  # pragma: no cover - depends on the solvers' version
    from hqp_tpm.solvers.damping import RANK_TOL as _ABS_TOL

    def _rank_tol(norm: float, size: int) -> float:
        return _ABS_TOL

#: Decisions are taken here only with this margin over a tolerance (the general path decides the rest).
MARGIN = 16.0
#: The shortcut is taken only for well-conditioned pivots: (lower bound of) ``sigma_min >= COND * ||rows||_F``
#: for the upper levels' pivots, ``A`` and the stack. Nearer to a rank loss two exact formulas differ by
#: ``cond * eps`` in rounding; the general path (the reference's own steps) decides there.
COND = 1e-5


def _fro(A: np.ndarray) -> float:
    flat = A.ravel()
    return math.sqrt(flat @ flat)


def solve_past_rank(J: np.ndarray, b: np.ndarray, sizes, n: int, lambda_max: float, eps: float):
    """``x = J# F b`` of TPM for a stacked ``J`` (``m x n``, ``m > n``) that reaches rank ``n``, or None.

    ``sizes``: the row count of each level, highest priority first. See the module doc.
    """
    m = J.shape[0]
    size = max(m, n)
    m1 = k = 0
    while m1 + sizes[k] < n:                        # level k crosses the rank: m1 < n <= m1 + m_k (m > n)
        m1 += sizes[k]
        k += 1
    mk = sizes[k]
    # levels < k: J_<k^T = Q1 R1, pivots regular (certified by 1/||R_ii^-1||_F <= sigma_min(R_ii))
    if m1:
        qr, tau, _, info = lapack.dgeqrf(J[:m1].T)
        if info:
            return None
        R1 = triu(qr[:m1, :m1])
        R1inv, info = lapack.dtrtri(R1, lower=0)
        if info:
            return None
        a = 0
        for s in sizes[:k]:
            e = a + s
            bound, norm = 1.0 / _fro(R1inv[a:e, a:e]), _fro(J[a:e])
            if bound <= max(MARGIN * _rank_tol(norm, size), COND * norm) or (lambda_max > 0.0 and bound < eps):
                return None
            a = e
        Qfull = np.zeros((n, n))
        Qfull[:, :m1] = qr
        Q = lapack.dorgqr(Qfull, tau)[0]            # [Q1 Z]
        Q1, Z = Q[:, :m1], Q[:, m1:]
        z = lapack.dtrtrs(qr[:m1, :m1], b[:m1], lower=0, trans=1)[0]
        x1 = Q1 @ z
        a_inv = _fro(R1inv)
    else:
        Z = np.eye(n)
        x1 = np.zeros(n)
        a_inv = 0.0
    Jk = J[m1:m1 + mk]
    A = Jk @ Z                                      # m_k x r, r = n - m1 <= m_k
    U, s, Vt, info = lapack.dgesdd(A, full_matrices=0)
    if info:
        return None
    smin, norm_k = s[-1], _fro(Jk)
    if smin <= max(MARGIN * _rank_tol(norm_k, size), COND * norm_k):
        return None                                 # rank n not reached clearly: general path
    # smallest singular value of the stack (its rank-n part): sigma_min >= 1 / ||left inverse||_F
    sinv = 1.0 / s
    p = math.sqrt(sinv @ sinv)
    bound, norm = 1.0 / (a_inv + p * (1.0 + norm_k * a_inv)), _fro(J)
    if bound <= max(MARGIN * _rank_tol(norm, size), COND * norm):
        return None
    smin_pivot = 0.0 if s.size < mk else smin      # R_kk has m_k - r zero singular values
    if lambda_max > 0.0 and smin_pivot < eps:
        inv = s / (s * s + (1.0 - (smin_pivot / eps) ** 2) * lambda_max**2)
    else:
        inv = sinv
    r = b[m1:m1 + mk] - Jk @ x1
    return x1 + Z @ (Vt.T @ (inv * (U.T @ r)))

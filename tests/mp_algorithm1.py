"""Algorithm 1 of papers/002 (SNS-TPM) in extended precision (mpmath, 50 digits): the tests' referee.

Independent of the library's kernels: the TPM matrix ``F`` from an mpmath QR of ``J^T`` and the
pivot pseudo-inverses (Steps 1-4 of papers/000), ``(J W)# = (J W)^T ((J W)(J W)^T)^+`` from a symmetric
eigendecomposition (exact enough at 50 digits for cond(J) up to 1e20), the box tested exactly (no
round-off tolerance). Rank decisions use the library's documented law
(:func:`hqp_tpm.solvers.damping.rank_tol`, restated here: ``100 max(m, n) eps ||A||_F`` with ``A`` the
level's rows for a pivot, ``D J`` for ``rank(J W)``, each level's rows scaled to unit norm).

Besides the command it returns ``margin``: the smallest relative gap met by any decision of the run
(a joint's distance to its bound, the gap between the two most critical joints, a new factor against
``s*``, a singular value against the rank tolerance). A margin below 1e-9 means that the double
precision paths may take the other branch legitimately: a *tie*, which the tests leave out.
"""

from __future__ import annotations

import mpmath
import numpy as np

EPS = float(np.finfo(float).eps)


def rank_tol(norm: float, size: int) -> float:
    return 100.0 * size * EPS * norm


def _mat(A):
    return mpmath.matrix(np.asarray(A, dtype=float).tolist()) if np.size(A) else mpmath.matrix(*np.shape(A))


def _fro(A) -> float:
    return float(np.linalg.norm(A))


class _Run:
    def __init__(self):
        self.margin = np.inf

    def gap(self, a, b, scale=1.0, unit=1.0):
        self.margin = min(self.margin, float(abs(a - b)) / max(unit, float(abs(scale))))

    def sv_gap(self, s, tol):
        # a singular value within a factor 1e3 of the tolerance is a tie (rank decision on round-off)
        if s > 0:
            self.margin = min(self.margin, abs(float(mpmath.log10(s / tol))) * 1e-6 / 3.0)


def _pinv_rows(G, tol, run: _Run):
    """``G# = G^T (G G^T)^+`` and the rank of ``G`` (singular values above ``tol`` count)."""
    m = G.rows
    if m == 0:
        return mpmath.zeros(G.cols, 0), 0
    M = G * G.T
    E, V = mpmath.eigsy(M)
    inv = mpmath.zeros(m, m)
    rank = 0
    for k in range(m):
        s = mpmath.sqrt(max(E[k], 0))
        run.sv_gap(s, tol)
        if s > tol:
            rank += 1
            inv[k, k] = 1 / E[k]
    return G.T * (V * inv * V.T), rank


def _pinv(A, tol, run):
    return _pinv_rows(A, tol, run)[0]


def tpm_F(J: np.ndarray, sizes, run: _Run):
    """The TPM matrix ``F = Fbar^T`` (Steps 1-4 of papers/000, undamped) in extended precision."""
    m, n = J.shape
    size = max(m, n)
    JT = _mat(J.T)
    if m > n:
        JT = _mat(np.vstack([J.T, np.zeros((m - n, m))]))
    _Q, R = mpmath.qr(JT, mode="skinny")
    Fbar = R[:m, :m]
    off = np.concatenate([[0], np.cumsum(sizes)]).astype(int)
    for i in range(len(sizes)):
        a, e = int(off[i]), int(off[i + 1])
        tol = rank_tol(_fro(J[a:e]), size)
        D = _pinv(Fbar[a:e, a:e], tol, run)
        Fbar[a:e, :] = D * Fbar[a:e, :]
        if i > 0:
            Fbar[:a, :] = Fbar[:a, :] - Fbar[:a, a:e] * Fbar[a:e, :]
    return Fbar.T


def sns_tpm_mp(levels, lower, upper, dps: int = 50):
    """Algorithm 1 of papers/002 on equality pairs ``(J_i, b_i)`` in ``dps`` digits.

    Returns ``(x, saturated, scale, margin)`` with ``x`` as floats. Only boxes containing 0.
    """
    with mpmath.workdps(dps):
        Js = [np.atleast_2d(np.asarray(J, float)) for J, _ in levels]
        J = np.vstack(Js)
        xd_np = np.concatenate([np.asarray(b, float) for _, b in levels])
        sizes = [Ji.shape[0] for Ji in Js]
        m, n = J.shape
        run = _Run()
        F = tpm_F(J, sizes, run)
        Jm, xd = _mat(J), _mat(xd_np.reshape(-1, 1))
        lo, up = np.asarray(lower, float), np.asarray(upper, float)
        finite = np.abs(np.concatenate([lo[np.isfinite(lo)], up[np.isfinite(up)]]))
        unit = float(finite.max()) if finite.size and finite.max() > 0 else 1.0   # the box's unit
        # rank(J W) on unit levels: D J W with D = diag(1/||J_i||_F) (hqp_tpm.solvers._kernels.row_weights)
        w = np.concatenate([np.full(k, 1.0 / _fro(Ji) if _fro(Ji) > 0 else 1.0)
                            for k, Ji in zip(sizes, Js, strict=True)])
        D = mpmath.diag(w.tolist()) if m else mpmath.matrix(0, 0)
        tol = rank_tol(np.sqrt(sum(_fro(Ji) > 0 for Ji in Js)), max(m, n))
        W = [1] * n
        xN = mpmath.zeros(n, 1)
        s_star, found = mpmath.mpf(0), False
        W_star, xN_star, order, order_star = list(W), xN.copy(), [], []

        def JWp(Wd):
            G = Jm.copy()
            for j in range(n):
                if not Wd[j]:
                    G[:, j] = mpmath.zeros(m, 1)
            P, rank = _pinv_rows(D * G, tol, run)             # (J W)# = (D J W)# D at full row rank
            P = P * D
            for j in range(n):
                if not Wd[j]:
                    P[j, :] = mpmath.zeros(1, m)
            return P, rank

        P, _ = JWp(W)
        while True:
            x = xN + P * (F * (xd - Jm * xN))
            viol = []
            for j in range(n):
                for bound in (lo[j], up[j]):
                    if W[j] and np.isfinite(bound):
                        run.gap(x[j], bound, bound, unit)
                viol.append(x[j] < lo[j] or x[j] > up[j])
            if not any(viol):
                return np.array([float(v) for v in x]), tuple(order), 1.0, run.margin
            a = P * (F * xd)
            b = x - a
            # getTaskScalingFactor(a, b): largest s in [0, 1] with s a + b in the box on the free joints
            smin_, smax_ = mpmath.mpf(-np.inf), mpmath.mpf(np.inf)
            smax_j = [mpmath.mpf(np.inf)] * n
            feasible = True
            for j in range(n):
                if not W[j]:
                    continue
                if a[j] == 0:
                    feasible = feasible and lo[j] <= b[j] <= up[j]
                    continue
                lo_s, up_s = (lo[j] - b[j]) / a[j], (up[j] - b[j]) / a[j]
                if a[j] < 0:
                    lo_s, up_s = up_s, lo_s
                smax_j[j] = up_s
                smin_, smax_ = max(smin_, lo_s), min(smax_, up_s)
            lo_f = max(smin_, mpmath.mpf(0))
            hi_f = min(smax_, mpmath.mpf(1))
            if mpmath.isfinite(lo_f) and mpmath.isfinite(hi_f):
                run.gap(lo_f, hi_f)
            factor = hi_f if feasible and lo_f <= hi_f else mpmath.mpf(-1)
            if factor >= 0:
                run.gap(factor, s_star)
            if factor > s_star or (factor >= 0 and not found):
                s_star, W_star, xN_star, order_star, found = factor, list(W), xN.copy(), list(order), True
            cand = [j for j in range(n) if W[j] and viol[j]]
            if not cand:
                j = -1
            else:
                order_j = sorted(range(n), key=lambda k: smax_j[k])
                j = order_j[0]
                if len(order_j) > 1 and mpmath.isfinite(smax_j[order_j[1]]):
                    run.gap(smax_j[order_j[0]], smax_j[order_j[1]], smax_j[order_j[0]])
                if not (W[j] and viol[j]):
                    j = min(cand, key=lambda k: smax_j[k])
            rank = m
            if j >= 0:
                W[j] = 0
                xN[j] = up[j] if x[j] > up[j] else lo[j]
                order.append(j)
                P, rank = JWp(W)
            if j < 0 or rank < m:
                if not found:
                    raise ValueError("no scale factor keeps the box (0 outside it): not covered here")
                P, _ = JWp(W_star)
                x = xN_star + P * (F * (s_star * xd - Jm * xN_star))
                return np.array([float(v) for v in x]), tuple(order_star), float(s_star), run.margin

"""Numerical kernels shared by the TPM and SNS-TPM fast paths (private to :mod:`hqp_tpm.solvers`).

Rules kept by every kernel here:

* a triangular factor is only ever *solved* with (LAPACK ``trtrs``), never multiplied by its explicit
  inverse: with ``sigma_min(R) = 2e-8`` a product with ``R^{-1}`` loses ``cond(R) * ||R^{-1}|| ||v|| eps``
  where a solve loses ``cond(R) eps ||R^{-1} v||``, which is far less when ``R^{-1} v`` is small;
  a triangular inverse is formed only as a *certificate* (``sigma_min(R) >= 1/||R^{-1}||_F``) that
  spares an SVD, and its entries never reach a result;
* rank decisions use :func:`hqp_tpm.solvers.damping.rank_tol`, relative to the data (the level's
  rows for a pivot, the stacked ``J`` for the whole stack): see that module.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg as sla
from scipy.linalg import lapack

from hqp_tpm.solvers.damping import inverted_singular_value, inverted_singular_values, rank_tol

_UPPER: dict[int, np.ndarray] = {}


def triu(A: np.ndarray) -> np.ndarray:
    """Upper triangle of a square block (``np.triu`` with a cached mask: several times cheaper)."""
    k = A.shape[0]
    mask = _UPPER.get(k)
    if mask is None:
        mask = _UPPER[k] = np.triu(np.ones((k, k), dtype=bool))
    return A * mask


def smin_lower_bound(Rinv: np.ndarray) -> float:
    """``sigma_min(R) >= 1/||R^-1||_F``: a certificate from a triangular inverse, without an SVD."""
    flat = Rinv.ravel("K")
    return 1.0 / np.sqrt(flat @ flat)


def regular(smin: float, tol: float, lambda_max: float, eps: float) -> bool:
    """A pivot whose smallest singular value is (at least) ``smin`` is inverted exactly: invertible, undamped."""
    return smin > tol and not (lambda_max > 0.0 and smin < eps)


def level_tols(J: np.ndarray, off: list[int], size: int) -> list[float]:
    """:func:`rank_tol` of each level's rows ``J[off[i]:off[i+1]]``."""
    out = []
    for a, e in zip(off, off[1:], strict=False):
        flat = J[a:e].ravel()
        out.append(rank_tol(np.sqrt(flat @ flat), size))
    return out


class Pivot:
    """One pivot block ``R_ii`` of Steps 2-4 of papers/000.

    ``regular``: inverted exactly (applied by a triangular solve with ``R_ii``); otherwise ``D`` is its
    damped or truncated pseudo-inverse (SVD). ``singular``: a singular value is at or below the tolerance.
    """

    __slots__ = ("D", "regular", "singular")

    def __init__(self, D, regular_: bool, singular: bool):
        self.D, self.regular, self.singular = D, regular_, singular


_REGULAR = Pivot(None, True, False)


def pivot(block: np.ndarray, tol: float, lambda_max: float, eps: float, Rinv: np.ndarray | None = None) -> Pivot:
    """The :class:`Pivot` of an upper-triangular block; ``Rinv``: its inverse if already known (certificate)."""
    if block.shape[0] == 1:
        r = block[0, 0]
        smin = abs(r)
        if regular(smin, tol, lambda_max, eps):
            return _REGULAR
        inv = inverted_singular_value(smin, lambda_max, eps, tol)
        return Pivot(np.array([[inv if r >= 0.0 else -inv]]), False, smin <= tol)
    R = triu(block)
    if R[0, 0] == 0.0 and not R.any():  # (a padded stack's zero rows, m > n): singular values 0, D = 0 (the SVD's)
        return Pivot(np.zeros_like(R), False, True)
    if Rinv is None and np.abs(np.diagonal(R)).min() > tol:
        Rinv, info = lapack.dtrtri(R, lower=0)
        Rinv = Rinv if info == 0 else None
    if Rinv is not None and regular(smin_lower_bound(Rinv), tol, lambda_max, eps):
        return _REGULAR
    U, sv, Vt, _ = lapack.dgesdd(R)
    if regular(sv[-1], tol, lambda_max, eps):
        return _REGULAR
    return Pivot((Vt.T * inverted_singular_values(sv, lambda_max, eps, tol)) @ U.T, False, sv[-1] <= tol)


def pivots(qr: np.ndarray, off: list[int], tols: list[float], lambda_max: float, eps: float) -> list[Pivot]:
    """:func:`pivot` of every pivot block; with 3 or more blocks and no small diagonal entry, one triangular
    inverse of all of ``R`` certifies them (its diagonal blocks are the ``R_ii^{-1}``)."""
    m = off[-1]
    Rinv = None
    if len(off) > 3 and np.abs(np.diagonal(qr)[:m]).min() > 1e3 * max(tols):
        Rinv, info = lapack.dtrtri(triu(qr[:m, :m]), lower=0)
        Rinv = Rinv if info == 0 else None
    out = []
    for (a, e), tol in zip(zip(off, off[1:], strict=False), tols, strict=True):
        if Rinv is not None:
            bound = abs(qr[a, a]) if e - a == 1 else smin_lower_bound(Rinv[a:e, a:e])  # 1 x 1: sigma_min itself
            if regular(bound, tol, lambda_max, eps):
                out.append(_REGULAR)
                continue
        out.append(pivot(qr[a:e, a:e], tol, lambda_max, eps))
    return out


class Factorization:
    """``J^T = Q R`` of a stacked ``J`` (LAPACK, compact form) and the pivots of Steps 2-4 of papers/000.

    ``regular``: every pivot is invertible and undamped, so Steps 2-4 give ``F = I``;
    ``singular``: some pivot (hence ``R``) is singular and ``J# = Q pinv(R^T)`` needs the SVD.
    If the stack has more rows than columns (``m > n``) ``J`` is padded with zero columns up to ``m``.
    """

    __slots__ = ("J", "m", "n", "qr", "tau", "off", "pivots", "regular", "singular", "tol", "_Fbar", "_Q", "_svd")

    def __init__(self, J: np.ndarray, sizes, n: int, lambda_max: float, eps: float):
        m = J.shape[0]
        self.J, self.m, self.n = J, m, n
        JT = J.T if m <= n else np.vstack([J.T, np.zeros((m - n, m))])  # zero columns when m > n
        self.qr, self.tau, _, _ = lapack.dgeqrf(JT)                      # eq. (8)
        off = [0]
        for k in sizes:
            off.append(off[-1] + k)
        self.off = off
        size = max(m, n)
        flat = J.ravel()
        self.tol = rank_tol(np.sqrt(flat @ flat), size)                  # whole-stack decisions
        self.pivots = pivots(self.qr, off, level_tols(J, off, size), lambda_max, eps)
        self.regular = all(p.regular for p in self.pivots)
        self.singular = any(p.singular for p in self.pivots)
        self._Fbar = self._Q = self._svd = None

    def Fbar(self) -> np.ndarray:
        """Steps 1-4 of papers/000 on the pivot blocks: ``Fbar`` with ``F = Fbar^T`` (10)."""
        if self._Fbar is None:
            off = self.off
            Fbar = triu(self.qr[: self.m, : self.m])                     # Step 1
            for i, p in enumerate(self.pivots):                          # R_ii untouched by earlier steps
                a, e = off[i], off[i + 1]
                if p.regular:                                            # Step 2: R_ii^{-1} Fbar_i, solved
                    Fbar[a:e, a:] = lapack.dtrtrs(self.qr[a:e, a:e], Fbar[a:e, a:], lower=0)[0]
                else:
                    Fbar[a:e, a:] = p.D @ Fbar[a:e, a:]
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
        return triu(self.qr[: self.m, : self.m])

    def _RT_solve(self, y: np.ndarray) -> np.ndarray:
        """``R^{-T} y`` (triangular solve), or ``pinv(R^T) y`` by the truncated SVD when ``R`` is singular.

        The SVD is taken once per factorization. When ``m > n`` the rows of ``R`` below ``n`` are exactly zero
        (``J^T`` padded with zero rows: every reflector is zero there), so ``R^T = [R_n^T 0]`` and
        ``pinv(R^T) = [pinv(R_n^T); 0]``, with ``R_n`` the first ``n`` rows: the SVD of ``R_n^T`` (``m x n``) has
        the same nonzero singular values as the ``m x m`` one, at a fraction of its cost."""
        m = self.m
        if not self.singular:
            return lapack.dtrtrs(self.qr[:m, :m], y, lower=0, trans=1)[0]  # upper triangle read
        if self._svd is None:
            k = self.n if m > self.n and not self.qr[self.n:].any() else m
            U, s, Vt = np.linalg.svd((self.R() if k == m else np.triu(self.qr[:k, :m])).T, full_matrices=False)
            self._svd = (U, inverted_singular_values(s, tol=self.tol), Vt)
        U, inv, Vt = self._svd
        z = Vt.T @ (inv * (U.T @ y).T).T
        if z.shape[0] == m:
            return z
        out = np.zeros((m,) + y.shape[1:])
        out[: z.shape[0]] = z
        return out

    def pinv_times(self, y: np.ndarray) -> np.ndarray:
        """``J# y = Q R^{-T} y`` (eq. (11)), padded rows included when ``m > n``."""
        return self.Q() @ self._RT_solve(y)

    def pinv_matrix(self) -> np.ndarray:
        """``J#`` (first ``n`` rows), for inspection (the solvers apply it to vectors instead)."""
        return (self.Q() @ self._RT_solve(np.eye(self.m)))[: self.n]

    def solve(self, b: np.ndarray, x0: np.ndarray | None = None) -> np.ndarray:
        """``J# F b``, plus ``(I - J# J) x0`` when given (eq. (14)), as ``x0 + J# (F b - J x0)``."""
        y = self.F_times(b)
        if x0 is None:
            return self.pinv_times(y)[: self.n]
        x = self.pinv_times(y - self.J @ x0)
        return x[: self.n] + x0


def row_weights(J: np.ndarray, sizes) -> tuple[np.ndarray, float]:
    """``(w, tol)``: ``w_r = 1/||J_i||_F`` for the rows ``r`` of each level ``i`` (1 for a zero level) and the rank
    tolerance of the stack ``diag(w) J`` whose levels have unit norm. ``rank(J W) = rank(diag(w) J W)``, and the
    decision on the weighted rows does not depend on each level's units (:mod:`hqp_tpm.solvers.damping`)."""
    w = np.empty(J.shape[0])
    a, unit = 0, 0
    for k in sizes:
        flat = J[a:a + k].ravel()
        nrm = float(np.sqrt(flat @ flat))
        w[a:a + k] = 1.0 / nrm if nrm > 0.0 else 1.0
        unit += nrm > 0.0
        a += k
    return w, rank_tol(np.sqrt(float(unit)), max(J.shape[0], J.shape[1]))


class FreeColumns:
    """``(J W)#`` applied to vectors, ``W`` keeping the ``free`` columns, when ``rank(J W) = m``.

    With ``D = diag(w)`` (:func:`row_weights`), ``(D J W)^T = Q R`` on the free columns gives
    ``(J W)# v = (D J W)# D v = Q R^{-T} D v`` (triangular solve; ``D`` invertible and ``J W`` of full row rank)
    on the free rows, 0 on the others. Build it with :meth:`of`, which returns None on a rank loss.
    """

    __slots__ = ("free", "n", "m", "qr", "tau", "svd", "_Q", "w")

    @classmethod
    def of(cls, J: np.ndarray, free: np.ndarray, tol: float, w: np.ndarray) -> FreeColumns | None:
        """The solver of ``(J W)#``, or None if ``rank(D J W) < m`` (singular values ``<= tol`` count as 0).

        The SVD (the reference's rank test) is taken only when ``1/||R^-1||_F <= sigma_min <= min |r_jj|``
        cannot decide ``sigma_min > tol``.
        """
        m, n = J.shape
        self = cls.__new__(cls)
        self.free, self.n, self.m, self.svd, self._Q, self.w = free, n, m, None, None, w
        if m == 0:
            self.qr = None
            return self
        A = J[:, free] * w[:, None]
        if A.shape[1] < m:
            return None
        self.qr, self.tau, _, _ = lapack.dgeqrf(A.T)
        if np.abs(np.diagonal(self.qr)).min() <= tol:   # sigma_min <= min |r_jj|: a rank loss
            return None
        Rinv, info = lapack.dtrtri(triu(self.qr[:m, :m]), lower=0)
        if info == 0 and smin_lower_bound(Rinv) > tol:   # certificate only: Rinv is not used further
            return self
        U, sv, Vt = sla.svd(A, full_matrices=False, check_finite=False)
        if sv.size < m or sv[-1] <= tol:
            return None
        self.svd = (U, sv, Vt)
        return self

    def times(self, V: np.ndarray) -> np.ndarray:
        """``(J W)# V`` for an ``m x k`` (or ``m``) ``V``: ``n x k`` (or ``n``), zero at the saturated joints."""
        out = np.zeros((self.n,) + V.shape[1:])
        if self.m == 0:
            return out
        V = (self.w * V.T).T
        if self.svd is not None:
            U, sv, Vt = self.svd
            out[self.free] = Vt.T @ ((U.T @ V).T / sv).T
            return out
        Y = lapack.dtrtrs(self.qr[: self.m, : self.m], V, lower=0, trans=1)[0]
        if self._Q is None:
            self._Q = lapack.dorgqr(self.qr, self.tau)[0][:, : self.m]
        out[self.free] = self._Q @ Y
        return out

"""Pseudo-inverses and the rank tolerance shared by every solver of this package.

Rank tolerance (the one place it is defined; every solver decides ranks through :func:`rank_tol`).
A singular value counts as zero when it is at most

    ``rank_tol(||A||_F, size) = RANK_FACTOR * size * eps * ||A||_F``

with ``eps`` the machine epsilon (2.2e-16), ``size = max(m, n)`` of the stacked active rows of the
stack being solved and ``A`` the data the matrix comes from: a level's own rows ``J_i`` for that
level's pivot (TPM, SNS-TPM), its projected Jacobian ``J_i P_{i-1}`` (recursive null space,
multi-task SNS) or the cascaded QP's level, and for a decision on the whole stack (``rank(J W) < m`` of
SNS-TPM) the stack ``D J`` whose levels are scaled to unit norm (:func:`hqp_tpm.solvers._kernels.row_weights`;
``rank(D J W) = rank(J W)``). So the decisions are invariant to the units of each level (scaling
``J_i`` and ``b_i`` by any factor scales the singular values and the tolerance alike),
and a nearly dependent level with ``sigma_min / ||J_i|| >= 1e-10`` (cond(J) up to about 1e10 at
n <= 40) is inverted, not dropped: the rounding noise of an exactly dependent row is a few
``eps ||J_i||``, far below the tolerance, and ``1e-10`` is far above it (``RANK_FACTOR = 100``:
``8.9e-13 ||J_i||`` at ``size = 40``).

Damped law (reference page, 'Solver details'): SVD ``A = U S V^T``; if ``sigma_min >= eps``
the exact inverse is used, else ``lambda^2 = (1 - (sigma_min/eps)^2) lambda_max^2`` and
``sigma_i <- sigma_i / (sigma_i^2 + lambda^2)`` for ``sigma_i > tol``, 0 below.
With ``lambda_max = 0`` the result is the exact pseudo-inverse with singular values
below ``tol`` treated as zero.
"""

from __future__ import annotations

import math

import numpy as np

from hqp_tpm.errors import NonFiniteError, ParameterError, ShapeError

#: Machine epsilon of float64.
EPS = float(np.finfo(float).eps)

#: Safety factor of :func:`rank_tol` over the ``size * eps`` rounding level.
RANK_FACTOR = 100.0


def rank_tol(norm: float, size: int) -> float:
    """Singular values at or below this count as zero: ``RANK_FACTOR * size * eps * norm`` (module doc)."""
    return RANK_FACTOR * max(int(size), 1) * EPS * float(norm)


def matrix_tol(A: np.ndarray, size: int | None = None) -> float:
    """:func:`rank_tol` of ``A`` itself (``size`` defaults to ``max(A.shape)``)."""
    A = np.asarray(A, dtype=float)
    flat = A.ravel()
    return rank_tol(np.sqrt(flat @ flat), max(A.shape, default=1) if size is None else size)


def nonnegative(name: str, v) -> float:
    """``v`` as a float, finite and >= 0, else a :class:`~hqp_tpm.errors.ParameterError` naming ``name``."""
    if isinstance(v, float) and math.isfinite(v) and v >= 0.0:  # the common case, cheaply
        return v
    try:
        f = float(v) if np.ndim(v) == 0 and not isinstance(v, (bool, str)) else math.nan
    except (TypeError, ValueError):
        f = math.nan
    if not (math.isfinite(f) and f >= 0.0):
        raise ParameterError(f"{name} = {v!r} must be a finite number >= 0")
    return f


def check_damping(lambda_max, eps) -> tuple[float, float]:
    """``lambda_max`` and ``eps`` as floats, finite and >= 0 (a NaN or negative value would silently switch
    the damping off)."""
    return nonnegative("lambda_max", lambda_max), nonnegative("eps", eps)


def check_x0(x0, n: int) -> np.ndarray | None:
    """The null-space term ``x0`` as a finite float vector of length ``n`` (None stays None)."""
    if x0 is None:
        return None
    x = np.asarray(x0, dtype=float).reshape(-1)
    if x.shape != (n,):
        raise ShapeError(f"x0 has {x.size} entries, expected n = {n}")
    if not np.isfinite(x).all():
        raise NonFiniteError(f"x0 holds non-finite values: {x}")
    return x


def inverted_singular_values(s: np.ndarray, lambda_max: float = 0.0, eps: float = 0.0,
                             tol: float = 0.0) -> np.ndarray:
    """The diagonal that replaces ``1/sigma_i`` in the (damped) pseudo-inverse (``sigma_i <= tol``: 0)."""
    keep = s > tol
    out = np.zeros_like(s)
    if lambda_max > 0.0 and s.size and s.min() < eps:
        lam2 = (1.0 - (s.min() / eps) ** 2) * lambda_max**2
        out[keep] = s[keep] / (s[keep] ** 2 + lam2)
    else:
        out[keep] = 1.0 / s[keep]
    return out


def pinv(A: np.ndarray, lambda_max: float = 0.0, eps: float = 0.0, tol: float | None = None) -> np.ndarray:
    """Pseudo-inverse of ``A`` (k x p), exact or damped by the law above; shape p x k.

    ``tol``: the rank tolerance; by default :func:`matrix_tol` of ``A`` (relative to ``A`` itself).
    """
    A = np.asarray(A, dtype=float)
    k, p = A.shape
    if k == 0 or p == 0:
        return np.zeros((p, k))
    U, s, Vt = np.linalg.svd(A, full_matrices=False)
    inv = inverted_singular_values(s, lambda_max, eps, matrix_tol(A) if tol is None else tol)
    return (Vt.T * inv) @ U.T


def pinv_times(A: np.ndarray, y: np.ndarray, lambda_max: float = 0.0, eps: float = 0.0,
               tol: float | None = None) -> np.ndarray:
    """``pinv(A, ...) @ y`` without forming the pseudo-inverse (``V (S^+ (U^T y))``)."""
    A = np.asarray(A, dtype=float)
    k, p = A.shape
    if k == 0 or p == 0:
        return np.zeros((p,) + np.shape(y)[1:])
    U, s, Vt = np.linalg.svd(A, full_matrices=False)
    inv = inverted_singular_values(s, lambda_max, eps, matrix_tol(A) if tol is None else tol)
    z = U.T @ y
    z = (inv * z.T).T
    return Vt.T @ z

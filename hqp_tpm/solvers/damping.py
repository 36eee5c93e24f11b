"""Pseudo-inverses: exact (rank-revealing) and the damped law used by the TPM code.

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

#: Singular values at or below this are treated as zero (the reference code's 1e-10).
RANK_TOL = 1e-10


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
                             tol: float = RANK_TOL) -> np.ndarray:
    """The diagonal that replaces ``1/sigma_i`` in the (damped) pseudo-inverse."""
    keep = s > tol
    out = np.zeros_like(s)
    if lambda_max > 0.0 and s.size and s.min() < eps:
        lam2 = (1.0 - (s.min() / eps) ** 2) * lambda_max**2
        out[keep] = s[keep] / (s[keep] ** 2 + lam2)
    else:
        out[keep] = 1.0 / s[keep]
    return out


def inverted_singular_value(s: float, lambda_max: float = 0.0, eps: float = 0.0, tol: float = RANK_TOL) -> float:
    """:func:`inverted_singular_values` of a single singular value (a 1 x 1 block), same arithmetic."""
    if s <= tol:
        return 0.0
    if lambda_max > 0.0 and s < eps:
        return s / (s**2 + (1.0 - (s / eps) ** 2) * lambda_max**2)
    return 1.0 / s


def pinv(A: np.ndarray, lambda_max: float = 0.0, eps: float = 0.0, tol: float = RANK_TOL) -> np.ndarray:
    """Pseudo-inverse of ``A`` (k x p), exact or damped by the law above; shape p x k."""
    A = np.asarray(A, dtype=float)
    k, p = A.shape
    if k == 0 or p == 0:
        return np.zeros((p, k))
    U, s, Vt = np.linalg.svd(A, full_matrices=False)
    inv = inverted_singular_values(s, lambda_max, eps, tol)
    return (Vt.T * inv) @ U.T

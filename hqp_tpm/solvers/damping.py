"""Pseudo-inverses: exact (rank-revealing) and the damped law used by the TPM code.

Damped law (reference page, 'Solver details'): SVD ``A = U S V^T``; if ``sigma_min >= eps``
the exact inverse is used, else ``lambda^2 = (1 - (sigma_min/eps)^2) lambda_max^2`` and
``sigma_i <- sigma_i / (sigma_i^2 + lambda^2)`` for ``sigma_i > tol``, 0 below.
With ``lambda_max = 0`` the result is the exact pseudo-inverse with singular values
below ``tol`` treated as zero.
"""

from __future__ import annotations

import numpy as np

#: Singular values at or below this are treated as zero (the reference code's 1e-10).
RANK_TOL = 1e-10


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

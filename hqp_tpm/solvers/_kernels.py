"""The row weights of SNS-TPM's rank test ``rank(J W) < m`` (private to :mod:`hqp_tpm.solvers`).

Rank decisions use :func:`hqp_tpm.solvers.damping.rank_tol`, relative to the data: for ``rank(J W)`` the stack
``D J W`` whose levels have unit norm, so that a level's units do not move the decision. The kernel
(:func:`hqp_tpm.solvers._compiled_sns._sns_loop`) computes the same weights; ``sns_tpm_reference`` calls this one.
"""

from __future__ import annotations

import numpy as np

from hqp_tpm.solvers.damping import rank_tol


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

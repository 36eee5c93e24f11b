"""Solver names -> array solvers, so controllers and scenarios pick one by name.

``"tpm"`` and ``"nullspace"`` (analytic), ``"sns_tpm"`` and ``"sns"`` (hard joint boxes),
``"qp"`` (cascaded QP with proxqp) or ``"qp:<backend>"`` for any qpsolvers backend.
"""

from __future__ import annotations

import numpy as np

from hqp_tpm.errors import unknown_name

ANALYTIC = ("tpm", "nullspace")
BOXED = ("sns_tpm", "sns")
SOLVER_NAMES = (*ANALYTIC, *BOXED, "qp", "qp:<backend>")


def check_solver_name(name: str) -> str:
    """Validate a solver name (the backend of ``qp:<backend>`` is checked on first use)."""
    if type(name) is str and (name in ANALYTIC or name in BOXED or name == "qp" or name.startswith("qp:")):
        return name
    raise unknown_name("solver", name, SOLVER_NAMES)


def solve(name: str, levels, n: int, *, x0=None, box=None, lambda_max: float = 0.0, eps: float = 0.0):
    """Solve ``levels`` with solver ``name``; returns ``(x, info)`` (info: dict, may be empty).

    ``box = (lower, upper)`` is a hard box on ``x`` used by the SNS solvers and the QP; the
    analytic solvers ignore it. ``x0`` is the joint-space null-space term (eq. (14)).
    """
    check_solver_name(name)
    from hqp_tpm.solvers.damping import check_damping

    lambda_max, eps = check_damping(lambda_max, eps)
    if name == "tpm":
        from hqp_tpm.solvers import tpm

        return tpm(levels, lambda_max=lambda_max, eps=eps, x0=x0, n=n), {}
    if name == "nullspace":
        from hqp_tpm.solvers import nullspace

        return nullspace(levels, lambda_max=lambda_max, eps=eps, x0=x0, n=n), {}
    if name in BOXED:
        from hqp_tpm.solvers.sns import sns, sns_tpm

        lo, up = box if box is not None else (np.full(n, -np.inf), np.full(n, np.inf))
        if x0 is not None:  # the joint-space term must respect the box too: one more (lowest) level
            levels = [*levels, (np.eye(n), np.asarray(x0, dtype=float))]
        if name == "sns_tpm":
            x, info = sns_tpm(levels, lo, up, lambda_max=lambda_max, eps=eps, return_info=True)
            return x, {"scale": info.scale, "saturated": list(info.saturated), "iterations": info.iterations}
        x, scales, info = sns(levels, lo, up, lambda_max=lambda_max, eps=eps, return_info=True)
        saturated = sorted({j for lv in info.levels for j in lv.saturated})
        return x, {"scale": float(min(scales, default=1.0)), "scales": list(scales), "saturated": saturated}
    from hqp_tpm.solvers.cascaded_qp import cascaded_qp

    backend = "proxqp" if name == "qp" else name.split(":", 1)[1]
    lo, up = box if box is not None else (None, None)
    x, info = cascaded_qp(levels, solver=backend, x0=x0, lower=lo, upper=up, n=n, return_info=True,
                          lambda_max=lambda_max, eps=eps)
    return x, info if isinstance(info, dict) else vars(info)

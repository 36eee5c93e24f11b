"""The solve under a command-rate bound (velocity level): the stack solved for the change ``d`` from the previous
command ``v``, ``qdot = v + d`` (the SNS solvers assume a box around 0; the rate box ``v +- a_max T`` mostly excludes
it). The readable step calls :func:`solve_around`, the planned step :func:`shift_rows` (docs/internals.md).
"""

from __future__ import annotations

import numpy as np

from hqp_tpm.robot.limits import JointLimits
from hqp_tpm.solvers.levels import Level, as_levels
from hqp_tpm.solvers.registry import solve


def rate_limited(box) -> bool:
    """Does the box function bound the command's rate (``JointLimits(command_rate=True)``)?"""
    return isinstance(box, JointLimits) and box.command_rate


def shifted(level: Level, v: np.ndarray) -> Level:
    """``level`` seen from ``v``: ``J d = b - J v`` (equality), ``lower - J v <= J d <= upper - J v``."""
    Jv = level.J @ v
    if level.b is not None:
        return Level(level.J, level.b - Jv, name=level.name)
    return Level(level.J, lower=level.lower - Jv, upper=level.upper - Jv, active=level.active, name=level.name)


def shift_rows(J: np.ndarray, b: np.ndarray, v: np.ndarray, out: np.ndarray) -> None:
    """``out = b - J v`` into ``out`` (one matrix-vector product, no temporary): :func:`shifted`'s equality rows."""
    np.dot(J, v, out=out)
    np.subtract(b, out, out=out)


def solve_around(solver: str, levels, n: int, v: np.ndarray, box: tuple[np.ndarray, np.ndarray], *,
                 lambda_max: float, eps: float, solve=solve) -> tuple[np.ndarray, dict]:
    """``(qdot, info)``: ``levels`` solved by ``solver`` for the change from ``v`` (module doc) in ``box``
    (``solve``: the registry's, or the caller's own reference to it)."""
    lo, up = box
    d, info = solve(solver, [shifted(level, v) for level in as_levels(levels, n)], n, x0=-v, box=(lo - v, up - v),
                    lambda_max=lambda_max, eps=eps)
    return np.minimum(np.maximum(v + d, lo), up), info

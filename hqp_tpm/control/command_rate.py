"""The solve under a command-rate bound: the stack solved for the change of the command (velocity level, issue 31).

With ``JointLimits(command_rate=True)`` the box on ``qdot`` is also ``qdot_prev +- a_max T``
(:func:`hqp_tpm.robot.joint_boxes.command_rate_box`), and 0 is then mostly outside it. The SNS solvers assume a
box around 0 (their scale factor ``s`` shrinks the command towards 0; without 0 in the box they solve around the
box point nearest to 0, which moves every task, the top one included: ``hqp_tpm.solvers.sns``). So the stack is
solved around the previous command ``v`` instead: ``qdot = v + d`` with ``d`` the solution of

* every level seen from ``v``: ``J_i d = b_i - J_i v`` (an inequality level's bounds shifted alike),
* one more, lowest level ``d = -v`` (the registry's ``x0`` term: ``qdot = 0`` in what the tasks leave free),
* the box ``[lower - v, upper - v]``, which holds 0 whenever ``v`` is inside the position and velocity box.

Nothing binding (exact pseudo-inverses), ``d = J# (b - J v) - (I - J# J) v`` so ``qdot = J# b``: the usual
solution. A binding box scales the *change* (SNS-TPM: ``J qdot = J v + s (b - J v)``, the free motion
``(1 - s) v``): a task falls behind by a lag, not by a jump of the command. The result is clipped into the box
(``v + (lower - v)`` may round one ulp outside it). :class:`~hqp_tpm.control.controller.Controller` and the compiled
step (:mod:`hqp_tpm.control._planned_step`) both call :func:`solve_around`: one formula, the same numbers.
"""

from __future__ import annotations

import numpy as np

from hqp_tpm.robot.limits import JointLimits
from hqp_tpm.solvers.levels import Level, as_levels
from hqp_tpm.solvers.registry import solve


def rate_limited(box) -> bool:
    """Does the box function bound the command's rate (``JointLimits(command_rate=True)``)? Other box functions
    (plain callables) do not."""
    return isinstance(box, JointLimits) and box.command_rate


def shifted(level: Level, v: np.ndarray) -> Level:
    """``level`` seen from ``v``: ``J d = b - J v`` (equality), ``lower - J v <= J d <= upper - J v``."""
    Jv = level.J @ v
    if level.b is not None:
        return Level(level.J, level.b - Jv, name=level.name)
    return Level(level.J, lower=level.lower - Jv, upper=level.upper - Jv, active=level.active, name=level.name)


def solve_around(solver: str, levels, n: int, v: np.ndarray, box: tuple[np.ndarray, np.ndarray], *,
                 lambda_max: float, eps: float, solve=solve) -> tuple[np.ndarray, dict]:
    """``(qdot, info)``: ``levels`` solved by ``solver`` for the change from ``v`` (module doc) in ``box``
    (``solve``: the registry's, or the caller's own reference to it)."""
    lo, up = box
    d, info = solve(solver, [shifted(level, v) for level in as_levels(levels, n)], n, x0=-v, box=(lo - v, up - v),
                    lambda_max=lambda_max, eps=eps)
    return np.minimum(np.maximum(v + d, lo), up), info

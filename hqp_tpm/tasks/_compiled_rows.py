"""Compiled (numba) row writers of the pointing (19), (21) and 1-D avoidance (29) tasks (private; the planned step),
with the readable tasks' operations in the same order. Details: docs/internals.md#task-rows.
"""

from __future__ import annotations

import math

from hqp_tpm import _jit
from hqp_tpm._jit import kernel as _njit  # the package's one kernel decorator (compiled at the end of this module)
from hqp_tpm.robot.spatial import cross3
from hqp_tpm.tasks.base import tracking_command

_command = _njit(tracking_command, inline=True, into=(__name__, "_command"))  # Task.command's law, compiled here
_cross = _njit(cross3, inline=True, into=(__name__, "_cross"))


@_njit
def pointing_row(J, b, R, z_d, Jf, v, vel, acc, x_d, xd, xdd, kp, kd, order, limit):  # pragma: no cover - compiled
    """The pointing row (19) ``J = (z_e x z_d)^T J_O`` and its command into ``J``, ``b``; returns ``x_d - z_d^T z_e``.
    ``R``, ``Jf``, ``vel``, ``acc``: the frame's rotation, Jacobian, velocity and ``J̇ q̇``; ``limit``: drift_limit."""
    z0, z1, z2 = R[0, 2], R[1, 2], R[2, 2]
    c0, c1, c2 = _cross((z0, z1, z2), (z_d[0], z_d[1], z_d[2]))
    n = J.shape[1]
    for c in range(n):
        J[0, c] = c0 * Jf[3, c] + c1 * Jf[4, c] + c2 * Jf[5, c]
    e = x_d[0] - (z_d[0] * z0 + z_d[1] * z1 + z_d[2] * z2)
    if order == 1:
        b[0] = _command(1, e, xd[0], 0.0, 0.0, 0.0, kp, kd)
        return e
    rate = 0.0
    for c in range(n):
        rate += J[0, c] * v[c]
    a0, a1, a2 = _cross((acc[3], acc[4], acc[5]), (z0, z1, z2))
    u0, u1, u2 = _cross((vel[3], vel[4], vel[5]), (z0, z1, z2))
    w0, w1, w2 = _cross((vel[3], vel[4], vel[5]), (u0, u1, u2))
    jdq = z_d[0] * (a0 + w0) + z_d[1] * (a1 + w1) + z_d[2] * (a2 + w2)
    b[0] = _command(2, e, xd[0], xdd[0], rate, jdq, kp, kd)
    if limit < math.inf:
        s = 0.0
        for c in range(n):
            s += J[0, c] * J[0, c]
        if jdq * jdq > limit * limit * s:
            b[0] = b[0] + jdq
    return e


@_njit
def avoidance_row(J, b, normal, Jc, jdq, magnitude, order):  # pragma: no cover - compiled
    """The 1-D avoidance row (29): ``J = n^T J_c``, ``b = r`` (order 1) or ``r - n^T J̇_c q̇`` (order 2)."""
    for c in range(J.shape[1]):
        J[0, c] = normal[0] * Jc[0, c] + normal[1] * Jc[1, c] + normal[2] * Jc[2, c]
    r = magnitude * 1.0
    if order == 1:
        b[0] = r
    else:
        b[0] = r - (normal[0] * jdq[0] + normal[1] * jdq[1] + normal[2] * jdq[2])


_jit.compile_when_enabled(globals())  # numba's dispatchers (each compiled on its first call) while the switch is on

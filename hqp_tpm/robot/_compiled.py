"""Compiled (numba) kernels of the robot layer (private), with the readable code's (or pinocchio's) operations in the
same order: the same bits, except :func:`log3` and :func:`frame_jdot_qdot` (~1e-15). Switched by
:data:`hqp_tpm._jit.ENABLED` (off: they run as Python). Details: docs/internals.md#robot-kernels."""

from __future__ import annotations

import math

import numpy as np

from hqp_tpm import _jit
from hqp_tpm._jit import kernel as _njit  # the package's one kernel decorator (compiled at the end of this module)
from hqp_tpm.robot.spatial import cross3

_cross = _njit(cross3, inline=True, into=(__name__, "_cross"))


@_njit(inline=True)
def _add(a, b):  # pragma: no cover - compiled
    """``a + b`` of two 3-tuples."""
    return a[0] + b[0], a[1] + b[1], a[2] + b[2]


@_njit(inline=True)
def _braking(gap, two_a, ad, dt, discrete):  # pragma: no cover - compiled
    """The speed from which a joint ``gap >= 0`` from its limit stops before it (``two_a = 2 a_max``, ``ad = a_max
    dt``): ``sqrt(2 a_max gap)``, or ``discrete`` with the velocity held for periods ``dt``."""
    if not discrete:
        return math.sqrt(two_a * gap)
    m = math.floor((math.sqrt(1.0 + 8.0 * (gap / (ad * dt))) - 1.0) * 0.5)
    return (gap / dt + ad * (m * (m + 1.0)) * 0.5) / (m + 1.0)


@_njit(inline=True)
def _braking_velocity(delta, two_a, ad, dt):  # pragma: no cover - compiled
    """The largest next velocity ``w`` that can still stop within ``delta``: ``w**2 / (2 a) + w dt <= delta``, i.e.
    ``-a dt + sqrt((a dt)**2 + 2 a delta)``; for ``delta < 0`` (not viable) ``2 delta / dt``."""
    if not delta >= 0.0:
        return 2.0 * delta / dt
    if delta == math.inf:
        return math.inf
    return -ad + math.sqrt(ad * ad + two_a * delta)


@_njit(inline=True)
def _project(p_lo, p_up, lo, up, violated_lo, violated_up):  # pragma: no cover - compiled
    """The position box ``[p_lo, p_up]`` clipped into the rate box ``[lo, up]`` (empty: the violated side wins)."""
    if p_lo > p_up:
        if violated_lo:
            p_up = p_lo
        elif violated_up:
            p_lo = p_up
    p_up = max(p_lo, p_up)  # (an empty box with neither side violated cannot occur: keep the order anyway)
    return min(up, max(lo, p_lo)), min(up, max(lo, p_up))


@_njit
def velocity_box(q, P, idx, dt, lo, up, v=None):  # pragma: no cover - compiled
    """The velocity box (with ``v``: the command-rate box) at ``q[idx[0]]`` into ``lo[idx[1]]``, ``up[idx[1]]``
    (``P``: :attr:`BoxLimits.rows`); False if a joint was outside its limits (the recovery rule applied)."""
    inside, discrete = True, v is not None
    for j in range(P.shape[1]):
        c, qj = idx[1, j], q[idx[0, j]]
        q_min, q_max, v_max, two_a, ad = P[0, j], P[1, j], P[2, j], P[4, j], P[5, j]
        stop_lo = -math.inf if q_min == -math.inf else (  # (a_max = 0: the joint stops at once)
            -_braking(max(0.0, qj - q_min), two_a, ad, dt, discrete) if two_a != 0.0 else 0.0)
        stop_up = math.inf if q_max == math.inf else (
            _braking(max(0.0, q_max - qj), two_a, ad, dt, discrete) if two_a != 0.0 else 0.0)
        p_lo = max(stop_lo, (q_min - qj) / dt)
        p_up = min(stop_up, (q_max - qj) / dt)
        inside = inside and p_lo <= p_up
        a, b = _project(p_lo, p_up, -v_max, v_max, qj < q_min, qj > q_max)
        if v is None:
            lo[c], up[c] = a, b
        else:  # command_rate_box
            lo[c], up[c] = min(b, max(a, v[c] - ad)), min(b, max(a, v[c] + ad))
    return inside


@_njit
def acceleration_box(q, v, P, idx, dt, lo, up):  # pragma: no cover - compiled
    """The acceleration box at ``(q[idx[0]], v[idx[1]])`` into ``lo[idx[1]]``, ``up[idx[1]]``; False if a state was
    not viable (the recovery rules applied)."""
    viable = True
    for j in range(P.shape[1]):
        c = idx[1, j]
        qj, dq = q[idx[0, j]], v[c]
        q_min, q_max, v_max, a_max, two_a, ad = P[0, j], P[1, j], P[2, j], P[3, j], P[4, j], P[5, j]
        lo_v = min(a_max, max(-a_max, (-v_max - dq) / dt))
        up_v = min(a_max, max(-a_max, (v_max - dq) / dt))
        h = 0.5 * dq * dt
        delta_up = q_max - qj - h
        delta_lo = qj - q_min + h
        p_lo = (-_braking_velocity(delta_lo, two_a, ad, dt) - dq) / dt
        p_up = (_braking_velocity(delta_up, two_a, ad, dt) - dq) / dt
        viable = viable and delta_up >= 0.0 and delta_lo >= 0.0 and p_lo <= p_up
        lo[c], up[c] = _project(p_lo, p_up, lo_v, up_v, delta_lo < 0.0, delta_up < 0.0)
    return viable


@_njit
def euclidean_step(q, v, a, dt, order, q_next, v_next):  # pragma: no cover - compiled
    """:meth:`State.integrate` where ``pin.integrate`` is ``q + dq``, entry by entry."""
    for i in range(q.shape[0]):
        if order == 1:
            q_next[i] = q[i] + a[i] * dt
            v_next[i] = a[i]
        else:
            q_next[i] = q[i] + (v[i] * dt + 0.5 * a[i] * dt * dt)
            v_next[i] = v[i] + a[i] * dt


@_njit
def frame_placement(RiT, pi, P, RfT, p):  # pragma: no cover - compiled
    """``pin.updateFramePlacement`` (Eigen's order of sums): ``R_i R_p`` into ``RfT`` (transposed), ``R_i p_p + p_i``
    into ``p``, from ``RiT = R_i^T``, ``pi`` and ``P`` (rows of ``R_p``, then ``p_p``)."""
    for a in range(3):
        r0, r1, r2 = RiT[0, a], RiT[1, a], RiT[2, a]
        if a < 2:
            for b in range(3):
                RfT[b, a] = (r0 * P[0, b] + r1 * P[1, b]) + r2 * P[2, b]
            p[a] = ((r0 * P[3, 0] + r1 * P[3, 1]) + r2 * P[3, 2]) + pi[a]
        else:
            for b in range(3):
                RfT[b, a] = r0 * P[0, b] + (r1 * P[1, b] + r2 * P[2, b])
            p[a] = (r0 * P[3, 0] + (r1 * P[3, 1] + r2 * P[3, 2])) + pi[a]


@_njit
def frame_jacobian(JT, cols, p, S):  # pragma: no cover - compiled
    """``pin.getFrameJacobian(..., LOCAL_WORLD_ALIGNED)`` of a frame at ``p`` into columns ``cols`` of ``S`` from
    ``JT = data.J.T``: linear ``v - p x omega``, angular ``omega``."""
    pt = (p[0], p[1], p[2])
    for c in cols:
        omega = (JT[c, 3], JT[c, 4], JT[c, 5])
        x = _cross(pt, omega)
        S[0, c], S[1, c], S[2, c] = JT[c, 0] - x[0], JT[c, 1] - x[1], JT[c, 2] - x[2]
        S[3, c], S[4, c], S[5, c] = omega


@_njit
def frame_jdot_qdot(JT, cols, ends, v, p, jdq):  # pragma: no cover - compiled
    """``jdq <- J-dot q-dot`` of a frame at ``p`` (pinocchio's classical acceleration at zero ``q-ddot``) from ``JT =
    data.J.T``, ``v`` on columns ``cols`` (``ends``: :meth:`State.frame_jdot_source`), without a velocity pass."""
    zero = (0.0, 0.0, 0.0)
    u = w = j = k = a = b = zero  # the parent body's velocity V = [u, w], the joint's V_J = [j, k], A = [a, b]
    for i in range(cols.shape[0]):
        c = cols[i]
        qd = v[c]
        j = (j[0] + JT[c, 0] * qd, j[1] + JT[c, 1] * qd, j[2] + JT[c, 2] * qd)  # (V_J: its columns summed)
        k = (k[0] + JT[c, 3] * qd, k[1] + JT[c, 4] * qd, k[2] + JT[c, 5] * qd)
        if ends[i]:  # A += V x V_J = [w x j + u x k, w x k], then V += V_J
            a, b = _add(a, _add(_cross(w, j), _cross(u, k))), _add(b, _cross(w, k))
            u, w, j, k = _add(u, j), _add(w, k), zero, zero
    pt = (p[0], p[1], p[2])
    s = _add(u, _cross(w, pt))  # the frame origin's velocity u + w x p
    jdq[0], jdq[1], jdq[2] = _add(_add(a, _cross(b, pt)), _cross(w, s))
    jdq[3], jdq[4], jdq[5] = b


#: How far from orthonormal and right-handed a rotation may be in :func:`pose_into` (entry by entry)
ROTATION_TOL = 1e-7


@_njit
def pose_into(H, pose):  # pragma: no cover - compiled
    """A 4 x 4 pose ``H`` into ``pose`` (translation, then the rotation transposed, row by row) if its translation is
    finite and its rotation a rotation matrix to :data:`ROTATION_TOL` (rows 0, 1 orthonormal, row 2 their cross
    product); False (nothing written) else."""
    a, b, c, d, e, f, tol = H[0, 0], H[0, 1], H[0, 2], H[1, 0], H[1, 1], H[1, 2], ROTATION_TOL
    x = _cross((a, b, c), (d, e, f))
    if not (math.isfinite(H[0, 3]) and math.isfinite(H[1, 3]) and math.isfinite(H[2, 3])
            and abs(a * a + b * b + c * c - 1.0) < tol and abs(d * d + e * e + f * f - 1.0) < tol
            and abs(a * d + b * e + c * f) < tol and abs(x[0] - H[2, 0]) < tol and abs(x[1] - H[2, 1]) < tol
            and abs(x[2] - H[2, 2]) < tol):
        return False
    for r in range(3):
        pose[r] = H[r, 3]
        for k in range(3):
            pose[3 + 3 * k + r] = H[r, k]
    return True


@_njit
def copy_finite(x, out):  # pragma: no cover - compiled
    """``out <- x`` (vectors) if ``x`` has ``out``'s length and is finite; False (nothing written) else."""
    n = out.shape[0]
    if x.shape[0] != n:
        return False
    for i in range(n):
        if not math.isfinite(x[i]):
            return False
    for i in range(n):
        out[i] = x[i]
    return True


_EPS = 2.220446049250313e-16        # numpy.finfo(float).eps, Eigen's NumTraits<double>::epsilon()
_PREC = _EPS ** (1.0 / 3.0)         # pinocchio's TaylorSeriesExpansion<double>::precision<2>()


@_njit
def _theta_axis(i0, val, R, axis):  # pragma: no cover - compiled
    """pinocchio's ``internal::compute_theta_axis<i0>`` (``log3`` near ``pi``): the angle; ``axis`` normalized."""
    i1, i2 = (i0 + 1) % 3, (i0 + 2) % 3
    s = math.sqrt(val + _EPS + _EPS * _EPS) * (1.0 if R[i2, i1] >= R[i1, i2] else -1.0)
    axis[i0] = s / 2.0
    axis[i1] = 1.0 / (2.0 * s) * (R[i1, i0] + R[i0, i1])
    axis[i2] = 1.0 / (2.0 * s) * (R[i2, i0] + R[i0, i2])
    w = 1.0 / (2.0 * s) * (R[i2, i1] - R[i1, i2])
    norm = math.sqrt(axis[0] * axis[0] + axis[1] * axis[1] + axis[2] * axis[2])
    for k in range(3):
        axis[k] /= norm
    return 2.0 * math.atan2(norm, w)


@_njit
def log3(M, w):  # pragma: no cover - compiled
    """``w <- pin.log3(M)``: pinocchio's ``log3_impl`` (3.x) step by step (within a few ulps of it)."""
    R = np.empty((3, 3))
    n0 = math.sqrt(M[0, 0] * M[0, 0] + M[1, 0] * M[1, 0] + M[2, 0] * M[2, 0])
    n1 = math.sqrt(M[0, 1] * M[0, 1] + M[1, 1] * M[1, 1] + M[2, 1] * M[2, 1])
    for i in range(3):          # renormalize_rotation_matrix: c0, c1 normalized, c2 = c0 x c1, c0 = c1 x c2
        R[i, 0] = M[i, 0] / n0
        R[i, 1] = M[i, 1] / n1
    R[0, 2], R[1, 2], R[2, 2] = _cross((R[0, 0], R[1, 0], R[2, 0]), (R[0, 1], R[1, 1], R[2, 1]))
    R[0, 0], R[1, 0], R[2, 0] = _cross((R[0, 1], R[1, 1], R[2, 1]), (R[0, 2], R[1, 2], R[2, 2]))
    tr = R[0, 0] + R[1, 1] + R[2, 2]
    cos_value = (tr - 1.0) / 2.0
    if cos_value < -1.0 + _PREC:  # theta near pi: the axis from the largest 2 R_ii - tr + 1
        v0, v1, v2 = 2.0 * R[0, 0] - tr + 1.0, 2.0 * R[1, 1] - tr + 1.0, 2.0 * R[2, 2] - tr + 1.0
        i0 = (0 if v0 >= v2 else 2) if v0 >= v1 else (1 if v1 >= v2 else 2)
        axis = np.empty(3)
        theta = _theta_axis(i0, v0 if i0 == 0 else (v1 if i0 == 1 else v2), R, axis)
        for k in range(3):
            w[k] = theta * axis[k]
        return
    acos_expansion = math.sqrt(2.0 * (1.0 - cos_value) + _EPS * _EPS)
    if tr <= 3.0 - _PREC:
        theta = math.acos(cos_value) if tr >= -1.0 + _PREC else math.pi - acos_expansion
    else:
        theta = acos_expansion
    a0, a1, a2 = 0.5 * (R[2, 1] - R[1, 2]), 0.5 * (R[0, 2] - R[2, 0]), 0.5 * (R[1, 0] - R[0, 1])  # unSkew
    n2 = a0 * a0 + a1 * a1 + a2 * a2
    t = theta / math.sin(theta) if theta >= _PREC else 1.0 + n2 / 6.0 + n2 * n2 * 3.0 / 40.0
    w[0], w[1], w[2] = t * a0, t * a1, t * a2


@_njit
def rotation_error(RdT, RT, w):  # pragma: no cover - compiled
    """``w <- log3(R_d R^T)`` (the frame tasks' rotation error) from ``RdT = R_d^T``, ``RT = R^T``."""
    E = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            E[i, j] = RdT[0, i] * RT[0, j] + RdT[1, i] * RT[1, j] + RdT[2, i] * RT[2, j]
    log3(E, w)


def typed(kernel, *args):
    """``kernel``'s compiled code for the types of ``args`` (no per-call dispatch: arguments always of these types)."""
    return kernel.compile(tuple(kernel.typeof_pyval(a) for a in args))


_jit.compile_when_enabled(globals())  # numba's dispatchers (each compiled on its first call) while the switch is on
_jit.share_switch(__name__)  # ENABLED, AVAILABLE: hqp_tpm._jit's

"""Compiled (numba) kernels of the distance field and Algorithm 1's per-step arithmetic (private).

One call each instead of 10-40 small numpy calls: the closed-form sphere-sphere block of
:meth:`~hqp_tpm.geometry.distances.DistanceField.update` (eq. (22) for control points and spheres), the
witness point's ``J̇_c q̇`` (:func:`~hqp_tpm.geometry.witness.point_jdot_qdot`, used in (29)) and the
masked minimum of :meth:`Algorithm1._nearest <hqp_tpm.policies.algorithm1.Algorithm1._nearest>` ((22), (31)).
Every kernel does the readable code's floating-point operations in the same order (no fast-math, no
contraction): the choices (nearest pairs, the broad phase, the sphere block) are the readable code's to the last bit;
the rotations ``R.dot(x)`` of the witness point's ``J̇_c q̇`` sum in numpy's order on some CPUs' BLAS kernels only,
elsewhere a few ulps apart (``tests/test_geometry_compiled.py`` compares both paths: within 1e-12 there); a case the
kernel does not handle (coinciding centres) returns False and the readable code runs.

Switched with the other kernels: :data:`hqp_tpm._jit.ENABLED` (``HQP_TPM_COMPILED=0``: off).
"""

from __future__ import annotations

import math

import numpy as np

from hqp_tpm import _jit
from hqp_tpm._jit import kernel as _njit  # the package's one kernel decorator (compiled at the end of this module)


@_njit
def sphere_block(C, e_idx, Oc, o_idx, rsum, re, ro, re_zero, ro_zero, dist, normal, last, p_rob, p_obs,
                 computed, delta, tiny):  # pragma: no cover - compiled
    """The sphere block of :meth:`DistanceField._update_spheres` into the record views (E x H, E x H x 3).

    ``C[e_idx]`` the element centres, ``Oc[o_idx]`` the obstacle centres, ``delta`` an E x H scratch.
    Returns False (nothing written) if two centres are within ``tiny``: the readable code then runs.
    """
    E, H = e_idx.shape[0], o_idx.shape[0]
    for a in range(E):
        ea = e_idx[a]
        for b in range(H):
            ob = o_idx[b]
            d0 = C[ea, 0] - Oc[ob, 0]
            d1 = C[ea, 1] - Oc[ob, 1]
            d2 = C[ea, 2] - Oc[ob, 2]
            dl = math.sqrt((d0 * d0 + d2 * d2) + d1 * d1)  # numpy's einsum order (2 lanes), tested
            if not dl > tiny:
                return False
            delta[a, b] = dl
    for a in range(E):
        ea = e_idx[a]
        for b in range(H):
            ob = o_idx[b]
            dl = delta[a, b]
            for k in range(3):
                n = (C[ea, k] - Oc[ob, k]) / dl
                normal[a, b, k] = n
                last[a, b, k] = n
                p_rob[a, b, k] = C[ea, k] if re_zero else C[ea, k] - re[a] * n
                p_obs[a, b, k] = Oc[ob, k] if ro_zero else Oc[ob, k] + ro[b] * n
            dist[a, b] = dl - rsum[a, b]
            computed[a, b] = True
    return True


@_njit(inline=True)
def cross_into(a0, a1, a2, b0, b1, b2):  # pragma: no cover - compiled
    """:func:`hqp_tpm.robot.spatial.cross3` on scalars."""
    return a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0


@_njit(inline=True)
def _rotate(R, x0, x1, x2):  # pragma: no cover - compiled
    """``R x`` row by row, the sums in numpy's order (``R.dot(x)``: equal to the last bit, tested)."""
    return (R[0, 0] * x0 + R[0, 1] * x1 + R[0, 2] * x2, R[1, 0] * x0 + R[1, 1] * x1 + R[1, 2] * x2,
            R[2, 0] * x0 + R[2, 1] * x1 + R[2, 2] * x2)


@_njit(inline=True)  # (inlined where avoidance_row calls it; compiled alone when Python calls it)
def point_jdot_qdot(R, o, v, a, p, out):  # pragma: no cover - compiled
    """:func:`~hqp_tpm.geometry.witness.point_jdot_qdot` into ``out``: the joint's rotation ``R`` and origin ``o``,
    its local velocity ``v`` and acceleration ``a`` (linear, angular), the point ``p`` (world)."""
    c0, c1, c2 = cross_into(v[3], v[4], v[5], v[0], v[1], v[2])
    ao0, ao1, ao2 = _rotate(R, a[0] + c0, a[1] + c1, a[2] + c2)       # classical acceleration of the origin
    al0, al1, al2 = _rotate(R, a[3], a[4], a[5])
    w0, w1, w2 = _rotate(R, v[3], v[4], v[5])
    r0, r1, r2 = p[0] - o[0], p[1] - o[1], p[2] - o[2]
    c10, c11, c12 = cross_into(al0, al1, al2, r0, r1, r2)
    u0, u1, u2 = cross_into(w0, w1, w2, r0, r1, r2)
    c20, c21, c22 = cross_into(w0, w1, w2, u0, u1, u2)
    out[0] = ao0 + c10 + c20
    out[1] = ao1 + c11 + c21
    out[2] = ao2 + c12 + c22


@_njit
def nearest_pairs(distance, in_range, ee_row, eps2):  # pragma: no cover - compiled
    """``(j_ee, d_ee, k, j, d_minimal)`` of :meth:`Algorithm1._nearest` (direction ``"nearest"``): numpy's
    ``argmin`` (the first minimum in row-major order, the first NaN if any) of the in-range distances of row
    ``ee_row`` and of the rows above it; ``-1``/``inf`` where nothing is in range, and for the body when its
    minimum exceeds ``eps2``."""
    H = distance.shape[1]
    j_ee, d_ee = 0, math.inf
    for c in range(H):
        d = distance[ee_row, c] if in_range[ee_row, c] else math.inf
        if d != d:
            j_ee, d_ee = c, d
            break
        if d < d_ee:
            j_ee, d_ee = c, d
    if d_ee == math.inf:
        j_ee = -1
    k, j, dm = 0, 0, math.inf
    for r in range(ee_row):
        for c in range(H):
            d = distance[r, c] if in_range[r, c] else math.inf
            if d != d:
                if dm == dm:
                    k, j, dm = r, c, d
                break
            if d < dm:
                k, j, dm = r, c, d
        if dm != dm:
            break
    if dm > eps2:  # also +inf: nothing in range
        k, j, dm = -1, -1, math.inf
    return j_ee, d_ee, k, j, dm


@_njit
def avoidance_row(Jj, R, o, v, a, p, normal, magnitude, order, J, b):  # pragma: no cover - compiled
    """The 1-D avoidance row (29) of the witness point ``p`` fixed to a joint, into ``J`` (1 x n) and ``b`` (1):
    ``J_c = J_v - [r]x J_w`` (:func:`~hqp_tpm.geometry.witness.point_jacobian`: its product by numpy's ``dot``,
    the same BLAS call), ``J = n^T J_c``, ``b = r`` (order 1) or ``r - n^T J̇_c q̇`` (order 2, :func:`point_jdot_qdot`).

    ``Jj`` the joint's 6 x n world-aligned Jacobian, ``R``, ``o`` its rotation and origin, ``v``, ``a`` its local
    velocity and acceleration (linear, angular).
    """
    r0, r1, r2 = p[0] - o[0], p[1] - o[1], p[2] - o[2]
    S = np.zeros((3, 3))
    S[0, 1], S[0, 2], S[1, 0], S[1, 2], S[2, 0], S[2, 1] = -r2, r1, r2, -r0, -r1, r0
    P = np.dot(S, np.ascontiguousarray(Jj[3:]))
    for c in range(J.shape[1]):
        J[0, c] = (normal[0] * (Jj[0, c] - P[0, c]) + normal[1] * (Jj[1, c] - P[1, c])
                   + normal[2] * (Jj[2, c] - P[2, c]))
    rr = magnitude * 1.0
    if order == 1:
        b[0] = rr
        return
    jdq = np.empty(3)
    point_jdot_qdot(R, o, v, a, p, jdq)
    b[0] = rr - (normal[0] * jdq[0] + normal[1] * jdq[1] + normal[2] * jdq[2])


@_njit
def near_pairs(Ca, ia, Cb, ib, ra, rb, surveillance):  # pragma: no cover - compiled
    """:func:`hqp_tpm.geometry.pairs.near_pairs` of the gathered rows ``Ca[ia]``, ``Cb[ib]``, ``ra[ia]``, ``rb[ib]``:
    the pairs ``k`` with ``||Ca[ia[k]] - Cb[ib[k]]|| - ra[ia[k]] - rb[ib[k]] <= surveillance``, in order."""
    out = np.empty(ia.shape[0], dtype=np.int64)
    return out[:_near_into(Ca, ia, Cb, ib, ra, rb, surveillance, out)]


@_njit(inline=True)
def _near_into(Ca, ia, Cb, ib, ra, rb, surveillance, out):  # pragma: no cover - compiled
    """:func:`near_pairs` into ``out``; returns how many."""
    n = 0
    for k in range(ia.shape[0]):
        a, b = ia[k], ib[k]
        d0 = Ca[a, 0] - Cb[b, 0]
        d1 = Ca[a, 1] - Cb[b, 1]
        d2 = Ca[a, 2] - Cb[b, 2]
        lower = math.sqrt((d0 * d0 + d2 * d2) + d1 * d1) - ra[a] - rb[b]  # numpy's einsum order, tested
        if lower <= surveillance:
            out[n] = k
            n += 1
    return n


@_njit
def broad_phase(block, c, C, er, Oc, orad, ie, io, surveillance, ia, ib, self_surveillance, todo,
                self_todo):  # pragma: no cover - compiled
    """The bounding-sphere centres and both broad phases of :meth:`DistanceField.update` in one call: ``C[:n]`` the
    centres of the ``n`` geometries whose placements ``block`` holds (``block[i, :3]`` the rotation's columns,
    ``block[i, 3]`` the origin: :func:`centres`' operations), then the obstacle pairs (``ie``, ``io``) and the self
    pairs (``ia``, ``ib``) :func:`near_pairs` keeps, into ``todo`` and ``self_todo``; returns how many of each."""
    for i in range(block.shape[0]):
        for k in range(2):
            C[i, k] = ((block[i, 0, k] * c[i, 0] + block[i, 1, k] * c[i, 1]) + block[i, 2, k] * c[i, 2]) \
                + block[i, 3, k]
        C[i, 2] = (block[i, 0, 2] * c[i, 0] + (block[i, 1, 2] * c[i, 1] + block[i, 2, 2] * c[i, 2])) + block[i, 3, 2]
    n = _near_into(C, ie, Oc, io, er, orad, surveillance, todo)
    return n, _near_into(C, ia, C, ib, er, er, self_surveillance, self_todo)


@_njit
def centres(R, T, c, out):  # pragma: no cover - compiled
    """``out[i] = R[i] c[i] + T[i]``: the world centres of the elements' bounding spheres from their placements, in
    the order of ``pin.SE3.act`` on x86-64 (Eigen: rows 0 and 1 as one packet summed in order, row 2 as
    ``r0 + (r1 + r2)``: equal to the last bit there; elsewhere within an ulp, tests/test_geometry_compiled.py).
    They serve the broad phase only (lower bounds of distances)."""
    for i in range(R.shape[0]):
        for k in range(2):
            out[i, k] = ((R[i, k, 0] * c[i, 0] + R[i, k, 1] * c[i, 1]) + R[i, k, 2] * c[i, 2]) + T[i, k]
        out[i, 2] = (R[i, 2, 0] * c[i, 0] + (R[i, 2, 1] * c[i, 1] + R[i, 2, 2] * c[i, 2])) + T[i, 2]


@_njit
def scatter_pairs(D, P1, P2, index, dist, p1, p2, normal, last, computed, tiny, bad):  # pragma: no cover - compiled
    """The queried pairs ``i`` (distance ``D[i]``, witness points ``P1[i]``, ``P2[i]``) into the records' flat rows
    ``index[i]``: distance, witness points, ``normal = sign(d) (p1 - p2)/||p1 - p2||`` (the readable path's
    operations, :meth:`DistanceField._normals`), its copy in ``last``, ``computed``. Rows whose witness points
    coincide (not ``||p1 - p2|| > tiny``) get no normal: their ``i`` go to ``bad``; returns how many."""
    return _scatter(D, P1, P2, index, np.arange(D.shape[0]), D.shape[0], dist, p1, p2, normal, last, computed, tiny,
                    bad)


@_njit(inline=True)
def _scatter(D, P1, P2, flat, todo, m, dist, p1, p2, normal, last, computed, tiny, bad):  # pragma: no cover
    """:func:`scatter_pairs` of the first ``m`` queries, query ``i`` into flat row ``flat[todo[i]]``."""
    nb = 0
    for i in range(m):
        r = flat[todo[i]]
        d = D[i]
        u0 = P1[i, 0] - P2[i, 0]
        u1 = P1[i, 1] - P2[i, 1]
        u2 = P1[i, 2] - P2[i, 2]
        nu = math.sqrt((u0 * u0 + u2 * u2) + u1 * u1)  # numpy's einsum order, tested
        dist[r] = d
        for k in range(3):
            p1[r, k] = P1[i, k]
            p2[r, k] = P2[i, k]
        computed[r] = True
        if not nu > tiny:
            bad[nb] = i
            nb += 1
            continue
        s = (1.0 if d >= 0.0 else -1.0) / nu
        normal[r, 0] = last[r, 0] = u0 * s
        normal[r, 1] = last[r, 1] = u1 * s
        normal[r, 2] = last[r, 2] = u2 * s
    return nb


@_njit
def rewrite_pairs(D, P1, P2, flat, todo, m, dist, p1, p2, normal, last, computed, in_range, surveillance, tiny,
                  bad):  # pragma: no cover - compiled
    """A whole record in one call: cleared (:meth:`~hqp_tpm.geometry.records.PairRecord.clear`: ``+inf``, NaN,
    zero normal, not computed), the first ``m`` queries written as :func:`scatter_pairs` writes them (query ``i``
    into flat row ``flat[todo[i]]``), then ``in_range = dist <= surveillance``; returns how many queries go to
    ``bad`` (witness points coincide: no normal written; ``bad[nb]`` then holds the first nearest in-range row, as
    ``np.argmin`` of the in-range distances chooses it, ``-1`` if none)."""
    for r in range(dist.shape[0]):
        dist[r] = math.inf
        computed[r] = False
        for k in range(3):
            p1[r, k] = math.nan
            p2[r, k] = math.nan
            normal[r, k] = 0.0
    nb = _scatter(D, P1, P2, flat, todo, m, dist, p1, p2, normal, last, computed, tiny, bad)
    k, best = -1, math.inf
    for r in range(dist.shape[0]):
        in_range[r] = dist[r] <= surveillance
        if in_range[r] and dist[r] < best:
            k, best = r, dist[r]
    bad[nb] = k
    return nb


@_njit
def normal_row(Jj, o, p, normal, out):  # pragma: no cover - compiled
    """``out = n^T J_c``: the rate of a pair's distance per joint velocity, ``J_c`` the Jacobian of the witness point
    ``p`` fixed to a joint (:func:`~hqp_tpm.geometry.witness.point_jacobian`: ``J_v - [r]x J_w``), with numpy's
    ``dot`` for both products (the same BLAS calls as ``normal @ point_jacobian(...)``: equal to the last bit where
    numba and numpy call the same BLAS kernels, tests/test_geometry_compiled.py).

    ``Jj`` the joint's 6 x n world-aligned Jacobian, ``o`` its origin."""
    Jc = np.empty((3, Jj.shape[1]))
    _point_jacobian(Jj, o, p, Jc)
    out[:] = np.dot(normal, Jc)


@_njit
def self_normal_row(Ja, oa, pa, Jb, ob, pb, normal, out):  # pragma: no cover - compiled
    """``out = n^T (J_a - J_b)``: the rate of a self pair's distance per joint velocity, ``J_a``, ``J_b`` the
    Jacobians of its witness points ``pa``, ``pb`` fixed to their joints (Jacobians ``Ja``, ``Jb``, origins ``oa``,
    ``ob``), in the operations of ``normal @ (point_jacobian(a) - point_jacobian(b))`` (:func:`normal_row`)."""
    Jc = np.empty((3, Ja.shape[1]))
    Jd = np.empty((3, Ja.shape[1]))
    _point_jacobian(Ja, oa, pa, Jc)
    _point_jacobian(Jb, ob, pb, Jd)
    out[:] = np.dot(normal, Jc - Jd)


@_njit(inline=True)
def _point_jacobian(Jj, o, p, out):  # pragma: no cover - compiled
    """``out = J_v - [p - o]x J_w`` (:func:`~hqp_tpm.geometry.witness.point_jacobian`, numpy's ``dot``)."""
    r0, r1, r2 = p[0] - o[0], p[1] - o[1], p[2] - o[2]
    S = np.zeros((3, 3))
    S[0, 1], S[0, 2], S[1, 0], S[1, 2], S[2, 0], S[2, 1] = -r2, r1, r2, -r0, -r1, r0
    out[:] = np.ascontiguousarray(Jj[:3]) - np.dot(S, np.ascontiguousarray(Jj[3:]))


@_njit
def closest_per_column(distance, in_range, below, element, value):  # pragma: no cover - compiled
    """Per column ``j`` (an obstacle) of the in-range distances (out of range: +inf), its first minimum's row, as
    ``np.argmin`` chooses it (the first NaN if any); the columns whose minimum is ``< below`` go to ``element``,
    ``value`` (column ``j`` at ``element[j]``, ``value[j]``; others ``-1``). Returns how many."""
    M, H = distance.shape
    n = 0
    for j in range(H):
        be, bd = 0, distance[0, j] if in_range[0, j] else math.inf
        if bd == bd:
            for r in range(1, M):
                x = distance[r, j] if in_range[r, j] else math.inf
                if x != x:
                    be, bd = r, x
                    break
                if x < bd:
                    be, bd = r, x
        if bd < below:
            element[j], value[j] = be, bd
            n += 1
        else:
            element[j], value[j] = -1, math.inf
    return n


_jit.compile_when_enabled(globals())  # numba's dispatchers (each compiled on its first call) while the switch is on

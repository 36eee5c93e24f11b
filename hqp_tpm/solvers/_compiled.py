"""The solvers' kernels (private to :mod:`hqp_tpm.solvers`): compiled by numba when :data:`hqp_tpm._jit.ENABLED`,
else the same source runs as Python. They are the implementation of TPM (``tpm``/``tpm_stacked``: :func:`_tpm`, one
call) and of the recursion (``nullspace``, and TPM where a pivot is singular); the paper-literal oracles are
``tpm_reference`` and ``sns_tpm_reference``:

* :func:`_past_rank` (``m > n``, rank ``n`` reached before the last level: the shortcut of
  :mod:`hqp_tpm.solvers._fullrank`), also inside SNS-TPM's kernel for the stack and its free-column stacks;
* :func:`_general` (``m <= n``): the Householder QR of ``J^T``; each pivot certified regular (or a 1 x 1 block
  damped); Steps 2-4 on the pivot blocks, ``x = Q R^{-T} F b``, ``x0`` term; a singular pivot: the recursion; a
  block the certificate cannot decide: :func:`_general_svd`, the same with that block decided and damped by its SVD
  (compiled only when a run needs it, then in :func:`_general`'s place);
* :func:`_recursion_cols` / :func:`_recursion`: eqs. (5)-(6), (14) of papers/000 on orthonormal bases.

``tests/test_compiled.py`` proves them equal to the oracles (1e-12; on ill-conditioned draws against a 50-digit
reference).

How :func:`past_rank` computes (``J_<k^T = Q1 R1``, ``Q = [Q1 Z]``, see :mod:`hqp_tpm.solvers._fullrank`):

* Householder QR of ``J_<k^T`` (LAPACK's ``dlarfg`` convention) on the rows of ``J`` (contiguous), the
  certificates from ``R1^{-1}`` (back substitution), ``z = R1^{-T} b_<k``; with the damping on, a pivot whose
  certificate ``1/||R_ii^{-1}||_F`` is below ``eps`` is decided by the SVD of its block and, where ``sigma_min <
  eps``, inverted by the damping law: then ``z`` by Steps 2-4 as a forward substitution with every pivot's
  (damped) inverse, ``z_i = D_i^T (b_i - sum_{j<i} R_ji^T z_j)`` (the recursion on the basis ``Q1``, tpm module
  doc; :func:`_pivot_forward`);
* ``J_k Q`` by applying the reflectors from the right (to a row-major ``J_k^T``): its first ``m1`` columns
  give ``J_k x1``, the others are ``A = J_k Z``;
* ``A = Q_A R_A`` (Householder): ``||A#||_F = ||R_A^{-1}||_F`` exactly, and ``1/||R_A^{-1}||_F <= sigma_min(A)
  <= min |r_jj|`` decides the rank test without an SVD; when it cannot decide (``sigma_min`` within a factor
  ``sqrt(r)`` of a threshold), the recursion answers instead; a square ``A`` whose bound is below ``eps`` gets
  its ``sigma_min`` (for the damping law) from the SVD of ``R_A``;
* the crossing level's least squares ``y = A# r`` from ``R_A`` (undamped) or from the QR of ``[R_A; lambda I]``
  (damped: the same minimizer as ``V diag(s/(s^2 + lambda^2)) U^T r``; :func:`_damped_qr` walks only its
  nonzeros, once per factorization, for every right-hand side);
* ``x = Q [z; y]`` (the reflectors applied once more).

Dispatch: compiled when :data:`hqp_tpm._jit.ENABLED` (``HQP_TPM_COMPILED=0``: off; this module's :data:`ENABLED`
and :data:`AVAILABLE` are that switch). :mod:`hqp_tpm._jit` compiles them on the first call of a process (~2-5 s)
or loads them from its disk cache (~0.1-1 s).
"""

from __future__ import annotations

import math

import numpy as np

from hqp_tpm import _jit
from hqp_tpm._jit import kernel as _kernel  # the package's one kernel decorator
from hqp_tpm.solvers._fullrank import COND, MARGIN
from hqp_tpm.solvers.damping import EPS, RANK_FACTOR

#: Factorization outcomes: ``x`` computed; declined (the shortcut does not apply); the certificates cannot decide
#: (``sigma_min`` itself would); a singular pivot (``_general_factors`` with ``singular_ok``). The last three: the
#: recursion answers.
SOLVED, DECLINED, UNDECIDED, SINGULAR = 0, 1, 2, 3
#: :func:`_general`'s hand-back: a pivot block its certificate cannot decide, whose SVD :func:`_general_svd` takes
#: (nothing solved; the value is beyond the statuses the compiled steps add, 3-7 in
#: :mod:`hqp_tpm.control._compiled_step`, so that they hand it back as it is).
PIVOT_SVD = 8
#: :func:`_tpm`'s report: the factorization's kernel answered, or the recursion did.
FACTORED, RECURSION = 0, 1

_READY = False


def _inlined(fn):
    """A kernel numba inlines where compiled code calls it (``inline="always"``): no call, no array tuple handed
    back, fewer reference counts; the same operations in the same order (numba's IR is inlined, LLVM does not
    reorder floating-point operations)."""
    return _kernel(fn, inline=True)


def _compile() -> None:
    """Replace every kernel of this module by its numba dispatcher (:func:`hqp_tpm._jit.compile_module`)."""
    global _READY, _gesdd, _block_svd, _general_first
    if not _jit.compile_module(globals()):
        raise ImportError("numba cannot be imported")
    _general_first = _general
    lapack = _jit.lapack_gesdd()
    if lapack is not None:  # (else numba's np.linalg.svd: _block_svd's own source)
        _gesdd = lapack
        _block_svd = _jit.dispatcher(_block_svd_lapack)
    _READY = True


# ----------------------------------------------------------------------------------------
# Small dense building blocks (row-major; loops over a contiguous row run innermost and from 0, so that
# numba drops the negative-index check and LLVM vectorizes them). Sums keep their term order, except the dot
# products of a Householder reflection and a reflector's norm (:func:`_dot`: four interleaved partial sums).
# ----------------------------------------------------------------------------------------
@_inlined
def _dot(u, v, t0, c):
    """``sum_{tt < c} u[t0 + tt] v[t0 + tt]`` in four partial sums (every fourth term; then ``(s0 + s1) + (s2 + s3)``):
    four independent chains of additions instead of one latency-bound chain."""
    s0 = 0.0
    s1 = 0.0
    s2 = 0.0
    s3 = 0.0
    c4 = c - c % 4
    for tt in range(0, c4, 4):
        s0 += u[t0 + tt] * v[t0 + tt]
        s1 += u[t0 + tt + 1] * v[t0 + tt + 1]
        s2 += u[t0 + tt + 2] * v[t0 + tt + 2]
        s3 += u[t0 + tt + 3] * v[t0 + tt + 3]
    for tt in range(c4, c):
        s0 += u[t0 + tt] * v[t0 + tt]
    return (s0 + s1) + (s2 + s3)


@_kernel
def _householder_rows(V, tau, R):
    """QR of ``M = V^T`` (``q x p``, ``q >= p``), in place on the rows of ``V`` (``p x q``, row-major).

    Reflector ``i`` is ``I - tau_i v v^T`` with ``v = (0..0, 1, V[i, i+1:])``; ``R`` (``p x p``) gets the upper
    triangle. LAPACK ``dgeqr2``/``dlarfg`` convention: ``r_ii = -sign(alpha) ||x||``.

    Each column's ``w_j = V[j, i] + sum_t v_t V[j, t]`` is one sum in ``t`` order; four columns run at once
    (four independent chains instead of one latency-bound chain), and the updates ``V[j, t] -= w_j v_t`` run
    along contiguous rows from 0 (LLVM vectorizes them); the reflector's norm by :func:`_dot`.
    """
    p, q = V.shape
    for i in range(p):
        alpha = V[i, i]
        t0 = i + 1                                     # entries t0 + tt of a row (loops from 0: numba then
        c = q - t0                                     # drops its negative-index check and LLVM vectorizes)
        xn = _dot(V[i], V[i], t0, c)
        if xn == 0.0:
            tau[i] = 0.0
            beta = alpha
        else:
            beta = -math.copysign(math.sqrt(alpha * alpha + xn), alpha)
            tau[i] = (beta - alpha) / beta
            scal = 1.0 / (alpha - beta)
            for tt in range(c):
                V[i, t0 + tt] *= scal
        R[i, i] = beta
        ti = tau[i]
        j = i + 1
        while j + 4 <= p:                              # H_i applied to columns j..j+3 of M (rows of V)
            w0 = V[j, i]
            w1 = V[j + 1, i]
            w2 = V[j + 2, i]
            w3 = V[j + 3, i]
            for tt in range(c):
                v = V[i, t0 + tt]
                w0 += v * V[j, t0 + tt]
                w1 += v * V[j + 1, t0 + tt]
                w2 += v * V[j + 2, t0 + tt]
                w3 += v * V[j + 3, t0 + tt]
            w0 *= ti
            w1 *= ti
            w2 *= ti
            w3 *= ti
            V[j, i] -= w0
            V[j + 1, i] -= w1
            V[j + 2, i] -= w2
            V[j + 3, i] -= w3
            for tt in range(c):                        # one loop per row: each one vectorizes
                V[j, t0 + tt] -= w0 * V[i, t0 + tt]
            for tt in range(c):
                V[j + 1, t0 + tt] -= w1 * V[i, t0 + tt]
            for tt in range(c):
                V[j + 2, t0 + tt] -= w2 * V[i, t0 + tt]
            for tt in range(c):
                V[j + 3, t0 + tt] -= w3 * V[i, t0 + tt]
            R[i, j] = V[j, i]
            R[i, j + 1] = V[j + 1, i]
            R[i, j + 2] = V[j + 2, i]
            R[i, j + 3] = V[j + 3, i]
            j += 4
        while j < p:
            w = V[j, i]
            for tt in range(c):
                w += V[i, t0 + tt] * V[j, t0 + tt]
            w *= ti
            V[j, i] -= w
            for tt in range(c):
                V[j, t0 + tt] -= w * V[i, t0 + tt]
            R[i, j] = V[j, i]
            j += 1


@_inlined
def _rows_qr(J, p):
    """``(V, tau, R)``: the QR of ``J[:p]^T`` by :func:`_householder_rows` on a copy of the first ``p`` rows."""
    n = J.shape[1]
    V = np.empty((p, n))
    for i in range(p):
        for t in range(n):
            V[i, t] = J[i, t]
    tau = np.zeros(p)
    R = np.zeros((p, p))
    if p:
        _householder_rows(V, tau, R)
    return V, tau, R


@_kernel
def _apply_right_t(BT, V, tau, p, w):
    """``B <- B H_0 H_1 ... H_{p-1}`` on ``BT = B^T`` (``q x rows``, row-major) with the reflectors of
    :func:`_householder_rows` (rows of ``V``); ``w``: scratch of length ``>= rows``. Each row's
    ``w_r = B[r, i] + sum_t B[r, t] v_t`` in ``t`` order, all rows at once along the contiguous rows of ``BT``."""
    q, rows = BT.shape
    for i in range(p):
        ti = tau[i]
        if ti == 0.0:
            continue
        for r in range(rows):
            w[r] = BT[i, r]
        t = i + 1
        while t + 4 <= q:                              # four terms of each sum per pass, still in t order
            v0, v1, v2, v3 = V[i, t], V[i, t + 1], V[i, t + 2], V[i, t + 3]
            for r in range(rows):
                w[r] = (((w[r] + BT[t, r] * v0) + BT[t + 1, r] * v1) + BT[t + 2, r] * v2) + BT[t + 3, r] * v3
            t += 4
        while t < q:
            vt = V[i, t]
            for r in range(rows):
                w[r] += BT[t, r] * vt
            t += 1
        for r in range(rows):
            w[r] *= ti
            BT[i, r] -= w[r]
        t = i + 1
        while t + 4 <= q:
            v0, v1, v2, v3 = V[i, t], V[i, t + 1], V[i, t + 2], V[i, t + 3]
            for r in range(rows):
                wr = w[r]
                BT[t, r] -= wr * v0
                BT[t + 1, r] -= wr * v1
                BT[t + 2, r] -= wr * v2
                BT[t + 3, r] -= wr * v3
            t += 4
        while t < q:
            vt = V[i, t]
            for r in range(rows):
                BT[t, r] -= w[r] * vt
            t += 1


@_inlined
def _reflect(x, V, tau, i):
    """``x <- H_i x`` with ``H_i = I - tau_i v_i v_i^T``, ``v_i = (1, V[i, i+1:])`` on rows ``i:``."""
    ti = tau[i]
    if ti == 0.0:
        return
    t0 = i + 1
    c = x.shape[0] - t0
    w = x[i] + _dot(V[i], x, t0, c)
    w *= ti
    x[i] -= w
    for tt in range(c):
        x[t0 + tt] -= w * V[i, t0 + tt]


@_kernel
def _apply_q(x, V, tau, p):
    """``x <- H_0 H_1 ... H_{p-1} x`` (``Q x``)."""
    for i in range(p - 1, -1, -1):
        _reflect(x, V, tau, i)


@_kernel
def _apply_q_rows(X, V, tau, p):
    """``X[r] <- Q X[r]`` for every row ``r`` of ``X`` (:func:`_apply_q` on each row, the rows interleaved
    reflector by reflector: independent chains the processor overlaps)."""
    for i in range(p - 1, -1, -1):
        for r in range(X.shape[0]):
            _reflect(X[r], V, tau, i)


@_kernel
def _apply_qt(x, V, tau, p):
    """``x <- H_{p-1} ... H_0 x`` (``Q^T x``)."""
    for i in range(p):
        _reflect(x, V, tau, i)


@_inlined
def _sumsq_rows(J, a, e, acc):
    """``||J[a:e]||_F^2``: squares accumulated per column along the contiguous rows (``acc``, length ``>= n``,
    holds each column's sum afterwards), then the columns' sums added in order."""
    n = J.shape[1]
    for t in range(n):
        acc[t] = 0.0
    for i in range(a, e):
        for t in range(n):
            acc[t] += J[i, t] * J[i, t]
    s = 0.0
    for t in range(n):
        s += acc[t]
    return s


@_kernel
def _triangular_inverse(R):
    """``R^{-1}`` of an upper-triangular ``R`` with a nonzero diagonal (back substitution, row by row).

    ``X[i, j] = -(sum_{t=i+1..j} R[i, t] X[t, j]) / R[i, i]``, each sum accumulated in ``t`` order along the
    contiguous rows ``X[t, t:]`` (the loop vectorizes; the same sums as column by column).
    """
    p = R.shape[0]
    X = np.zeros((p, p))
    for i in range(p - 1, -1, -1):
        t = i + 1
        while t + 2 <= p:                              # two terms per pass (t, t + 1), still in t order
            r0 = R[i, t]
            r1 = R[i, t + 1]
            X[i, t] += r0 * X[t, t]
            t1 = t + 1
            for jj in range(p - t1):                   # j = t + 1 + jj (from 0: vectorized)
                X[i, t1 + jj] = (X[i, t1 + jj] + r0 * X[t, t1 + jj]) + r1 * X[t1, t1 + jj]
            t += 2
        if t < p:
            rit = R[i, t]
            for jj in range(p - t):
                X[i, t + jj] += rit * X[t, t + jj]
        rii = R[i, i]
        X[i, i] = 1.0 / rii
        for j in range(i + 1, p):
            X[i, j] = -X[i, j] / rii
    return X


@_kernel
def _solve_upper(R, c):
    """``R^{-1} c`` (upper triangular)."""
    p = R.shape[0]
    y = np.empty(p)
    for i in range(p - 1, -1, -1):
        s = c[i]
        for t in range(i + 1, p):
            s -= R[i, t] * y[t]
        y[i] = s / R[i, i]
    return y


@_kernel
def _solve_upper_t(R, c):
    """``R^{-T} c`` (forward substitution with ``R^T``)."""
    p = R.shape[0]
    y = np.empty(p)
    for i in range(p):
        s = c[i]
        for t in range(i):
            s -= R[t, i] * y[t]
        y[i] = s / R[i, i]
    return y


@_inlined
def _fro_block(X, a, e, c0, c1):
    s = 0.0
    for i in range(a, e):
        for j in range(c0, c1):
            s += X[i, j] * X[i, j]
    return math.sqrt(s)


@_inlined
def _fro_upper(X, a, e):
    """``_fro_block(X, a, e, a, e)`` of an upper-triangular ``X``: the same sum without its zero terms."""
    s = 0.0
    for i in range(a, e):
        for j in range(i, e):
            s += X[i, j] * X[i, j]
    return math.sqrt(s)


@_inlined
def _lower_dot(u, v, i, r):
    """``sum_{t <= i} u[t] v[t]`` as :func:`_dot` sums these terms inside reflector ``i`` of :func:`_damped_qr`: term
    ``t`` is entry ``r + t`` of the ``2r`` rows, so term ``r - i - 1 + t`` of ``_dot``'s ``2r - i - 1``, and joins
    the same one of its four partial sums."""
    c = 2 * r - i - 1
    c4 = c - c % 4
    off = r - i - 1
    s0 = 0.0
    s1 = 0.0
    s2 = 0.0
    s3 = 0.0
    for t in range(i + 1):
        p = u[t] * v[t]
        tt = off + t
        k = tt & 3 if tt < c4 else 0
        if k == 0:
            s0 += p
        elif k == 1:
            s1 += p
        elif k == 2:
            s2 += p
        else:
            s3 += p
    return (s0 + s1) + (s2 + s3)


@_kernel
def _damped_qr(RA, lam):
    """The QR of ``M = [R_A; lam I]`` (``2r x r``, ``R_A`` upper triangular) for damped least squares:
    ``(DV, tau, R2)``, reflector ``i`` being ``I - tau_i v v^T`` with ``v`` 1 at row ``i`` and ``DV[i, :i + 1]``
    at rows ``r .. r + i`` (its only other nonzeros: reflectors ``< i`` fill the lower block's rows ``<= i`` only).

    :func:`_householder_rows` on ``M^T`` gives the same bits: each sum takes the same nonzero terms in the same
    order and partial sums (:func:`_lower_dot`); it also walks the known zeros, ``~4x`` the arithmetic at ``r = 10``.
    """
    r = RA.shape[0]
    DV = np.zeros((r, r))
    tau = np.zeros(r)
    R2 = np.zeros((r, r))
    B = np.zeros((r, r))                               # B[j, t]: the lower block's entry (t, j) (column j as a row)
    for j in range(r):
        B[j, j] = lam
    for i in range(r):
        alpha = RA[i, i]                               # (the upper block's rows > i are zero in reflectors < i)
        xn = _lower_dot(B[i], B[i], i, r)
        if xn == 0.0:
            beta = alpha
            for t in range(i + 1):
                DV[i, t] = B[i, t]
        else:
            beta = -math.copysign(math.sqrt(alpha * alpha + xn), alpha)
            tau[i] = (beta - alpha) / beta
            scal = 1.0 / (alpha - beta)
            for t in range(i + 1):
                DV[i, t] = B[i, t] * scal
        R2[i, i] = beta
        ti = tau[i]
        for j in range(i + 1, r):
            w = RA[i, j]
            for t in range(i + 1):
                w += DV[i, t] * B[j, t]
            w *= ti
            R2[i, j] = RA[i, j] - w
            for t in range(i + 1):
                B[j, t] -= w * DV[i, t]
    return DV, tau, R2


@_kernel
def _damped_solve(DV, tau, R2, c):
    """``argmin ||R_A y - c||^2 + lam^2 ||y||^2`` from :func:`_damped_qr`'s factors: ``R2^{-1}`` of the first ``r``
    entries of ``Q^T [c; 0]`` (the sums of :func:`_apply_qt` on ``2r`` entries, without their zero terms)."""
    r = R2.shape[0]
    x = np.empty(r)
    for i in range(r):
        x[i] = c[i]
    d = np.zeros(r)                                    # the lower half of Q^T [c; 0]
    for i in range(r):
        ti = tau[i]
        if ti == 0.0:
            continue
        w = x[i] + _lower_dot(DV[i], d, i, r)
        w *= ti
        x[i] -= w
        for t in range(i + 1):
            d[t] -= w * DV[i, t]
    return _solve_upper(R2, x)


# ----------------------------------------------------------------------------------------
# The full-rank shortcut (hqp_tpm.solvers._fullrank): TPM of a stack that reaches rank n before its last level.
# ----------------------------------------------------------------------------------------
@_inlined
def _crossing_level(sizes, n):
    """``(k, m1, mk, r)``: the level ``k`` whose rows take a stack of ``n`` columns to rank ``n`` (the levels above
    it have ``m1 < n`` rows together), its row count ``mk`` and ``r = n - m1``."""
    m1 = 0
    k = 0
    while m1 + sizes[k] < n:
        m1 += sizes[k]
        k += 1
    return k, m1, sizes[k], n - m1


@_inlined
def _level_sumsq(J, sizes, w):
    """``||J_lev||_F^2`` of every level (``w``: scratch of length ``>= n``)."""
    nlev = sizes.shape[0]
    sq = np.empty(nlev)
    a = 0
    for lev in range(nlev):
        e = a + sizes[lev]
        sq[lev] = _sumsq_rows(J, a, e, w)
        a = e
    return sq


@_inlined
def _past_rank_certify(R1, BT, sq, sizes, k, m1, mk, r, size, lambda_max, eps, unit, margin, cond, damped_map):
    """The certificates of :func:`_past_rank` and the QR of ``A = J_k Z``, given ``R1`` (``J_<k^T = Q1 R1``, its
    diagonal nonzero) and ``BT = (J_k Q)^T``: ``(status, AT, tauA, RA, Dp, blk, lam)``.

    A pivot ``R_ii`` of the levels ``< k`` is certified regular (``1/||R_ii^{-1}||_F`` above ``margin`` times its
    rank tolerance and ``cond ||J_i||_F``); where that bound is below ``eps`` (damping on) the SVD of the block
    gives ``sigma_min`` and, below ``eps``, its damped inverse (:func:`_damped_block`): then ``Dp`` (``m1 x m1``,
    block diagonal) holds every pivot's inverse, ``R_ii^{-1}`` or damped, and ``blk[i]`` the first row of row
    ``i``'s level (else both empty: ``R1^{-T}`` by substitution). ``lam``: the crossing level's damping (0: none),
    ``lambda_max`` when ``A`` has fewer columns than rows, else from ``sigma_min(A)`` (the SVD of ``R_A`` where
    ``1/||R_A^{-1}||_F < eps``). The damping law is continuous in ``sigma_min``: no margin is needed at ``eps``.

    ``damped_map`` (SNS-TPM's downdated passes, :func:`hqp_tpm.solvers._compiled_sns._downdated_factor`): where a
    pivot is damped and the undamped ``||R1^{-1}||_F`` fails the solution-map certificate, the map ``b -> z`` of the
    forward substitution with the damped inverses is measured instead (:func:`_damped_map_norm`). Such stacks (upper
    levels ~1e-4 of their norm from dependence, damped) then take the shortcut rather than the recursion; the two
    differ by the stack's own rounding sensitivity (the upper levels' null space moves by ``~eps / sigma_min``: up
    to ~1e-11 relative, inside SNS-TPM's 1e-9 to its reference; ``tests/test_damped_certificate.py``). ``tpm`` (and
    the SNS loop's first pass, its TPM) keep the undamped certificate: 1e-12 to ``tpm_reference``."""
    AT = np.empty((r, mk))                             # A^T: the columns of A as rows
    tauA = np.empty(r)
    RA = np.zeros((r, r))
    Dp = np.empty((0, 0))
    blk = np.empty(0, dtype=np.int64)
    a_inv = 0.0
    if m1:                                             # levels < k: pivots certified regular by 1/||R_ii^-1||_F
        R1inv = _triangular_inverse(R1)
        a = 0
        for lev in range(k):
            e = a + sizes[lev]
            bound = 1.0 / _fro_upper(R1inv, a, e)
            norm = math.sqrt(sq[lev])
            if bound <= max(margin * unit * size * norm, cond * norm):
                return DECLINED, AT, tauA, RA, Dp, blk, 0.0
            if lambda_max > 0.0 and bound < eps:       # sigma_min may be below eps: the block's SVD decides
                if Dp.shape[0] == 0:
                    Dp, blk = _pivot_inverses(R1inv, sizes, k, m1)
                if e - a == 1:
                    s = abs(R1[a, a])
                    if s < eps:
                        inv = s / (s * s + (1.0 - (s / eps) ** 2) * lambda_max**2)
                        Dp[a, a] = inv if R1[a, a] >= 0.0 else -inv
                else:
                    _damped_pivot(R1, a, e, lambda_max, eps, Dp)
            a = e
        a_inv = _fro_upper(R1inv, 0, m1)
    norm_k = math.sqrt(sq[k])
    thr_k = max(margin * unit * size * norm_k, cond * norm_k)
    norm = 0.0
    for lev in range(sq.shape[0]):
        norm += sq[lev]
    norm = math.sqrt(norm)
    thr = max(margin * unit * size * norm, cond * norm)
    for j in range(r):
        for i in range(mk):
            AT[j, i] = BT[m1 + j, i]
    _householder_rows(AT, tauA, RA)
    dmin = math.inf
    for j in range(r):
        dmin = min(dmin, abs(RA[j, j]))
    if dmin <= thr_k:                                  # sigma_min <= min |r_jj|: rank n not reached clearly
        return DECLINED, AT, tauA, RA, Dp, blk, 0.0
    RAinv = _triangular_inverse(RA)
    p = _fro_upper(RAinv, 0, r)                        # = ||A#||_F = sqrt(sum 1/sigma^2)
    lower = 1.0 / p                                    # <= sigma_min(A)
    if lower <= thr_k:
        return UNDECIDED, AT, tauA, RA, Dp, blk, 0.0   # sigma_min itself: the reference's SVD decides
    lam = 0.0
    if lambda_max > 0.0 and r < mk and 0.0 < eps:      # m_k - r zero singular values: lambda = lambda_max
        lam = math.sqrt(lambda_max * lambda_max)       # (as the earlier kernel took it: the same bits)
        p = min(p, math.sqrt(r) / (2.0 * lam))         # s / (s^2 + lam^2) <= min(1/s, 1/(2 lam))
    elif lambda_max > 0.0 and r == mk and lower < eps:
        sv = _jacobi_svd(RA, 0, r)[1]                  # sigma(A) = sigma(R_A)
        smin = sv[0]
        for t in range(1, r):
            smin = min(smin, sv[t])
        if smin < eps:
            lam2 = (1.0 - (smin / eps) ** 2) * lambda_max**2
            lam = math.sqrt(lam2)
            p = 0.0
            for t in range(r):
                p += (sv[t] / (sv[t] * sv[t] + lam2)) ** 2
            p = math.sqrt(p)                           # ||A#_lambda||_F
    if 1.0 / (a_inv + p * (1.0 + norm_k * a_inv)) <= thr:   # the stack's solution map: at most 1/(cond ||J||)
        if not damped_map or Dp.shape[0] == 0:         # (SNS downdated passes: z's map, damped pivots)
            return DECLINED, AT, tauA, RA, Dp, blk, 0.0
        a_inv = _damped_map_norm(R1, Dp, sizes, k, m1)
        if 1.0 / (a_inv + p * (1.0 + norm_k * a_inv)) <= thr:
            return DECLINED, AT, tauA, RA, Dp, blk, 0.0
    return SOLVED, AT, tauA, RA, Dp, blk, lam


@_kernel
def _damped_map_norm(R1, Dp, sizes, k, m1):
    """``||X||_F`` of the map ``b -> z = X^T b`` of :func:`_pivot_forward` (``R1^{-1}`` with each pivot's inverse
    replaced by ``Dp``'s block, damped or not): block column by block column, ``X[:, i] = (E_i - X[:, :a_i]
    R1[:a_i, i]) D_i`` (``E_i``: the identity's columns of level ``i``; ``X`` is block upper triangular)."""
    X = np.zeros((m1, m1))
    T = np.empty(m1)
    a = 0
    for lev in range(k):
        e = a + sizes[lev]
        for row in range(a):                           # the rows above level lev: -X[row, :a] R1[:a, a:e] D_i
            for c in range(a, e):
                s = 0.0
                for t in range(a):
                    s += X[row, t] * R1[t, c]
                T[c] = -s
            for c in range(a, e):
                s = 0.0
                for t in range(a, e):
                    s += T[t] * Dp[t, c]
                X[row, c] = s
        for row in range(a, e):                        # its own rows: D_i
            for c in range(a, e):
                X[row, c] = Dp[row, c]
        a = e
    return _fro_block(X, 0, m1, 0, m1)


@_kernel
def _jacobi_svd(B, a, e):
    """``(W, sv, Vt)`` of the square block ``B[a:e, a:e] = U diag(sv) V^T`` by one-sided Jacobi (Hestenes; Demmel
    & Veselic's rotation): the block's columns rotated pairwise until orthogonal, ``W[j] = sv_j u_j`` (the rotated
    columns as rows), ``Vt[j]`` = ``v_j``, ``sv`` unsorted. Singular values to high relative accuracy, a few
    sweeps on the small pivot blocks of TPM, no LAPACK call and no workspace query."""
    k = e - a
    W = np.empty((k, k))
    for j in range(k):
        for i in range(k):
            W[j, i] = B[a + i, a + j]
    Vt = np.zeros((k, k))
    for j in range(k):
        Vt[j, j] = 1.0
    for _ in range(40):
        rotated = False
        for p in range(k - 1):
            for q in range(p + 1, k):
                al = 0.0
                be = 0.0
                ga = 0.0
                for i in range(k):
                    al += W[p, i] * W[p, i]
                    be += W[q, i] * W[q, i]
                    ga += W[p, i] * W[q, i]
                if ga == 0.0 or abs(ga) <= EPS * math.sqrt(al * be):
                    continue
                rotated = True
                zeta = (be - al) / (2.0 * ga)
                t = math.copysign(1.0, zeta) / (abs(zeta) + math.sqrt(1.0 + zeta * zeta))
                c = 1.0 / math.sqrt(1.0 + t * t)
                sn = c * t
                for i in range(k):
                    wp = W[p, i]
                    wq = W[q, i]
                    W[p, i] = c * wp - sn * wq
                    W[q, i] = sn * wp + c * wq
                    vp = Vt[p, i]
                    vq = Vt[q, i]
                    Vt[p, i] = c * vp - sn * vq
                    Vt[q, i] = sn * vp + c * vq
        if not rotated:
            break
    sv = np.empty(k)
    for j in range(k):
        ssq = 0.0
        for i in range(k):
            ssq += W[j, i] * W[j, i]
        sv[j] = math.sqrt(ssq)
    return W, sv, Vt


@_inlined
def _damped_pivot(R, a, e, lambda_max, eps, D):
    """The regular pivot block ``R[a:e, a:e]`` whose certificate is below ``eps``: its singular values
    (:func:`_jacobi_svd`) and, when ``sigma_min < eps``, ``D[a:e, a:e]`` <- its damped inverse ``V diag(s / (s^2 +
    lambda^2)) U^T`` (``damping.inverted_singular_values``' law; every ``s`` is above the rank tolerance: certified).
    Returns 1 if damped, 0 if not (``D`` untouched)."""
    W, sv, Vt = _jacobi_svd(R, a, e)
    k = e - a
    smin = sv[0]
    for j in range(1, k):
        smin = min(smin, sv[j])
    if not smin < eps:
        return 0
    lam2 = (1.0 - (smin / eps) ** 2) * lambda_max**2
    for j in range(k):                                 # (u_j s_j = W[j]: s_j / (s_j^2 + lam2) u_j = W[j] / (..))
        sv[j] = 1.0 / (sv[j] * sv[j] + lam2)
    for i in range(k):
        for col in range(k):
            s = 0.0
            for j in range(k):
                s += Vt[j, i] * sv[j] * W[j, col]
            D[a + i, a + col] = s
    return 1


@_inlined
def _pivot_inverses(R1inv, sizes, k, m1):
    """``(Dp, blk)``: the block diagonal of ``R1^{-1}`` (the pivots' inverses ``R_ii^{-1}`` of levels ``< k``) and
    each row's first row of its level."""
    Dp = np.zeros((m1, m1))
    blk = np.empty(m1, dtype=np.int64)
    a = 0
    for lev in range(k):
        e = a + sizes[lev]
        for i in range(a, e):
            blk[i] = a
            for j in range(i, e):
                Dp[i, j] = R1inv[i, j]
        a = e
    return Dp, blk


@_inlined
def _pivot_forward(R1, Dp, blk, b, m1):
    """``z`` of Steps 2-4 with the pivots' (damped) inverses ``Dp`` (:func:`_past_rank_certify`): level by level
    ``z_i = D_i^T (b_i - sum_{j<i} R_ji^T z_j)``, the recursion on the basis ``Q1`` (tpm module doc)."""
    z = np.empty(m1)
    c = np.empty(m1)
    a = 0
    while a < m1:
        e = a + 1
        while e < m1 and blk[e] == a:
            e += 1
        for i in range(a, e):
            s = b[i]
            for t in range(a):
                s -= R1[t, i] * z[t]
            c[i] = s
        for i in range(a, e):
            s = 0.0
            for t in range(a, e):
                s += Dp[t, i] * c[t]
            z[i] = s
        a = e
    return z


@_inlined
def _past_rank_factor(J, sizes, n, lambda_max, eps, unit, margin, cond, damped_map):
    """The part of :func:`_past_rank` that depends on ``J`` only: its status and, if :data:`SOLVED`, the
    factors :func:`_past_rank_rhs` needs, ``(status, m1, mk, r, V, tau, R1, BT, AT, tauA, RA, DV, Dtau, DR, Dp,
    blk)``."""
    m = J.shape[0]
    k, m1, mk, r = _crossing_level(sizes, n)
    w = np.empty(max(n, mk))                           # scratch of the Householder updates and row norms
    sq = _level_sumsq(J, sizes, w)
    V, tau, R1 = _rows_qr(J, m1)                       # levels < k: J_<k^T = Q1 R1 on the rows of J
    BT = np.empty((n, mk))
    for i in range(m1):
        if R1[i, i] == 0.0:                            # dtrtri's info > 0
            AT, tauA, RA = np.empty((r, mk)), np.empty(r), np.zeros((r, r))
            return (DECLINED, m1, mk, r, V, tau, R1, BT, AT, tauA, RA, *_no_damping())
    for i in range(mk):                                # (J_k Q)^T = [J_k Q1, A]^T: J_k x1 = (J_k Q1) z, A = J_k Z
        for t in range(n):
            BT[t, i] = J[m1 + i, t]
    _apply_right_t(BT, V, tau, m1, w)
    status, AT, tauA, RA, Dp, blk, lam = _past_rank_certify(R1, BT, sq, sizes, k, m1, mk, r, max(m, n), lambda_max,
                                                            eps, unit, margin, cond, damped_map)
    if status != SOLVED:
        return (status, m1, mk, r, V, tau, R1, BT, AT, tauA, RA, *_no_damping())
    DV, Dtau, DR = _crossing_damping(RA, lam)
    return status, m1, mk, r, V, tau, R1, BT, AT, tauA, RA, DV, Dtau, DR, Dp, blk


@_inlined
def _no_damping():
    """Empty ``(DV, Dtau, DR, Dp, blk)``: no damped crossing level and no damped pivot above it (or nothing
    solved)."""
    return np.empty((0, 0)), np.empty(0), np.empty((0, 0)), np.empty((0, 0)), np.empty(0, dtype=np.int64)


@_inlined
def _crossing_damping(RA, lam):
    """The crossing level's damped factors (:func:`_damped_qr` of ``[R_A; lam I]``, shared by every right-hand
    side) when ``lam > 0`` (:func:`_past_rank_certify`), else empty."""
    if lam > 0.0:
        return _damped_qr(RA, lam)
    return np.empty((0, 0)), np.empty(0), np.empty((0, 0))


@_inlined
def _crossing_rhs(b, m1, mk, r, R1, BT, AT, tauA, RA, DV, Dtau, DR, Dp, blk, out):
    """``out[:m1] <- z``, ``out[m1:m1 + r] <- y`` of :func:`_past_rank` for the right-hand side ``b``
    (``x = Q [z; y]``; ``DV, Dtau, DR``: :func:`_crossing_damping`; ``Dp, blk``: :func:`_past_rank_certify`)."""
    if Dp.shape[0]:                                    # a damped pivot above the crossing level
        z = _pivot_forward(R1, Dp, blk, b, m1)
    else:
        z = _solve_upper_t(R1, b[:m1]) if m1 else np.empty(0)
    res = np.empty(mk)
    for i in range(mk):
        res[i] = b[m1 + i]
    for t in range(m1):                                # res_i = b_i - sum_t (J_k Q1)[i, t] z_t (t ascending)
        zt = z[t]
        for i in range(mk):
            res[i] -= BT[t, i] * zt
    _apply_qt(res, AT, tauA, r)
    if DR.shape[0]:                                    # the crossing level damped (lambda > 0)
        y = _damped_solve(DV, Dtau, DR, res[:r])
    else:
        y = _solve_upper(RA, res[:r])
    for i in range(m1):                                # (loops, not slice copies: a slice assignment from an
        out[i] = z[i]                                  # array compiles numba's shape-error message, ~2 s of CPU)
    for i in range(r):
        out[m1 + i] = y[i]


@_inlined
def _past_rank_rhs(b, m1, mk, r, V, tau, R1, BT, AT, tauA, RA, DV, Dtau, DR, Dp, blk, lambda_max, eps, out):
    """``out <- x`` of :func:`_past_rank` for the right-hand side ``b``, from :func:`_past_rank_factor`'s factors
    (``lambda_max``, ``eps``: not read, the damping is in the factors)."""
    _crossing_rhs(b, m1, mk, r, R1, BT, AT, tauA, RA, DV, Dtau, DR, Dp, blk, out)
    _apply_q(out, V, tau, m1)                          # x = Q [z; y]


@_kernel
def _past_rank(J, b, sizes, n, lambda_max, eps, unit, margin, cond, out):
    """``out <- x`` of the full-rank shortcut (:mod:`hqp_tpm.solvers._fullrank`); returns :data:`SOLVED`,
    :data:`DECLINED` or :data:`UNDECIDED` (only ``sigma_min(A)`` itself can decide: the caller runs the recursion).

    ``unit = RANK_FACTOR * EPS`` (``rank_tol(norm, size) = unit * size * norm``), ``margin``, ``cond``: the
    reference's ``MARGIN`` and ``COND``.
    """
    (status, m1, mk, r, V, tau, R1, BT, AT, tauA, RA, DV, Dtau, DR, Dp,
     blk) = _past_rank_factor(J, sizes, n, lambda_max, eps, unit, margin, cond, False)
    if status == SOLVED:
        _past_rank_rhs(b, m1, mk, r, V, tau, R1, BT, AT, tauA, RA, DV, Dtau, DR, Dp, blk, lambda_max, eps, out)
    return status


# ----------------------------------------------------------------------------------------
# The general TPM path when m <= n.
# ----------------------------------------------------------------------------------------
@_kernel
def _block_svd(R, a, e):
    """``(U, s, Vt)``: ``np.linalg.svd`` of the upper triangle of the block ``R[a:e, a:e]`` (LAPACK's ``dgesdd``,
    ``U`` and ``Vt`` square). Compiled, :func:`_block_svd_lapack` takes its place (:func:`_compile`): the same
    LAPACK call."""
    k = e - a
    B = np.zeros((k, k))
    for i in range(k):
        for j in range(i, k):
            B[i, j] = R[a + i, a + j]
    return np.linalg.svd(B)


_gesdd = None  # numba's LAPACK driver of np.linalg.svd (hqp_tpm._jit.lapack_gesdd; read by _block_svd_lapack)


def _block_svd_lapack(R, a, e):  # pragma: no cover - compiled (as _block_svd)
    """:func:`_block_svd` as numba compiles its ``np.linalg.svd``, without the generic parts: the block copied in
    column-major order, numba's own ``dgesdd`` driver (``numba_ez_gesdd``: the workspace query, then ``dgesdd``,
    ``jobz = 'A'``) on it, ``U`` and ``Vt`` the transposes of its column-major results. The same call on the same
    bytes: the same bits. Left out: numba's checks of an empty or non-finite matrix (a pivot block of a finite
    stack's ``R`` is neither) and its copy of any layout; with them ~0.4 s of CPU compiling each kernel that calls
    it (``benchmarks/first_run.py``)."""
    k = e - a
    A = np.zeros((k, k))                               # A[j, i] = B[i, j]: B in column-major order
    for i in range(k):
        for j in range(i, k):
            A[j, i] = R[a + i, a + j]
    u = np.empty((k, k))
    s = np.empty(k)
    vt = np.empty((k, k))
    r = _gesdd(100, 65, k, k, A.ctypes, k, s.ctypes, u.ctypes, k, vt.ctypes, k)   # kind 'd', jobz 'A'
    if r != 0 or A.shape[0] != k:                      # (A read after the call: alive until it returns)
        raise ValueError("Internal algorithm failed to converge.")
    return u.T, s, vt.T


@_inlined
def _damped_block(R, a, e, tol, lambda_max, eps, singular_ok, D):
    """The pivot block ``R[a:e, a:e]`` (``e - a > 1``) that its certificate did not decide, by the SVD of the block
    (LAPACK's ``gesdd``; ``damping.inverted_singular_values``' law): 0 regular, 1 damped
    (``D[a:e, a:e]`` gets the damped inverse ``V diag(s / (s^2 + lambda^2)) U^T``), -1 singular; with
    ``singular_ok`` a singular block gets its truncated (damped) inverse too (``s <= tol``: 0) and 2."""
    k = e - a
    U, sv, Vt = _block_svd(R, a, e)
    smin = sv[k - 1]
    singular = smin <= tol
    if singular and not singular_ok:
        return -1
    if not singular and not (lambda_max > 0.0 and smin < eps):
        return 0
    lam2 = (1.0 - (smin / eps) ** 2) * lambda_max**2 if lambda_max > 0.0 and smin < eps else 0.0
    for i in range(k):                                  # damping.inverted_singular_values
        for j in range(k):
            s = 0.0
            for t in range(k):
                if sv[t] > tol:
                    s += Vt[t, i] * (sv[t] / (sv[t] * sv[t] + lam2)) * U[j, t]
            D[a + i, a + j] = s
    return 2 if singular else 1


@_inlined
def _general_factors(J, sizes, lambda_max, eps, unit, singular_ok):
    """:func:`_factors` with every pivot decided, by the SVD of its block where its certificate cannot tell
    (:func:`_damped_block`; SNS-TPM's kernel)."""
    return _factors(J, sizes, lambda_max, eps, unit, singular_ok, _damped_block)


@_inlined
def _defer_block(R, a, e, tol, lambda_max, eps, singular_ok, D):
    """:func:`_factors`' ``block`` of :func:`_general`: a pivot block that needs its SVD is left to
    :func:`_general_svd` (-2; none of the SVD's code compiled into :func:`_general`)."""
    return -2


@_inlined
def _factors(J, sizes, lambda_max, eps, unit, singular_ok, block):
    """The factorization of TPM for ``m <= n`` (eq. (8) of papers/000): ``(status, damped, V, tau, R, Fb)``, the
    Householder QR of ``J^T`` and, when some pivot is damped (``damped``), ``Fb`` (``m x m``) = ``Fbar`` of Steps 1-4
    (``F = Fbar^T``); otherwise ``F = I`` and ``Fb`` is empty (nothing allocated for it). Each pivot is certified
    regular (``1/||R_ii^{-1}||_F``, ``|r_ii|`` for a 1 x 1 block) or decided by ``block`` (:func:`_damped_block`,
    the SVD of the block; or :func:`_defer_block`: :data:`PIVOT_SVD`, nothing solved). A singular pivot:
    :data:`UNDECIDED` (the caller runs the recursion), or with ``singular_ok`` :data:`SINGULAR` and ``Fb`` with that
    pivot's truncated inverse (SNS-TPM's ``F``; ``x`` by the recursion)."""
    m, n = J.shape
    size = max(m, n)
    nlev = sizes.shape[0]
    V, tau, R = _rows_qr(J, m)
    Fb = np.empty((0, 0))
    zero = False
    for i in range(m):
        if R[i, i] == 0.0:
            if not singular_ok:
                return UNDECIDED, False, V, tau, R, Fb
            zero = True
    Rinv = np.empty((0, 0)) if zero else _triangular_inverse(R)
    kind = np.empty(0, dtype=np.int64)                 # 0: regular (solved with R_ii), 1: damped (D_ii applied)
    D = np.empty((0, 0))                               # block diagonal: the damped inverses of the damped pivots
    damped = False
    singular = False
    a = 0
    for lev in range(nlev):
        e = a + sizes[lev]
        tol = unit * size * _fro_block(J, a, e, 0, n)
        bound = abs(R[a, a]) if e - a == 1 else (0.0 if zero else 1.0 / _fro_upper(Rinv, a, e))
        if not (bound > tol and not (lambda_max > 0.0 and bound < eps)):
            if kind.shape[0] == 0:                     # the first pivot not certified: allocated now
                kind = np.zeros(nlev, dtype=np.int64)
                D = np.zeros((m, m))
            if e - a == 1:
                if bound <= tol:                       # a singular pivot (its inverse: 0)
                    if not singular_ok:
                        return UNDECIDED, False, V, tau, R, Fb
                    singular = True
                    kind[lev] = 1
                else:
                    inv = bound / (bound * bound + (1.0 - (bound / eps) ** 2) * lambda_max**2)
                    D[a, a] = inv if R[a, a] >= 0.0 else -inv
                    kind[lev] = 1
            else:
                k = block(R, a, e, tol, lambda_max, eps, singular_ok, D)
                if k < 0:
                    return (UNDECIDED if k == -1 else PIVOT_SVD), False, V, tau, R, Fb
                singular = singular or k == 2
                kind[lev] = 0 if k == 0 else 1
            damped = damped or kind[lev] == 1
        a = e
    if not damped:
        return SOLVED, False, V, tau, R, Fb
    Fb = np.empty((m, m))
    for i in range(m):                                 # Step 1: Fbar = R
        for j in range(m):
            Fb[i, j] = R[i, j] if j >= i else 0.0
    col_tmp = np.empty(m)
    a = 0
    for lev in range(nlev):
        e = a + sizes[lev]
        if kind[lev] == 0:                             # Step 2: R_ii^{-1} Fbar_i (back substitution)
            for col in range(a, m):
                for i in range(e - 1, a - 1, -1):
                    s = Fb[i, col]
                    for t in range(i + 1, e):
                        s -= R[i, t] * Fb[t, col]
                    Fb[i, col] = s / R[i, i]
        else:                                          # D_ii Fbar_i
            for col in range(a, m):
                for i in range(a, e):
                    s = 0.0
                    for t in range(a, e):
                        s += D[i, t] * Fb[t, col]
                    col_tmp[i] = s
                for i in range(a, e):
                    Fb[i, col] = col_tmp[i]
        mult = np.empty(e - a)
        for i in range(a):                             # Step 3: Fbar[:a, a:] -= Fbar[:a, a:e] Fbar[a:e, a:]
            for t in range(a, e):
                mult[t - a] = Fb[i, t]                 # (the row's old values: the update overwrites them)
            for col in range(a, m):
                s = 0.0
                for t in range(a, e):
                    s += mult[t - a] * Fb[t, col]
                Fb[i, col] -= s
        a = e
    return (SINGULAR if singular else SOLVED), True, V, tau, R, Fb


@_kernel
def _f_times(Fb, b, out):
    """``out <- F b = Fbar^T b`` (Steps 1-4 of papers/000, eq. (10))."""
    m = Fb.shape[0]
    for col in range(m):
        s = 0.0
        for i in range(m):
            s += Fb[i, col] * b[i]
        out[col] = s


@_inlined
def _general_x(J, b, x0, use_x0, damped, V, tau, R, Fb, out):
    """``out <- x = Q R^{-T} F b`` (``x0 + Q R^{-T} (F b - J x0)`` with ``use_x0``) from :func:`_factors`' factors."""
    m, n = J.shape
    c = np.empty(m)
    if damped:
        _f_times(Fb, b, c)
    else:
        for i in range(m):                             # (loops, not slice copies: see _crossing_rhs)
            c[i] = b[i]
    if use_x0:
        for i in range(m):
            s = 0.0
            for t in range(n):
                s += J[i, t] * x0[t]
            c[i] -= s
    z = _solve_upper_t(R, c)
    for i in range(m):
        out[i] = z[i]
    for i in range(m, n):
        out[i] = 0.0
    _apply_q(out, V, tau, m)
    if use_x0:
        for i in range(n):
            out[i] += x0[i]


@_kernel
def _general(J, b, sizes, x0, use_x0, lambda_max, eps, unit, out):
    """``out <- x = Q R^{-T} F b`` (``x0 + Q R^{-T} (F b - J x0)`` with ``use_x0``) of a stack with ``m <= n``
    whose pivots are each certified regular, or singular or damped as a 1 x 1 block (:func:`_factors`). Returns
    :data:`SOLVED`; :data:`UNDECIDED` for a singular pivot (the caller runs the recursion); :data:`PIVOT_SVD` for a
    block only its SVD decides, nothing solved: :func:`_general_svd` answers (the same factorization, the same bits
    as one kernel deciding all), and from then on takes this kernel's place (:func:`_pivot_svd`). Without the SVD
    (LAPACK, the damping of a block) numba compiles ~0.8 s of CPU less on a process's first solve, and only a run
    whose stacks need it compiles :func:`_general_svd` (``benchmarks/first_run.py``).
    """
    status, damped, V, tau, R, Fb = _factors(J, sizes, lambda_max, eps, unit, False, _defer_block)
    if status == SOLVED:
        _general_x(J, b, x0, use_x0, damped, V, tau, R, Fb, out)
    return status


@_kernel
def _general_svd(J, b, sizes, x0, use_x0, lambda_max, eps, unit, out):
    """:func:`_general` with every pivot decided, by the SVD of its block where its certificate cannot tell
    (:func:`_damped_block`): :data:`SOLVED` or :data:`UNDECIDED` (a singular pivot: the caller runs the recursion).
    """
    status, damped, V, tau, R, Fb = _general_factors(J, sizes, lambda_max, eps, unit, False)
    if status == SOLVED:
        _general_x(J, b, x0, use_x0, damped, V, tau, R, Fb, out)
    return status


_general_first = _general  # (the kernel that hands back, whichever _general is now: tests)


_SIZES: dict[tuple, np.ndarray] = {}
_UNIT = RANK_FACTOR * EPS
_NO_X0 = np.zeros(0)


def _sizes(sizes) -> np.ndarray | None:
    """``sizes`` as an int64 array (cached per tuple), after compiling the kernels on first use; None if the switch
    is off (:data:`ENABLED`, kernels not made: nothing compiled, numba not imported) or numba cannot be imported
    after all (then :data:`ENABLED` becomes False: the numpy path from now on)."""
    if not _READY:
        if not _jit.ENABLED:
            return None
        try:
            _compile()
        except ImportError:  # pragma: no cover - numba found but not importable (_jit turned the switch off)
            return None
    if type(sizes) is not tuple:                       # a list or an array: not hashable, converted each call
        return np.asarray(sizes, dtype=np.int64)
    s = _SIZES.get(sizes)
    if s is None:
        s = np.asarray(sizes, dtype=np.int64)
        if len(_SIZES) < 256:
            _SIZES[sizes] = s
    return s


def past_rank(J: np.ndarray, b: np.ndarray, sizes, n: int, lambda_max: float, eps: float, margin: float = MARGIN,
              cond: float = COND):
    """``x`` of the full-rank shortcut (:func:`_past_rank`), or None (declined or undecided: the recursion
    answers); compiled when :data:`ENABLED`, else the same source as Python."""
    s = _SIZES.get(sizes) if _READY and type(sizes) is tuple else None
    if s is None and (s := _sizes(sizes)) is None:
        s = np.asarray(sizes, dtype=np.int64)
    x = np.empty(n)
    status = _past_rank(J, b, s, n, float(lambda_max), float(eps), _UNIT, margin, cond, x)
    return x if status == SOLVED else None


def general(J: np.ndarray, b: np.ndarray, sizes, n: int, lambda_max: float, eps: float, x0=None):
    """``x`` of the general TPM path for ``m <= n`` (:func:`_general`), or None (a singular pivot: the recursion
    answers)."""
    s = _SIZES.get(sizes) if _READY and type(sizes) is tuple else None
    if s is None and (s := _sizes(sizes)) is None:
        s = np.asarray(sizes, dtype=np.int64)
    x = np.empty(n)
    use = x0 is not None
    args = (J, b, s, x0 if use else _NO_X0, use, float(lambda_max), float(eps), _UNIT, x)
    status = _general(*args)
    if status == PIVOT_SVD:
        status = _pivot_svd()(*args)
    return x if status == SOLVED else None


def _pivot_svd():
    """:func:`_general_svd`, from now on also as :func:`_general` (this module's global, which :func:`_tpm` and the
    planned step's solve call): the process has met a stack whose pivot block needs its SVD, and its next solves
    take the kernel that decides every pivot at once (no hand-back; the same bits either way). Compiled only: as
    Python (the switch off) :func:`tpm` takes :func:`_general_svd` at once, and :func:`_compile` finds the module's
    own functions under their names."""
    global _general
    if _READY:
        _general = _general_svd
    return _general_svd


# ----------------------------------------------------------------------------------------
# The recursion of hqp_tpm.solvers.nullspace: TPM on the stacks its factorization cannot take exactly.
# ----------------------------------------------------------------------------------------
@_kernel
def _recursion_cols(J, B, sizes, n, lambda_max, eps, unit, ranks):
    """``(X, Z)``: ``X[:, c]`` the ``x`` of eqs. (5)-(6) of papers/000 for the right-hand side ``B[:, c]``, on
    orthonormal bases ``Z`` (:mod:`hqp_tpm.solvers.nullspace`): level by level the SVD of ``J_i Z``; its singular
    values above ``rank_tol(||J_i||_F, max(m, n))`` are the directions the level uses (inverted by the damping law,
    which sees ``m_i`` values: zeros for the rows beyond ``Z``'s columns), the others stay in ``Z`` for the levels
    below (``Z``: the last basis, ``P = Z Z^T``). ``ranks[i]``: the number of directions level ``i`` uses (its rank
    in what the levels above leave). One SVD per level for every column of ``B``."""
    m = J.shape[0]
    k = B.shape[1]
    size = max(m, n)
    X = np.zeros((n, k))
    Z = np.eye(n)
    a = 0
    for lev in range(sizes.shape[0]):
        e = a + sizes[lev]
        nz = Z.shape[1]
        ranks[lev] = 0
        if nz > 0 and e > a:
            Ji = np.ascontiguousarray(J[a:e])
            ssq = 0.0
            for i in range(Ji.shape[0]):
                for j in range(n):
                    ssq += Ji[i, j] * Ji[i, j]
            tol = unit * size * math.sqrt(ssq)
            r = np.ascontiguousarray(B[a:e]) - Ji @ X
            U, s, Vt = np.linalg.svd(Ji @ Z)
            ns = s.shape[0]
            smin = s[ns - 1] if ns == e - a else 0.0      # m_i values: zeros beyond Z's columns
            lam2 = 0.0
            if lambda_max > 0.0 and smin < eps:
                lam2 = (1.0 - (smin / eps) ** 2) * lambda_max * lambda_max
            rank = 0
            y = np.zeros((nz, k))
            for t in range(ns):
                if s[t] > tol:
                    rank += 1
                    inv = s[t] / (s[t] * s[t] + lam2)
                    for col in range(k):
                        c = 0.0
                        for i in range(e - a):
                            c += U[i, t] * r[i, col]
                        c *= inv
                        for j in range(nz):
                            y[j, col] += c * Vt[t, j]
            ranks[lev] = rank
            X += Z @ y                                    # eq. (5): Z (J_i Z)# (b_i - J_i x)
            Z = Z @ np.ascontiguousarray(Vt[rank:].T)     # eq. (6): P = Z Z^T
        a = e
    return X, Z


@_kernel
def _recursion(J, b, sizes, n, lambda_max, eps, unit, x0, use_x0, ranks):
    """``x`` of :func:`_recursion_cols` for one right-hand side ``b``, then ``+ Z Z^T x0`` (eq. (14)) when
    ``use_x0``."""
    B = np.empty((b.shape[0], 1))
    for i in range(b.shape[0]):
        B[i, 0] = b[i]
    X, Z = _recursion_cols(J, B, sizes, n, lambda_max, eps, unit, ranks)
    x = np.empty(n)
    for i in range(n):
        x[i] = X[i, 0]
    if use_x0:
        x += Z @ (Z.T @ x0)                               # eq. (14)
    return x


def recursion(J: np.ndarray, b: np.ndarray, sizes, n: int, lambda_max: float, eps: float, x0=None,
              ranks: np.ndarray | None = None) -> np.ndarray:
    """:func:`_recursion`, compiled when :data:`ENABLED` (else the same source as Python); ``ranks`` (int64, one
    per level), when given, receives the levels' ranks."""
    use = x0 is not None
    x0 = np.ascontiguousarray(x0, dtype=float) if use else _NO_X0
    ranks = np.empty(len(sizes), dtype=np.int64) if ranks is None else ranks
    if _jit.ENABLED:
        s = _SIZES.get(sizes) if _READY and type(sizes) is tuple else None
        if s is not None or (s := _sizes(sizes)) is not None:
            return _recursion(J, b, s, n, float(lambda_max), float(eps), _UNIT, x0, use, ranks)
    return _recursion(J, b, np.asarray(sizes, dtype=np.int64), n, float(lambda_max), float(eps), _UNIT, x0, use,
                      ranks)


def _tpm(J, b, sizes, n, lambda_max, eps, unit, margin, cond, x0, use_x0, out, pivot_svd=False):
    """``out <- x`` of TPM: the factorization's kernel (:func:`_past_rank` when ``m > n``, else :func:`_general`,
    and :func:`_general_svd` when a pivot block needs its SVD, or at once with ``pivot_svd``) and, on a stack it does
    not take (a singular pivot, a certificate that cannot decide), the recursion (:func:`_recursion`: the same answer
    where both apply, the exact one where a pivot is singular). Returns :data:`FACTORED` or :data:`RECURSION`, the
    path that answered. Python calling the kernels, not a kernel: one kernel holding them all would compile them all
    on a process's first solve (~15 s of CPU on a first run); this way numba compiles the branch a stack takes, and
    the recursion when it answers."""
    if J.shape[0] > n:                                 # rank n reached before the last level: x0 has no effect
        status = _past_rank(J, b, sizes, n, lambda_max, eps, unit, margin, cond, out)
    else:
        status = PIVOT_SVD if pivot_svd else _general(J, b, sizes, x0, use_x0, lambda_max, eps, unit, out)
        if status == PIVOT_SVD:
            status = _pivot_svd()(J, b, sizes, x0, use_x0, lambda_max, eps, unit, out)
    if status == SOLVED:
        return FACTORED
    ranks = np.empty(sizes.shape[0], dtype=np.int64)
    out[:] = _recursion(J, b, sizes, n, lambda_max, eps, unit, x0, use_x0, ranks)
    return RECURSION


def tpm(J: np.ndarray, b: np.ndarray, sizes, n: int, lambda_max: float, eps: float, x0=None,
        pivot_svd: bool = False) -> np.ndarray:
    """TPM of a stacked, checked stack (:func:`hqp_tpm.solvers.tpm.tpm_stacked`): :func:`_tpm`, its kernels
    compiled when :data:`ENABLED`, else the same source as Python (its loops are made for the compiler: ~2-8 ms a
    solve; it decides every pivot in one pass, :func:`_general_svd`). ``pivot_svd``: :func:`_general` already handed
    these arrays back (:data:`PIVOT_SVD`)."""
    use = x0 is not None
    x0 = np.ascontiguousarray(x0, dtype=float) if use else _NO_X0
    out = np.empty(n)
    if _jit.ENABLED:
        s = _SIZES.get(sizes) if _READY and type(sizes) is tuple else None
        if s is not None or (s := _sizes(sizes)) is not None:
            _tpm(J, b, s, n, float(lambda_max), float(eps), _UNIT, MARGIN, COND, x0, use, out, pivot_svd)
            return out
    _tpm_py(J, b, np.asarray(sizes, dtype=np.int64), n, float(lambda_max), float(eps), _UNIT, MARGIN, COND, x0, use,
            out, True)
    return out


_tpm_py = _tpm  # (the same function: _tpm is no kernel; its callees are the module's kernels)


_jit.share_switch(__name__)  # ENABLED, AVAILABLE: hqp_tpm._jit's

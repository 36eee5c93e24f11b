"""The SNS-TPM loop in one kernel (private to :mod:`hqp_tpm.solvers`; compiled by numba when
:data:`hqp_tpm._jit.ENABLED`, else the same source runs as Python).

:func:`sns_tpm_loop` runs :func:`hqp_tpm.solvers.sns.sns_tpm` (papers/002 Algorithm 1, eq. (4)) in one call, the
scale factor and the most critical joint computed joint by joint (:func:`_pick`), the best scaled solution and the
clip into the exact box at the end:

* ``m > n`` (the extension of :mod:`hqp_tpm.solvers.sns`): the TPM of the stack by the full-rank shortcut
  :func:`hqp_tpm.solvers._compiled._past_rank` and of each free-column stack ``J W`` by the same shortcut on the
  upper levels' QR *downdated* when a joint saturates (Givens rotations on an explicit basis, below; the
  certificates of ``_past_rank`` on the downdated factors, damped pivots by the SVD of their blocks, the solution
  map measured with those damped inverses: ``_past_rank_certify``'s ``damped_map``; when a level
  above crosses rank, its factors are already in the downdated ``R~``: :func:`_downdated_views`). Where the
  shortcut's certificates do not take a stack (a singular or nearly singular pivot above the crossing level, a
  crossing level without a clear full column rank), the recursion :func:`hqp_tpm.solvers._compiled._recursion_cols`
  solves it, both right-hand sides of a pass with one SVD per level, and reports the first level's rank for the
  rank test; the later passes downdate the first pass's QR also where the recursion answered the first pass (the
  QR exists unless a pivot of ``R1`` is zero), so they keep the downdated passes' certificate;
* ``m <= n``: ``F`` (``I``, or Steps 1-4 of papers/000 when a pivot is damped or singular) by
  :func:`hqp_tpm.solvers._compiled._general_factors`, the first pass's ``x`` by ``Q R^{-T} F b`` (or the recursion
  when a pivot is singular), ``(J W)#`` by the QR of ``(D J W)^T`` and the rank test ``rank(J W) < m`` of
  Algorithm 1 on ``D J W`` (``min |r_jj| <= tol`` loses rank, ``1/||R^-1||_F > tol`` keeps it; between the two,
  the SVD of ``D J W`` decides and applies ``(J W)#``).

Each pass after a saturation solves one right-hand side, ``x = (J W)# (xd - J xN) + xN``; ``a = (J W)# xd`` (and
``b = x - a``) only when ``x`` leaves the box, so the last pass costs one solve instead of two (the downdated
factors solve both at once: one sweep of ``Q~``).

No stack leaves the kernel inside a solve; it returns :data:`BAD_BOX` (the caller raises the box's typed error) or
:data:`SHIFT` (no scale factor in ``[0, 1]`` keeps a box without 0: the caller solves around the box point,
``_around_box_point`` of :mod:`hqp_tpm.solvers.sns`, by this kernel again). :data:`DECLINED` and :data:`RESUME`
are no longer returned (kept for the callers that test for them).

``tests/test_compiled_sns.py`` proves it equal to ``sns_tpm_reference`` (Algorithm 1 as written) compiled and as
Python.
"""

from __future__ import annotations

import math

import numpy as np

from hqp_tpm import _jit
from hqp_tpm._jit import kernel as _kernel  # the package's one kernel decorator
from hqp_tpm.solvers import _compiled

#: Outcomes: solved; the box is not valid; (no longer returned); no scale factor in ``[0, 1]`` kept the box (the
#: box-point shift); (no longer returned).
DONE, BAD_BOX, DECLINED, SHIFT, RESUME = 0, 1, 2, 3, 4

_READY = False


def _inlined(fn):
    """A kernel numba inlines where compiled code calls it (as :func:`_compiled._inlined`)."""
    return _kernel(fn, inline=True)


def _compile() -> None:
    """Compile :mod:`hqp_tpm.solvers._compiled` first (its kernels are called from here), then this module's
    (:func:`hqp_tpm._jit.compile_module`: its cache directory is keyed by both files, so a changed callee is
    compiled again in every caller)."""
    global _READY
    if not _compiled._READY:
        _compiled._compile()
    if not _jit.compile_module(globals()):
        raise ImportError("numba cannot be imported")
    _READY = True

# ----------------------------------------------------------------------------------------
# Building blocks: hqp_tpm.solvers._compiled's QR kernels (_householder_rows, _triangular_inverse, _fro_block,
# _solve_upper_t, _apply_q), called from here.
# ----------------------------------------------------------------------------------------
@_kernel
def _q_rinv_t(V, tau, R, c, out):
    """``out <- Q R^{-T} c`` (``(J W)# c`` when ``(J W)^T = Q R``, :func:`_compiled._householder_rows` on
    ``V = J W``)."""
    p = V.shape[0]
    out[:p] = _compiled._solve_upper_t(R, c)
    out[p:] = 0.0
    _compiled._apply_q(out, V, tau, p)


@_kernel
def _svd_solve(U, sv, Vt, c, out):
    """``out <- V diag(1/sv) U^T c`` (``(D J W)# c`` from the SVD of ``D J W``)."""
    k = sv.shape[0]
    t = np.empty(k)
    for j in range(k):
        s = 0.0
        for i in range(U.shape[0]):
            s += U[i, j] * c[i]
        t[j] = s / sv[j]
    for f in range(Vt.shape[1]):
        s = 0.0
        for j in range(k):
            s += Vt[j, f] * t[j]
        out[f] = s


@_kernel
def _gather_free(J, free, out):
    """``out <- J W``: the columns of ``J`` whose ``free`` flag is set, in order."""
    m, n = J.shape
    f = 0
    for t in range(n):
        if free[t]:
            for i in range(m):
                out[i, f] = J[i, t]
            f += 1


@_kernel
def _saturated_rows(J, order, t0, nsat, xN, c):
    """``c <- c + J xN`` over the joints ``order[t0:nsat]`` saturated since ``c`` was last updated (``c = J xN`` over
    the saturated joints in saturation order, kept from one saturation to the next: the same sums, term by term)."""
    for i in range(J.shape[0]):
        s = c[i]
        for t in range(t0, nsat):
            s += J[i, order[t]] * xN[order[t]]
        c[i] = s


@_kernel
def _free_columns(J, free, nf, tol, V, tau, R, rw):
    """The rank test ``rank(J W) = m`` (module doc): the QR of ``(D J W)^T`` into ``V`` (``m x nf``), ``tau``,
    ``R``, ``D = diag(rw)`` the rows' level weights (``row_weights``). Returns 1 (rank ``m``: ``1/||R^-1||_F > tol``),
    0 (rank lost: ``min |r_jj| <= tol``) or -1 (only an SVD decides: hand back)."""
    m = J.shape[0]
    if nf < m:
        return 0
    _gather_free(J, free, V)
    for i in range(m):
        for f in range(nf):
            V[i, f] *= rw[i]
    _compiled._householder_rows(V, tau, R)
    dmin = math.inf
    for i in range(m):
        dmin = min(dmin, abs(R[i, i]))
    if dmin <= tol:                                    # sigma_min <= min |r_jj|
        return 0
    Rinv = _compiled._triangular_inverse(R)
    if 1.0 / _compiled._fro_upper(Rinv, 0, m) > tol:  # <= sigma_min
        return 1
    return -1


# ----------------------------------------------------------------------------------------
# m > n: the upper levels' QR downdated when a joint saturates (instead of refactorizing J W).
#
# After s saturations the factorization is kept in "extended" coordinates: Q~ (n x n, orthogonal; kept explicitly
# as QT = Q~^T, its columns as rows: :func:`_basis` builds it from the first pass's Householder reflectors), R~
# (n x m1, its rows s .. s + m1 - 1 hold R1) and C~^T = (J_k Q~)^T (n x mk). The factorization of J_<k W^T is
# Q~[free rows, s:] R1 and J_k W Q~[free rows, s:] = C~[:, s:]. Saturating joint j: rotate coordinates
# (i, i + 1), i = n - 2 .. s, so that row j of Q~ becomes (.., +-1, 0, ..) at coordinate s; then coordinate s
# (and row j) drop out: R~'s row s and C~'s column s belong to joint j alone (Golub & Van Loan, deleting a row
# of a QR factorization). Orthogonal rotations: backward stable, as the refactorization.
# ----------------------------------------------------------------------------------------
@_kernel
def _basis(V, tau, p, n):
    """``QT = Q^T`` (``n x n``, row ``c`` = column ``c`` of ``Q = H_0 ... H_{p-1}``), ``H_i`` the ``p`` reflectors of
    ``V`` (:func:`_compiled._householder_rows`): ``Q^T = H_{p-1} ... H_0`` applied to ``I``, each reflector to whole
    contiguous rows (``M <- M - tau_i v (v^T M)``)."""
    QT = np.zeros((n, n))
    for i in range(n):
        QT[i, i] = 1.0
    w = np.empty(n)
    for i in range(p):
        ti = tau[i]
        if ti == 0.0:
            continue
        for t in range(n):                             # w = v^T M (v = (1, V[i, i+1:]) on rows i..)
            w[t] = QT[i, t]
        for c in range(i + 1, n):
            vc = V[i, c]
            for t in range(n):
                w[t] += vc * QT[c, t]
        for t in range(n):
            w[t] *= ti
            QT[i, t] -= w[t]
        for c in range(i + 1, n):
            vc = V[i, c]
            for t in range(n):
                QT[c, t] -= vc * w[t]
    return QT


@_inlined
def _rotate_rows(X, i, c, sv):
    """Rows ``i``, ``i + 1`` of ``X`` <- ``(c X_i + s X_{i+1}, c X_{i+1} - s X_i)`` (a rotation of coordinates
    ``(i, i + 1)`` applied to the rows of ``Q~^T``, ``C~^T`` or ``R~``)."""
    for t in range(X.shape[1]):
        x0 = X[i, t]
        x1 = X[i + 1, t]
        X[i, t] = c * x0 + sv * x1
        X[i + 1, t] = c * x1 - sv * x0


@_kernel
def _downdate(j, QT, CT, Rt, s, p, w):
    """Saturation ``s`` of joint ``j``: the rotations of coordinates ``(i, i + 1)``, ``i = n - 2 .. s``, that turn
    ``w`` (``Q~``'s row ``j``, read from ``QT``) into ``+-e_s``, applied to the rows of ``QT = Q~^T``, of
    ``CT = (J_k Q~)^T`` (none when it has no rows: no longer read) and of ``Rt = R~`` (``p`` rows of ``R1`` from row
    ``s``)."""
    n = QT.shape[0]
    for i in range(s, n):
        w[i] = QT[i, j]
    ct = CT.shape[0] > 0
    for i in range(n - 2, s - 1, -1):
        w0 = w[i]
        w1 = w[i + 1]
        if w1 == 0.0:
            continue
        h = math.sqrt(w0 * w0 + w1 * w1)               # (|w| <= 1: a row of Q~; hypot where the squares underflow)
        if h < 1e-150:
            h = math.hypot(w0, w1)
        c = w0 / h
        sv = w1 / h
        w[i] = h
        w[i + 1] = 0.0
        _rotate_rows(QT, i, c, sv)
        if ct:
            _rotate_rows(CT, i, c, sv)
        if i < s + p:                                  # rows of R~ below s + p are zero
            _rotate_rows(Rt, i, c, sv)


@_kernel
def _level_colsq(J, sizes):
    """``S[lev, t] = sum_i J[i, t]^2`` over the rows ``i`` of level ``lev`` (as :func:`_compiled._sumsq_rows` leaves
    them in its ``acc``)."""
    n = J.shape[1]
    nlev = sizes.shape[0]
    S = np.empty((nlev, n))
    a = 0
    for lev in range(nlev):
        e = a + sizes[lev]
        _compiled._sumsq_rows(J, a, e, S[lev])
        a = e
    return S


@_inlined
def _downdated_views(CT, Rt, nsat, k, m1, mk, k0):
    """``(R1, BT)`` of the crossing level ``k`` (``m1`` rows above it, ``mk`` its own) of ``J W`` in the downdated
    factorization (saturation ``nsat``): ``R~``'s rows ``nsat ..`` and, for ``k`` = the first pass's crossing level
    ``k0``, ``C~^T``; for a level ``k < k0`` (fewer free joints than the rows above ``k0``) ``R~`` holds both: its
    leading ``m1`` columns stay upper triangular under the row deletions (the QR of ``J_<k W^T``) and its columns of
    level ``k`` are ``(J_k Q~)^T``. So the downdates go on when another level crosses rank."""
    R1 = Rt[nsat:nsat + m1, 0:m1]
    if k == k0:
        return R1, CT[nsat:, 0:mk]
    return R1, Rt[nsat:, m1:m1 + mk]


@_kernel
def _downdated_factor(J, sizes, colsq, free, nsat, k, m1, mk, R1, BT, lambda_max, eps, unit, margin, cond):
    """The TPM of ``J W`` (its free columns, in order) from the downdated factorization (``R1``, ``BT``:
    :func:`_downdated_views`): ``_past_rank``'s certificates on it and the crossing level's factors, ``(status, AT,
    tauA, RA, DV, Dtau, DR, Dp, blk)``."""
    m, n = J.shape
    nf = n - nsat
    r = nf - m1
    for i in range(m1):
        if R1[i, i] == 0.0:
            return (_compiled.DECLINED, np.empty((0, 0)), np.empty(0), np.empty((0, 0)), *_compiled._no_damping())
    nlev = sizes.shape[0]
    sq = np.empty(nlev)                                # ||J_lev W||_F^2: the free columns' sums of squares, in order
    for lev in range(nlev):
        total = 0.0
        for t in range(n):
            if free[t]:
                total += colsq[lev, t]
        sq[lev] = total
    status, AT, tauA, RA, Dp, blk, lam = _compiled._past_rank_certify(R1, BT, sq, sizes, k, m1, mk, r, max(m, nf),
                                                                      lambda_max, eps, unit, margin, cond, True)
    if status != _compiled.SOLVED:
        return (status, AT, tauA, RA, *_compiled._no_damping())
    DV, Dtau, DR = _compiled._crossing_damping(RA, lam)
    return status, AT, tauA, RA, DV, Dtau, DR, Dp, blk


@_inlined
def _crossing_rhs2(b1, b2, m1, mk, r, R1, BT, AT, tauA, RA, DV, Dtau, DR, Dp, blk, sc, o1, o2):
    """:func:`hqp_tpm.solvers._compiled._crossing_rhs` of two right-hand sides at once: ``o1[:m1 + r] <- [z; y]`` of
    ``b1``, ``o2`` of ``b2``. Each right-hand side takes the sums of ``_crossing_rhs`` term by term, in the same order
    (the same bits); the two run in one loop (two independent chains of the substitutions, whose divisions and
    additions wait on each other within one), into ``sc``'s rows 4.. (scratch of length ``>= max(m1, mk)``: no
    allocation)."""
    c1, c2, res1, res2, d1, d2 = sc[4], sc[5], sc[6], sc[7], sc[8], sc[9]
    if Dp.shape[0]:                                    # a damped pivot above the crossing level: _pivot_forward
        a = 0
        while a < m1:
            e = a + 1
            while e < m1 and blk[e] == a:
                e += 1
            for i in range(a, e):
                s1 = b1[i]
                s2 = b2[i]
                for t in range(a):
                    s1 -= R1[t, i] * o1[t]
                    s2 -= R1[t, i] * o2[t]
                c1[i] = s1
                c2[i] = s2
            for i in range(a, e):
                s1 = 0.0
                s2 = 0.0
                for t in range(a, e):
                    s1 += Dp[t, i] * c1[t]
                    s2 += Dp[t, i] * c2[t]
                o1[i] = s1
                o2[i] = s2
            a = e
    else:                                              # _solve_upper_t
        for i in range(m1):
            s1 = b1[i]
            s2 = b2[i]
            for t in range(i):
                s1 -= R1[t, i] * o1[t]
                s2 -= R1[t, i] * o2[t]
            o1[i] = s1 / R1[i, i]
            o2[i] = s2 / R1[i, i]
    for i in range(mk):
        res1[i] = b1[m1 + i]
        res2[i] = b2[m1 + i]
    for t in range(m1):                                # res_i = b_i - sum_t (J_k Q1)[i, t] z_t (t ascending)
        z1 = o1[t]
        z2 = o2[t]
        for i in range(mk):
            res1[i] -= BT[t, i] * z1
            res2[i] -= BT[t, i] * z2
    for i in range(r):                                 # _apply_qt: Q_A^T res (_reflect's sums)
        ti = tauA[i]
        if ti == 0.0:
            continue
        t0 = i + 1
        cc = mk - t0
        w1 = res1[i] + _compiled._dot(AT[i], res1, t0, cc)
        w2 = res2[i] + _compiled._dot(AT[i], res2, t0, cc)
        w1 *= ti
        w2 *= ti
        res1[i] -= w1
        res2[i] -= w2
        for tt in range(cc):
            res1[t0 + tt] -= w1 * AT[i, t0 + tt]
            res2[t0 + tt] -= w2 * AT[i, t0 + tt]
    U = RA
    if DR.shape[0]:                                    # the crossing level damped: _damped_solve's Q^T [c; 0]
        U = DR
        for t in range(r):
            d1[t] = 0.0
            d2[t] = 0.0
        for i in range(r):
            ti = Dtau[i]
            if ti == 0.0:
                continue
            w1 = res1[i] + _compiled._lower_dot(DV[i], d1, i, r)
            w2 = res2[i] + _compiled._lower_dot(DV[i], d2, i, r)
            w1 *= ti
            w2 *= ti
            res1[i] -= w1
            res2[i] -= w2
            for t in range(i + 1):
                d1[t] -= w1 * DV[i, t]
                d2[t] -= w2 * DV[i, t]
    for i in range(r - 1, -1, -1):                     # _solve_upper
        s1 = res1[i]
        s2 = res2[i]
        for t in range(i + 1, r):
            s1 -= U[i, t] * o1[m1 + t]
            s2 -= U[i, t] * o2[m1 + t]
        o1[m1 + i] = s1 / U[i, i]
        o2[m1 + i] = s2 / U[i, i]


@_kernel
def _downdated_rhs(r1, r2, free, nsat, m1, mk, QT, R1, BT, AT, tauA, RA, DV, Dtau, DR, Dp, blk, sc, x1, x2):
    """``x1 <- (J W)# r1``, ``x2 <- (J W)# r2`` (the free joints' entries, in order) from :func:`_downdated_factor`'s
    factors (``m1``, ``mk``: the crossing level's): ``x = Q~ [0; z; y]``, ``Q~ = QT^T``, both in one sweep of ``QT``
    (``sc``: scratch, ``10 x max(m, n)``)."""
    n = free.shape[0]
    r = n - nsat - m1
    v1, v2, acc1, acc2 = sc[0], sc[1], sc[2], sc[3]
    _crossing_rhs2(r1, r2, m1, mk, r, R1, BT, AT, tauA, RA, DV, Dtau, DR, Dp, blk, sc, v1[nsat:], v2[nsat:])
    for t in range(n):
        acc1[t] = 0.0
        acc2[t] = 0.0
    for c in range(nsat, n):                           # x = sum_c v_c Q~[:, c] (rows of QT, contiguous)
        c1 = v1[c]
        c2 = v2[c]
        for t in range(n):
            acc1[t] += c1 * QT[c, t]
            acc2[t] += c2 * QT[c, t]
    f = 0
    for t in range(n):
        if free[t]:
            x1[f] = acc1[t]
            x2[f] = acc2[t]
            f += 1


@_kernel
def _refactor(Jf, sizes, nf, lambda_max, eps, unit, margin, cond):
    """:func:`_compiled._past_rank_factor` of ``J W`` (its free columns ``Jf``), called (not inlined) from the loop."""
    return _compiled._past_rank_factor(Jf, sizes, nf, lambda_max, eps, unit, margin, cond, False)


@_kernel
def _refactored_rhs(rhs, m1, mk, r, V, tau, R1, BT, AT, tauA, RA, DV, Dtau, DR, Dp, blk, lambda_max, eps, xf):
    """``xf <- (J W)# rhs`` from :func:`_refactor`'s factors (:func:`_compiled._past_rank_rhs`)."""
    _compiled._past_rank_rhs(rhs, m1, mk, r, V, tau, R1, BT, AT, tauA, RA, DV, Dtau, DR, Dp, blk, lambda_max, eps,
                             xf)


@_kernel
def _pick(a, b, lo, up, wlo, wup, free, viol, smax):
    """``(factor, j)``: the task scale factor and the most critical joint, joint by joint (the numbers of the
    reference's ``sns._scaling`` then ``sns._critical_joint``; ``tests/test_sns.py`` holds them equal)."""
    n = a.shape[0]
    for j in range(n):
        smax[j] = math.inf
    factor = 0.0
    decided = False
    for j in range(n):                                 # saturated joints must sit inside, at s = 0 and s = 1
        if not free[j]:
            bj = b[j]
            s1 = a[j] + bj
            if not (wlo[j] <= bj <= wup[j] and wlo[j] <= s1 <= wup[j]):
                factor = -1.0
                decided = True
                break
    if not decided:
        for j in range(n):                             # s has no effect on a joint outside the box
            if free[j] and a[j] == 0.0 and not (wlo[j] <= b[j] <= wup[j]):
                smax[j] = -math.inf
                factor = -1.0
                decided = True
    if not decided:
        s_hi_w, s_lo, s_hi, any_idx = math.inf, -math.inf, math.inf, False
        for j in range(n):
            aj = a[j]
            if free[j] and aj != 0.0:
                any_idx = True
                bj = b[j]
                if aj > 0.0:
                    sm, sw, sl = (up[j] - bj) / aj, (wup[j] - bj) / aj, (wlo[j] - bj) / aj
                else:
                    sm, sw, sl = (lo[j] - bj) / aj, (wlo[j] - bj) / aj, (wup[j] - bj) / aj
                smax[j] = sm
                s_hi, s_hi_w, s_lo = min(s_hi, sm), min(s_hi_w, sw), max(s_lo, sl)
        if not any_idx:
            factor = 1.0
        else:
            s_lo = max(s_lo, 0.0)
            factor = -1.0 if s_lo > min(s_hi_w, 1.0) else max(min(s_hi, 1.0), s_lo)
    j = 0                                              # first argmin, as np.argmin
    for k in range(1, n):
        if smax[k] < smax[j]:
            j = k
    if not (free[j] and viol[j]):
        j = -1
        for k in range(n):
            if free[k] and viol[k] and (j < 0 or smax[k] < smax[j]):
                j = k
    return factor, j


@_kernel
def _sns_loop(J, xd, sizes, lo, up, lambda_max, eps, unit, margin, cond, x, order, state, nwarm=0):
    """SNS-TPM of a stack ``J`` under ``lo <= x <= up``: ``x``, ``order[:nsat]`` the saturated joints (module doc:
    ``m > n`` the extension, each ``J W`` by the full-rank shortcut or the recursion; ``m <= n`` the paper's loop).

    Returns ``(status, scale, nsat, iterations, feasible, nrec)``; ``status`` :data:`DONE`, :data:`BAD_BOX` or
    :data:`SHIFT` (``iterations``: the passes made); ``nrec``: the passes whose TPM (or ``(J W)#``) the recursion
    (or an SVD) gave, where the factorization's certificates did not decide (before, the kernel handed those
    stacks back to numpy). ``state``: not used (the callers' buffer of earlier versions). ``nwarm``: the measurement
    of a warm start (benchmarks/romeo_damped.py; not used by the solvers): at the first saturation, the joints
    ``order[:nwarm]`` (a previous call's) that are beyond a bound are saturated at once, then the algorithm goes on.
    """
    m, n = J.shape
    warm = order[:nwarm].copy()
    for j in range(n):                                 # _box's test (NaN fails it): else the typed error
        if not (lo[j] <= up[j] and lo[j] < math.inf and up[j] > -math.inf):
            return BAD_BOX, 0.0, 0, 0, False, 0
    extended = m > n
    nlev = sizes.shape[0]
    ranks = np.empty(nlev, dtype=np.int64)             # the recursion's ranks of the levels
    no_x0 = np.empty(0)
    rec = False                                        # this pass's TPM by the recursion (m > n)
    nrec = 0                                           # passes whose TPM or (J W)# took the recursion or an SVD
    k_fit = True                                       # m > n: the rank test watches the first level
    if extended:                                       # _past_rank, its factors kept for the downdates
        (status, m1, mk, r, PV, Ptau, PR1, PBT, PAT, PtauA, PRA, PDV, PDtau, PDR, PDp,
         Pblk) = _compiled._past_rank_factor(J, sizes, n, lambda_max, eps, unit, margin, cond, False)
        k0 = _compiled._crossing_level(sizes, n)[0]
        rec = status != _compiled.SOLVED
        nrec += rec
        if rec:                                        # a pivot the shortcut does not take: the recursion
            x[:] = _compiled._recursion(J, xd, sizes, n, lambda_max, eps, unit, no_x0, False, ranks)
            k_fit = ranks[0] == sizes[0]
        else:
            _compiled._past_rank_rhs(xd, m1, mk, r, PV, Ptau, PR1, PBT, PAT, PtauA, PRA, PDV, PDtau, PDR, PDp,
                                     Pblk, lambda_max, eps, x)
            k_fit = not sizes[0] > n
    else:
        m1, mk, k0 = 0, 0, 0
        PV, Ptau, PR1, PBT = np.empty((0, n)), np.empty(0), np.empty((0, 0)), np.empty((n, 0))
    Fb = np.empty((0, 0))                              # m <= n: Fbar (F = Fbar^T) when a pivot is damped
    Fxd = np.empty(0 if extended else m)               # F xd
    damped = False
    if not extended:                                   # the general path's factorization
        status, damped, V0, tau0, R0, Fb = _compiled._general_factors(J, sizes, lambda_max, eps, unit, True)
        if damped:
            _compiled._f_times(Fb, xd, Fxd)
        else:
            Fxd[:] = xd
        if status == _compiled.SINGULAR:               # x = J# F xd is not exact there: the recursion's x
            nrec += 1
            x[:] = _compiled._recursion(J, xd, sizes, n, lambda_max, eps, unit, no_x0, False, ranks)
        else:
            _q_rinv_t(V0, tau0, R0, Fxd, x)            # x = J# F xd
    inside = True
    for j in range(n):
        if not (x[j] >= lo[j] and x[j] <= up[j]):
            inside = False
            break
    if inside:                                         # no bound reached: the TPM solution
        return DONE, 1.0, 0, 1, True, nrec
    scale = 0.0                                        # _Box: the largest finite bound, the widened box
    for j in range(n):
        if math.isfinite(lo[j]):
            scale = max(scale, abs(lo[j]))
        if math.isfinite(up[j]):
            scale = max(scale, abs(up[j]))
    if not scale > 0.0:
        scale = 1.0
    ws = np.empty((13, n))                             # the loop's vectors: one allocation, a row each
    tlo, tup, wlo, wup, xN, a, b, smax, best_a, best_b, xf, yf, w = (ws[0], ws[1], ws[2], ws[3], ws[4], ws[5],
                                                                     ws[6], ws[7], ws[8], ws[9], ws[10], ws[11],
                                                                     ws[12])
    sc = np.empty((10, max(m, n)))                     # (_downdated_rhs's scratch)
    for j in range(n):
        tlo[j] = 1e-10 * (scale + abs(lo[j]))          # sns.VIOLATION_TOL
        tup[j] = 1e-10 * (scale + abs(up[j]))
        wlo[j] = lo[j] - tlo[j]
        wup[j] = up[j] + tup[j]
    free = np.ones(n, dtype=np.bool_)
    viol = np.zeros(n, dtype=np.bool_)
    xN[:] = 0.0
    a[:] = x
    b[:] = 0.0
    best_s = 0.0
    best_nsat = 0
    found = False
    nsat = 0
    iterations = 0
    Jf = np.empty((m, 0))
    mg = 0 if extended else m                          # (the general path's arrays: empty when extended)
    rw = np.ones(m)                                    # row_weights: rank(J W) on unit levels (m <= n)
    nz = 0
    a0 = 0
    for k in range(sizes.shape[0]):
        e0 = a0 + sizes[k]
        nrm = _compiled._fro_block(J, a0, e0, 0, n)
        if nrm > 0.0:
            nz += 1
            for i in range(a0, e0):
                rw[i] = 1.0 / nrm
        a0 = e0
    tol = 0.0 if extended else unit * max(m, n) * math.sqrt(nz)
    wFxd = np.empty(Fxd.shape[0])
    for i in range(Fxd.shape[0]):
        wFxd[i] = rw[i] * Fxd[i]
    V = np.empty((mg, n))
    tau = np.empty(mg)
    R = np.zeros((mg, mg))
    c = np.zeros(m)                                    # J xN
    Fc = np.empty(mg)
    downdating = extended                              # the first pass's factors exist (its QR of J_<k^T and
    for i in range(m1):                                # (J_k Q)^T), also where the recursion answered its TPM:
        downdating = downdating and PR1[i, i] != 0.0   # not where a zero pivot stopped them (no (J_k Q)^T)
    Xr = np.empty((0, 2))                              # rec: (J W)# F_W [xd - J xN, xd] by the recursion
    SU, Ssv, SVt = np.empty((0, 0)), np.empty(0), np.empty((0, 0))   # m <= n: the SVD of D J W when the QR
    use_svd = False                                                 # cannot decide its rank
    CT = np.empty((0, 0))
    Rt = np.empty((0, 0))
    dm1, dmk = 0, 0                                    # the downdated factorization's crossing level: rows above, its
    DR1, DBT = _downdated_views(CT, Rt, 0, 0, 0, 0, 0)  # rows, R1 and (J_k Q~)^T (views of Rt, CT)
    QT = np.empty((0, 0))                              # Q~^T (the downdated basis, explicit)
    colsq = np.empty((0, 0))
    # the free-column stack's factors (the downdated ones, or J W's own when refactorized): set at each saturation
    none2, none1 = np.empty((0, 0)), np.empty(0)     # (placeholders: two allocations, not ten)
    AT, tauA, RA, DV, Dtau, DR, Dp = none2, none1, none2, none2, none1, none2, none2
    blk = np.empty(0, dtype=np.int64)
    FV, Ftau, FR1, FBT = none2, none1, none2, none2
    fm1, fmk, fr = 0, 0, 0
    dc = c.copy()                                      # xd - J xN (F applied when damped)
    while True:
        iterations += 1
        if nsat:                                       # x = (J W)# F_W (xd - J xN) + xN: one right-hand side; a (and
            nf = n - nsat                              # b = x - a) below, only if a bound is violated (downdated:
                                                       # both at once)
            if not extended:                           # (c = J xN: updated at the saturation)
                if damped:                             # F (J xN)
                    _compiled._f_times(Fb, c, Fc)
                    for i in range(m):
                        dc[i] = Fxd[i] - Fc[i]
                else:
                    for i in range(m):
                        dc[i] = Fxd[i] - c[i]
                for i in range(m):
                    dc[i] *= rw[i]                     # (J W)# = (D J W)# D
                if use_svd:
                    _svd_solve(SU, Ssv, SVt, dc, yf[:nf])
                else:
                    _q_rinv_t(V[:, :nf], tau, R, dc, yf[:nf])
            else:
                for i in range(m):
                    dc[i] = xd[i] - c[i]
                if rec:
                    yf[:nf] = Xr[:, 0]
                elif downdating:                       # (and a = (J W)# xd, read below if a bound is violated)
                    _downdated_rhs(dc, xd, free, nsat, dm1, dmk, QT, DR1, DBT, AT, tauA, RA, DV, Dtau, DR, Dp, blk,
                                   sc, yf, xf)
                else:
                    _refactored_rhs(dc, fm1, fmk, fr, FV, Ftau, FR1, FBT, AT, tauA, RA, DV, Dtau, DR, Dp, blk,
                                    lambda_max, eps, yf[:nf])
            f = 0
            for j in range(n):
                if free[j]:
                    x[j] = yf[f]
                    f += 1
                else:
                    x[j] = xN[j]
        anyv = False
        for j in range(n):
            viol[j] = x[j] < wlo[j] or x[j] > wup[j]
            anyv = anyv or viol[j]
        if not anyv:
            for j in range(n):
                x[j] = min(max(x[j], lo[j]), up[j])
            return DONE, 1.0, nsat, iterations, True, nrec
        if nsat:                                       # a = (J W)# F_W xd, b = x - a (b = xN - (J W)# F_W J xN)
            if not extended:
                if use_svd:
                    _svd_solve(SU, Ssv, SVt, wFxd, xf[:nf])
                else:
                    _q_rinv_t(V[:, :nf], tau, R, wFxd, xf[:nf])
            elif rec:
                xf[:nf] = Xr[:, 1]
            elif downdating:
                pass                                   # (xf: solved with x above)
            else:
                _refactored_rhs(xd, fm1, fmk, fr, FV, Ftau, FR1, FBT, AT, tauA, RA, DV, Dtau, DR, Dp, blk,
                                lambda_max, eps, xf[:nf])
            f = 0
            for j in range(n):
                if free[j]:
                    a[j] = xf[f]
                    b[j] = x[j] - a[j]
                    f += 1
                else:
                    a[j] = 0.0
                    b[j] = xN[j]
        factor, j = _pick(a, b, lo, up, wlo, wup, free, viol, smax)
        if factor >= 0.0 and (not found or factor > best_s):
            best_s, best_nsat, found = factor, nsat, True
            best_a[:] = a
            best_b[:] = b
        stop = j < 0
        if j >= 0:
            n0 = nsat
            if nsat == 0 and nwarm > 0:                # (warm start: the previous call's joints beyond a bound)
                for t in range(nwarm):
                    jj = warm[t]
                    if free[jj] and viol[jj]:
                        free[jj] = False
                        xN[jj] = up[jj] if x[jj] > up[jj] else lo[jj]
                        order[nsat] = jj
                        nsat += 1
                if nsat > 1:
                    downdating = False
                if nsat:
                    j = order[nsat - 1]
            if free[j]:
                free[j] = False
                xN[j] = up[j] if x[j] > up[j] else lo[j]
                order[nsat] = j
                nsat += 1
            nf = n - nsat
            _saturated_rows(J, order, n0, nsat, xN, c)  # the next pass's J xN
            if not extended:
                rank = _free_columns(J, free, nf, tol, V[:, :nf], tau, R, rw)
                use_svd = rank < 0
                nrec += use_svd
                if use_svd:                            # only an SVD decides rank(J W)
                    A = np.empty((m, nf))
                    _gather_free(J, free, A)
                    for i in range(m):
                        for f in range(nf):
                            A[i, f] *= rw[i]
                    SU, Ssv, SVt = np.linalg.svd(A, full_matrices=False)
                    rank = 1 if Ssv[m - 1] > tol else 0
                stop = rank == 0                       # rank(J W) < m
            elif nf == 0:
                stop = True
            else:
                if downdating:                         # the upper levels' QR downdated (saturation nsat - 1)
                    if nsat == 1:
                        CT = PBT                       # (the first pass's, not read again)
                        Rt = np.zeros((n, m1))
                        Rt[:m1] = PR1
                        QT = _basis(PV, Ptau, m1, n)
                        colsq = _level_colsq(J, sizes)
                    _downdate(j, QT, CT, Rt, nsat - 1, m1, w)
                    dk, dm1, dmk, _ = _compiled._crossing_level(sizes, nf)  # (k0, or a level above it)
                    if dk != k0:                       # (C~ is read for k0 only; the crossing level only rises)
                        CT = none2
                    DR1, DBT = _downdated_views(CT, Rt, nsat, dk, dm1, dmk, k0)
                    status, AT, tauA, RA, DV, Dtau, DR, Dp, blk = _downdated_factor(
                        J, sizes, colsq, free, nsat, dk, dm1, dmk, DR1, DBT, lambda_max, eps, unit, margin, cond)
                else:
                    Jf = np.empty((m, nf))             # J W on its free columns, in order
                    _gather_free(J, free, Jf)
                    (status, fm1, fmk, fr, FV, Ftau, FR1, FBT, AT, tauA, RA, DV, Dtau, DR, Dp,
                     blk) = _refactor(Jf, sizes, nf, lambda_max, eps, unit, margin, cond)
                rec = status != _compiled.SOLVED       # the certificates cannot decide J W: the recursion
                nrec += rec
                if rec:                                # (its TPM of J W for both right-hand sides, one SVD a level)
                    Jf = np.empty((m, nf))
                    _gather_free(J, free, Jf)
                    Bc = np.empty((m, 2))
                    for i in range(m):
                        Bc[i, 0] = xd[i] - c[i]
                        Bc[i, 1] = xd[i]
                    Xr = _compiled._recursion_cols(Jf, Bc, sizes, nf, lambda_max, eps, unit, ranks)[0]
                    stop = k_fit and ranks[0] < sizes[0]  # J_1 W loses rank
                else:
                    stop = k_fit and sizes[0] > nf     # the first level crosses rank nf: J_1 W loses rank
        if stop:
            if not found:                              # no factor kept the box: the box-point shift
                return SHIFT, 0.0, 0, iterations, False, nrec
            feasible = True
            for t in range(n):
                x[t] = best_s * best_a[t] + best_b[t]
                if x[t] < lo[t] - 2.0 * tlo[t] or x[t] > up[t] + 2.0 * tup[t]:
                    feasible = False
                x[t] = min(max(x[t], lo[t]), up[t])
            return DONE, best_s, best_nsat, iterations, feasible, nrec


def sns_tpm_loop(J, xd, sizes, lo, up, lambda_max, eps, margin=_compiled.MARGIN, cond=_compiled.COND, warm=()):
    """``(status, x, saturated, scale, iterations, feasible, nrec)`` of SNS-TPM by :func:`_sns_loop`, compiled when
    :data:`hqp_tpm._jit.ENABLED` (else the same source as Python); ``status`` :data:`DONE`, or :data:`BAD_BOX` /
    :data:`SHIFT` (the caller raises the box's typed error / solves around the box point); ``nrec``: the passes
    the recursion (or an SVD) answered inside the kernel. ``warm``: joints to saturate at once at the first
    saturation (the warm-start measurement of benchmarks/romeo_damped.py)."""
    if _jit.ENABLED and not _READY and _compiled._sizes(sizes) is not None:
        try:
            _compile()
        except ImportError:  # pragma: no cover - (_jit turned the switch off)
            pass
    s = _compiled._sizes(sizes) if _READY else np.asarray(sizes, dtype=np.int64)
    n = lo.shape[0]
    x = np.empty(n)
    order = np.empty(n, dtype=np.int64)
    order[:len(warm)] = warm
    status, scale, nsat, iterations, feasible, nrec = (_sns_loop if _jit.ENABLED else _sns_loop_py)(
        J, xd, s, lo, up, float(lambda_max), float(eps), _compiled._UNIT, margin, cond, x, order, _NO_STATE,
        len(warm))
    return status, x, tuple(order[:nsat].tolist()), scale, iterations, feasible, nrec


_NO_STATE = np.empty((3, 0))
_sns_loop_py = _sns_loop  # the Python source (the name _sns_loop becomes the dispatcher when compiled)

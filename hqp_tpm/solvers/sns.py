"""Saturation in the Null Space (SNS) under hard joint boxes ``lower <= x <= upper``.

* :func:`sns_tpm` / :func:`sns_tpm_reference`: SNS-TPM, Algorithm 1 of papers/002 with the core
  step eq. (4), ``x = x_N + (J W)# F (b - J x_N)``. ``F`` is the TPM matrix of the whole stack
  (computed once, :func:`hqp_tpm.solvers.tpm.tpm_factors`), ``W = diag(0/1)`` marks the saturated
  joints and one scale factor ``s`` applies to *all* tasks. Without an active bound the result
  is exactly :func:`hqp_tpm.solvers.tpm.tpm`. The reference path follows the algorithm line by
  line with ``n x n`` matrices; :func:`sns_tpm` runs every pass in one kernel
  (:mod:`hqp_tpm.solvers._compiled_sns`: the TPM factorization of the stack, then the columns of the
  free joints: with more rows than joints the upper levels' QR downdated by Givens rotations at each
  saturation, else one QR per saturation; the recursion or an SVD where the QR's certificates cannot
  decide). ``tests/test_sns.py`` and ``tests/test_compiled_sns.py`` prove them equal.
* :func:`sns`: the multi-task SNS of Flacco, De Luca, Khatib (T-RO 2015): level by level, higher
  first, each with its own scale factor (the largest one that keeps the box, i.e. scaled by the
  least amount); a lower level moves only in the null space of the higher ones (an orthonormal
  basis ``Z``, ``P = Z Z^T``, as in :func:`hqp_tpm.solvers.nullspace.nullspace`), so their
  saturations and task values are kept. Without an active bound it equals
  :func:`hqp_tpm.solvers.nullspace.nullspace`.

``getTaskScalingFactor`` (T-RO 2015) is :func:`task_scaling_factor`: with ``x(s) = s a + b``,
each free joint allows ``s`` in ``[smin_j, smax_j]``; the factor is the largest ``s`` in ``[0, 1]``
allowed by all free joints and the most critical joint is the argmin of ``smax_j``.

The functions are array-level: at acceleration level pass the stack ``b_i = xdd_i - Jdot_i qd``
(TPM eq. (12) of papers/000) and a box on ``qdd`` (:func:`hqp_tpm.robot.joint_boxes.acceleration_box`);
``s`` then scales the whole right-hand side ``b`` (the T-RO paper scales only ``xdd``; to do so,
keep ``-Jdot qd`` out of ``b`` and add its contribution yourself). Inequality :class:`Level`\\ s
enter through their active rows, exactly as in :func:`tpm` (:mod:`hqp_tpm.solvers.levels`).

Details the papers leave open, decided here (both paths alike):

* ``rank(J W) < m`` is literal, ``m`` the number of active rows, when ``m <= n``: a rank-deficient
  stack (conflicting or repeated tasks) stops at its first saturation and returns the best scaled
  solution.
* **Extension for stacks with more rows than joints (``m > n``)**, e.g. every whole-body stack that ends
  in a posture level. There ``rank(J W) < m`` holds from the start, so the literal algorithm would stop
  at the first saturation and return its best uniformly scaled solution (often ``s = 0``), letting the
  top-priority levels drift. Instead: the core step is the TPM solution of the stack restricted to the
  free joints, ``x = x_N + (J W)# F_W (xd - J x_N)`` with ``F_W`` the TPM matrix of ``J W`` (for a
  full-row-rank ``J W``, ``F_W = I = F``: the paper's step), and the rank test watches the first level
  only (if it has full row rank; no rank test otherwise): saturation continues while ``J_1 W`` keeps
  full row rank, the lower levels that no longer fit being solved by TPM as far as the free joints
  allow (by priority: a lower level loses exactness before a higher one), and only when the first
  level itself cannot be met is the best uniformly scaled solution returned. With ``m <= n`` nothing
  changes (the paper's algorithm); ``tests/test_sns.py`` and ``tests/test_numerics.py`` check both.
* ``s* = 0`` initially and a factor replaces it only if larger; a feasible factor of exactly 0 is
  kept the first time (with the zero command in the box that is the paper's ``W = I, x_N = 0``).
* The most critical joint is the argmin of ``smax_j``; if that joint is not beyond a bound (possible
  only when no factor is feasible) the argmin over the joints that are beyond one is used.
* Multi-task SNS: level ``k`` saturates joint ``j`` through ``((I - W_k) P_{k-1})#``; if the rows of
  ``P_{k-1}`` at the saturated joints become dependent (``REALIZABLE_TOL``) the levels above fix the
  joint through the others, the saturation cannot be realized and the level stops as on a rank
  loss. Saturated joints are set exactly on their bounds (an identity when realizable).
* Round-off: bounds are checked with the tolerance ``VIOLATION_TOL`` and the result is clipped
  into the exact box (a change of at most that tolerance).

Boxes without the zero command. If 0 is inside the box (always true for the velocity box of a
state inside its limits) the papers' algorithms return a command inside it. Otherwise (acceleration
boxes that force a joint to brake, recovery boxes) it can happen that no scale factor in ``[0, 1]``
keeps the box and the paper's fallback ``x = 0`` leaves it. Then the same algorithm is run around
``x0 = clip(0, lower, upper)``, the box point nearest to zero: ``x = x0 + dx`` with ``dx`` solving
the stack ``b_i - J_i x0`` under the box ``[lower - x0, upper - x0]``, which contains 0. The result
is inside the box, equals the papers' algorithm whenever that one succeeds, and
``info.feasible`` (SNS-TPM) / ``info.shifted`` (SNS) tells when it was needed.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, replace

import numpy as np

from hqp_tpm.errors import BoxError, ShapeError
from hqp_tpm.solvers import _compiled_sns
from hqp_tpm.solvers._kernels import row_weights
from hqp_tpm.solvers.damping import check_damping, matrix_tol, pinv, rank_tol
from hqp_tpm.solvers.levels import Level, as_levels, equality_stack, stacked
from hqp_tpm.solvers.nullspace import nullspace_stacked, projected_step
from hqp_tpm.solvers.tpm import tpm_factors

#: A joint counts as beyond a bound when it exceeds it by more than ``VIOLATION_TOL * (|bound| + B)``, ``B``
#: the box's largest finite bound (so the test does not depend on units);
#: the scale factor uses the box widened by the same amount, and the returned command is clipped
#: into the exact box (a change of at most this size, the round-off of the null-space products).
VIOLATION_TOL = 1e-10

#: Multi-task SNS: a joint can be saturated at level ``k`` only if the rows of ``P_{k-1}`` of the
#: saturated joints stay independent (smallest singular value above this); otherwise the levels
#: above fix it through the others and the level stops as on a rank loss.
REALIZABLE_TOL = 1e-6


@dataclass(frozen=True)
class SNSInfo:
    """What one SNS solve did.

    ``scale``: the task scale factor ``s`` applied (1 when no scaling was needed, 0 when the task
    could not be executed at all); ``saturated``: the joints with ``W_jj = 0`` in the returned
    command, in the order they were saturated; ``iterations``: passes through the core step;
    ``feasible``: SNS-TPM: False only if the zero command is outside the box and no scale factor in
    ``[0, 1]`` kept it: the command is then solved around the box point nearest to zero (module doc);
    one level of the multi-task SNS: False if no scale kept the box and the level was not executed.
    """

    scale: float
    saturated: tuple[int, ...]
    iterations: int
    feasible: bool = True


@dataclass(frozen=True)
class SNSStackInfo:
    """Per-level :class:`SNSInfo` of :func:`sns`; ``shifted``: solved around ``x0 = clip(0, box)``
    (module doc); ``clipped``: the command left the box by more than round-off and was clipped (seen
    only with undamped, nearly singular stacks, where ``(J_k Pbar_k)#`` amplifies round-off)."""

    levels: tuple[SNSInfo, ...]
    clipped: bool = False
    shifted: bool = False


# ----------------------------------------------------------------------------------------
# Shared pieces.
# ----------------------------------------------------------------------------------------
def _box(lower, upper, n: int | None) -> tuple[np.ndarray, np.ndarray]:
    lo = np.asarray(lower, dtype=float)
    up = np.asarray(upper, dtype=float)
    if lo.ndim != 1 or (n is not None and lo.shape[0] != n) or up.shape != lo.shape:
        expected = f"({n},) each" if n is not None else "the same 1-D shape"
        raise ShapeError(f"box has lower shape {np.shape(lower)} and upper shape {np.shape(upper)}, "
                         f"expected {expected}")
    if ((lo <= up) & (lo < np.inf) & (up > -np.inf)).all():   # the common case, one pass
        return lo, up
    for name, arr in (("lower", lo), ("upper", up)):
        if np.isnan(arr).any():
            i = int(np.flatnonzero(np.isnan(arr))[0])
            raise BoxError(f"box {name}[{i}] is NaN (joint {i})")
    i = int(np.flatnonzero((lo > up) | (lo == np.inf) | (up == -np.inf))[0])
    if lo[i] > up[i]:
        raise BoxError(f"box of joint {i} is empty: lower[{i}] = {lo[i]} > upper[{i}] = {up[i]}")
    raise BoxError(f"box of joint {i} is empty: lower[{i}] = {lo[i]}, upper[{i}] = {up[i]} "
                   f"(a finite command needs lower < inf and upper > -inf)")


def _levels(levels, n, check_finite: bool = True):
    """Validated levels whose column count must be the box's ``n`` (see :func:`as_levels`)."""
    levels = tuple(levels)
    lv = as_levels(levels, check_finite=check_finite) if levels else ()
    if lv and lv[0].n != n:
        raise ShapeError(f"the stack has {lv[0].n} columns but the box has {n} joints")
    return lv


def _stacked(levels, n):
    """Validated levels, the stacked active rows ``(J, b)`` of the whole stack and the level sizes."""
    lv, J, b, sizes, _ = stacked(_levels(levels, n, check_finite=False), n)
    return lv, J, b, sizes


def _box_scale(lo, up) -> float:
    """The box's unit: its largest finite bound in magnitude (1 if it has none but 0 and infinities)."""
    finite = np.concatenate([lo[np.isfinite(lo)], up[np.isfinite(up)]])
    scale = float(np.abs(finite).max()) if finite.size else 0.0
    return scale if scale > 0.0 else 1.0


class _Box:
    """The exact box and the box widened by round-off (``VIOLATION_TOL``), computed once per solve."""

    __slots__ = ("lo", "up", "tlo", "tup", "wlo", "wup")

    def __init__(self, lo, up):
        self.lo, self.up = lo, up
        scale = _box_scale(lo, up)
        self.tlo = VIOLATION_TOL * (scale + np.abs(lo))   # +inf for an infinite bound: never crossed
        self.tup = VIOLATION_TOL * (scale + np.abs(up))
        self.wlo = lo - self.tlo
        self.wup = up + self.tup

    def violated(self, x, k: float = 1.0) -> np.ndarray:
        """Joints beyond the box by more than ``k`` times the round-off tolerance."""
        if k == 1.0:
            return (x < self.wlo) | (x > self.wup)
        return (x < self.lo - k * self.tlo) | (x > self.up + k * self.tup)


def _scaling(a, b, box: _Box, free) -> tuple[float, np.ndarray]:
    """Task scale factor (-1 if none in [0, 1]) and the per-joint ``smax`` (``+inf`` off ``free``).

    Per free joint, ``s a_j + b_j`` is in the box for ``s`` in ``[smin_j, smax_j]`` (all ``s`` or none
    if ``a_j = 0``). Saturated joints are not scaled (``a_j = 0`` up to round-off): they only have to
    be inside, which fails only if the null space above could not put them on their bound.

    The factor is the largest ``s <= 1`` allowed by the exact box; whether some ``s``
    in ``[0, 1]`` exists is decided on the box widened by round-off, so that a ``b`` that leaves the
    box by round-off only does not make the task infeasible (the factor is then raised to the
    smallest admissible value of the widened box).
    """
    n = a.shape[0]
    smax = np.full(n, np.inf)
    fixed = ~free                                # saturated: not scaled, they must only sit inside
    if fixed.any():
        b0, b1, wlo, wup = b[fixed], a[fixed] + b[fixed], box.wlo[fixed], box.wup[fixed]
        if ((b0 < wlo) | (b0 > wup) | (b1 < wlo) | (b1 > wup)).any():  # a saturation the null space could not realize
            return -1.0, smax
    idx = np.flatnonzero(free & (a != 0.0))
    flat = free & (a == 0.0)                     # s has no effect: fine iff b is in the box
    if flat.any() and ((b[flat] < box.wlo[flat]) | (b[flat] > box.wup[flat])).any():
        bad = flat & ((b < box.wlo) | (b > box.wup))
        smax[bad] = -np.inf
        return -1.0, smax
    if idx.size == 0:
        return 1.0, smax
    ai, bi = a[idx], b[idx]
    pos = ai > 0.0
    smax[idx] = (np.where(pos, box.up[idx], box.lo[idx]) - bi) / ai
    s_hi_w = float(((np.where(pos, box.wup[idx], box.wlo[idx]) - bi) / ai).min())
    s_lo = float(((np.where(pos, box.wlo[idx], box.wup[idx]) - bi) / ai).max())
    s_lo = max(s_lo, 0.0)
    if s_lo > min(s_hi_w, 1.0):
        return -1.0, smax
    return max(min(float(smax[idx].min()), 1.0), s_lo), smax


def task_scaling_factor(a, b, lower, upper, free=None) -> tuple[float, int]:
    """``getTaskScalingFactor(a, b)`` of the SNS T-RO paper (used by papers/002 Algorithm 1).

    Returns ``(s, j)``: ``s`` the largest value in ``[0, 1]`` such that ``s a + b`` stays inside
    ``[lower, upper]`` on the ``free`` joints (all by default), or -1 if there is none; ``j`` the
    most critical joint, the free joint whose bound limits ``s`` first (argmin of ``smax_j``), or
    -1 if there is no free joint. Joints that are not free (saturated) are not scaled: ``s`` is -1
    if one of them is outside the box.
    """
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    lo, up = _box(lower, upper, a.shape[0])
    if b.shape != a.shape:
        raise ShapeError(f"a has shape {a.shape} but b has shape {b.shape}")
    free = np.ones(a.shape[0], dtype=bool) if free is None else np.asarray(free, dtype=bool)
    s, smax = _scaling(a, b, _Box(lo, up), free)
    return s, (int(np.argmin(smax)) if free.any() else -1)


def _critical_joint(smax, free, violated) -> int:
    """The most critical joint: argmin of ``smax`` over the free joints (the T-RO rule).

    When a scale factor in [0, 1] exists this joint is beyond its bound at ``s = 1``. Otherwise
    (possible only when ``b`` leaves the box) it may not be; then the argmin over the free joints
    that *are* beyond a bound is taken, so that the saturated bound is always defined. -1 if no
    free joint is beyond a bound.
    """
    cand = np.flatnonzero(free & violated)
    if cand.size == 0:
        return -1
    j = int(np.argmin(smax))
    if not (free[j] and violated[j]):
        j = int(cand[np.argmin(smax[cand])])
    return j


def _rank(A, tol: float) -> int:
    """Numerical rank: singular values above ``tol`` (:func:`hqp_tpm.solvers.damping.rank_tol`)."""
    if A.size == 0:
        return 0
    return int(np.sum(np.linalg.svd(A, compute_uv=False) > tol))


def _result(x, box: _Box, info, return_info, checked: bool = False):
    """The command clipped into the exact box: a round-off change only, unless ``info.feasible`` is False.

    ``checked``: ``x`` is already known to be inside the widened box.
    """
    if info.feasible and not checked and box.violated(x, 2.0).any():  # cannot happen when a factor was found
        info = replace(info, feasible=False)
    x = np.minimum(np.maximum(x, box.lo), box.up)
    return (x, info) if return_info else x


# ----------------------------------------------------------------------------------------
# SNS-TPM, papers/002 Algorithm 1: reference path.
# ----------------------------------------------------------------------------------------
def _level_rank_lost(A, size: int) -> bool:
    """``rank(A) < rows(A)`` with the tolerance of a level's pivot, relative to ``A`` itself (damping doc)."""
    return A.shape[0] > 0 and _rank(A, matrix_tol(A, size)) < A.shape[0]


def _kept_rows(J, sizes, size: int) -> int:
    """``m > n`` extension: the rows whose rank the test watches, the first level's if it has full row rank."""
    return sizes[0] if sizes and not _level_rank_lost(J[: sizes[0]], size) else 0


def sns_tpm_reference(levels: Iterable, lower, upper, *, lambda_max: float = 0.0, eps: float = 0.0,
                      return_info: bool = False):
    """SNS-TPM exactly as written in papers/002 Algorithm 1 (readable, slow): ``n x n`` ``W``.

    With more rows than joints (``m > n``) the extension of the module doc: the core step is TPM of
    ``(J W, xd - J xN)`` (its own ``F``) and the rank test looks at the first level only.
    """
    lambda_max, eps = check_damping(lambda_max, eps)
    lo, up = _box(lower, upper, None)
    box = _Box(lo, up)
    n = lo.shape[0]
    lv, J, xd, sizes = _stacked(levels, n)
    m = J.shape[0]
    w, tol = row_weights(J, sizes)                               # rank(JW) on unit levels (damping doc)
    F = tpm_factors(lv, lambda_max=lambda_max, eps=eps, n=n).F
    extended = m > n                                             # this library's extension (module doc)
    m_fit = _kept_rows(J, sizes, max(m, n)) if extended else m

    def tpm_matrix(Jf):                                          # x = M c is tpm's solution of (Jf, c)
        return np.column_stack([nullspace_stacked(Jf, e, sizes, Jf.shape[1], lambda_max, eps)
                                for e in np.eye(m)]) if m else np.zeros((Jf.shape[1], 0))

    def core(W):                                                 # the matrix of the core step: x = xN + M (.)
        free = np.diag(W) > 0.5
        if free.all():                                           # W = I: eq. (4) is the TPM solution (1)
            return tpm_matrix(J)
        if not extended:
            return W @ pinv(w[:, None] * (J @ W), tol=tol) @ (w[:, None] * F)  # (JW)# F = (D J W)# D F
        M = np.zeros((n, m))                                     # TPM of the stack J W on its free columns
        if free.any():
            M[free] = tpm_matrix(J[:, free])
        return M

    W, xN, s, s_star = np.eye(n), np.zeros(n), 1.0, 0.0          # W = I, qdot_N = 0, s = 1, s* = 0
    W_star, xN_star, found = W.copy(), xN.copy(), False
    order, order_star = [], []
    iterations = 0
    while True:                                                  # repeat
        iterations += 1
        M = core(W)
        x = xN + M @ (xd - J @ xN)                               # eq. (4)
        viol = box.violated(x)
        if not viol.any():                                       # until no limit is exceeded
            return _result(x, box, SNSInfo(s, tuple(order), iterations), return_info)
        a = M @ xd
        b = x - a
        free = np.diag(W) > 0.5
        factor, smax = _scaling(a, b, box, free)                 # getTaskScalingFactor(a, b)
        if factor > s_star or (factor >= 0.0 and not found):     # (a feasible 0 counts once: see module doc)
            s_star, W_star, xN_star, order_star, found = factor, W.copy(), xN.copy(), list(order), True
        j = _critical_joint(smax, free, viol)                    # the most critical joint
        if j >= 0:
            W[j, j] = 0.0
            xN[j] = up[j] if x[j] > up[j] else lo[j]
            order.append(j)
        lost = _level_rank_lost((J @ W)[:m_fit], max(m, n)) if extended else _rank(w[:, None] * (J @ W), tol) < m
        if j < 0 or not W.any() or lost:                         # rank(JW) < m: output the best solution
            if not found:                                        # no factor kept the box (0 is outside it)
                return _around_box_point(sns_tpm_reference, lv, box, lambda_max, eps, iterations, return_info)
            s, W, xN, order = s_star, W_star, xN_star, order_star
            x = xN + core(W) @ (s * xd - J @ xN)
            return _result(x, box, SNSInfo(float(s), tuple(order), iterations), return_info)


def _shifted(lv, x0):
    """The stack seen from ``x0``: each level's active rows ``(J_i, t_i - J_i x0)``, one pair per level."""
    return [(J, t - J @ x0) for J, t in (level.as_equality() for level in lv)]


def _around_box_point(solver, lv, box: _Box, lambda_max, eps, iterations, return_info):
    """No scale factor in [0, 1] keeps a box without 0: solve around ``x0 = clip(0, box)`` instead.

    ``x = x0 + dx`` with ``dx`` the SNS-TPM solution for the right-hand side ``b - J x0`` and the
    box ``[lower - x0, upper - x0]``, which contains 0: so ``dx`` exists, ``x`` is inside the box and
    (full-rank stack) ``J x = (1 - s) J x0 + s b``. ``info.feasible`` is False to tell.
    """
    x0 = np.clip(0.0, box.lo, box.up)
    if not x0.any():  # 0 is in the box (then s = 0 is always feasible): the paper's fallback x = 0
        return _result(x0, box, SNSInfo(0.0, (), iterations, False), return_info)
    dx, info = solver(_shifted(lv, x0), box.lo - x0, box.up - x0, lambda_max=lambda_max, eps=eps,
                      return_info=True)
    info = replace(info, iterations=iterations + info.iterations, feasible=False)
    return _result(x0 + dx, box, info, return_info)


# ----------------------------------------------------------------------------------------
# SNS-TPM: the kernel (hqp_tpm.solvers._compiled_sns).
# ----------------------------------------------------------------------------------------
def sns_tpm(levels: Iterable, lower, upper, *, lambda_max: float = 0.0, eps: float = 0.0,
            return_info: bool = False):
    """SNS-TPM (papers/002 Algorithm 1, eq. (4)): prioritized stack under the box ``lower <= x <= upper``.

    ``levels`` as for :func:`tpm` (highest first; ``(J, b)`` pairs or :class:`Level`); ``lower``,
    ``upper`` per joint (``+-inf`` allowed). ``lambda_max``, ``eps`` damp the TPM pivots of ``F``.
    Returns ``x``, or ``(x, SNSInfo)`` with ``return_info``. Equal to :func:`tpm` when no bound is
    exceeded; otherwise joints are saturated one by one and, when ``rank(J W) < m``, the best
    scaled solution ``x = x_N + (J W)# F (s b - J x_N)`` is returned. Same numbers as
    :func:`sns_tpm_reference` (to 1e-9; at a decision point, two joints tied to rounding, the two may
    saturate different joints and their commands differ: docs/guarantees.md); every pass runs in one
    kernel (:mod:`hqp_tpm.solvers._compiled_sns`, compiled, or the same source as Python with
    ``HQP_TPM_COMPILED=0``), which evaluates the core step
    as ``x = s a + b`` with ``a = (J W)# F b`` and ``b = x_N - (J W)# F J x_N``.
    """
    lambda_max, eps = check_damping(lambda_max, eps)
    lo, up = _box(lower, upper, None)
    n = lo.shape[0]
    lv, J, xd, sizes = _stacked(levels, n)
    return _sns_tpm(J, xd, sizes, lo, up, lv, lambda_max, eps, return_info)


def sns_tpm_stacked(J: np.ndarray, xd: np.ndarray, sizes, lower, upper, *, lambda_max: float = 0.0,
                    eps: float = 0.0, return_info: bool = False, x0: np.ndarray | None = None):
    """:func:`sns_tpm` of a stack already stacked: ``J`` (m x n) and ``xd`` finite floats, ``sizes`` the row
    counts of the levels (a tuple, summing to m). The box is checked as by :func:`sns_tpm`, the stack is not
    (the compiled steps check it once per step). Same result as :func:`sns_tpm`. ``x0``: the joint-space term as
    one more, lowest level ``I x = x0``, as the registry adds it (the term must respect the box too)."""
    n = J.shape[1]
    if x0 is not None:  # (np.vstack((J, np.eye(n))), np.concatenate((xd, x0)): the same arrays, in fewer calls)
        m = J.shape[0]
        Jx, xx = np.empty((m + n, n)), np.empty(m + n)
        Jx[:m], Jx[m:], xx[:m], xx[m:] = J, _identity(n), xd, x0
        J, xd, sizes = Jx, xx, (*sizes, n)
    if not (type(lower) is np.ndarray and type(upper) is np.ndarray and lower.dtype == np.float64
            and upper.dtype == np.float64 and lower.shape == upper.shape == (n,)):
        lower, upper = _box(lower, upper, n)     # (else the kernel tests the box: BAD_BOX, then _box raises)
    return _sns_tpm(J, xd, tuple(sizes), lower, upper, None, lambda_max, eps, return_info)


_IDENTITY: dict[int, np.ndarray] = {}


def _identity(n: int) -> np.ndarray:
    """The ``n x n`` identity, read-only, made once per size."""
    eye = _IDENTITY.get(n)
    if eye is None:
        eye = _IDENTITY[n] = np.eye(n)
        eye.flags.writeable = False
    return eye


def _sns_tpm(J, xd, sizes, lo, up, lv, lambda_max, eps, return_info):
    """SNS-TPM of the stacked active rows by the kernel; the box-point shift (module doc) when no scale factor in
    ``[0, 1]`` kept the box (``lv``: the levels, or None: built from ``J``, ``xd``, ``sizes``)."""
    n = lo.shape[0]
    if sizes:
        status, x, sat, s, iterations, feasible, _ = _compiled_sns.sns_tpm_loop(J, xd, sizes, lo, up, lambda_max,
                                                                                eps)
        if status == _compiled_sns.DONE:
            return (x, SNSInfo(s, sat, iterations, feasible)) if return_info else x
        if status == _compiled_sns.BAD_BOX:
            _box(lo, up, n)                      # raises the box's typed error
    else:                                        # no active row: x = 0, if the box holds it
        x, iterations = np.zeros(n), 1
        if ((x >= lo) & (x <= up)).all():
            return (x, SNSInfo(1.0, (), 1)) if return_info else x
    if lv is None:                               # (the kernel's SHIFT: no factor kept the box, 0 is outside it)
        off = np.cumsum((0, *sizes))
        lv = [Level(J[a:e], xd[a:e]) for a, e in zip(off, off[1:], strict=False)]
    return _around_box_point(sns_tpm, lv, _Box(lo, up), lambda_max, eps, iterations, return_info)


# ----------------------------------------------------------------------------------------
# Multi-task SNS (Flacco, De Luca, Khatib, T-RO 2015).
# ----------------------------------------------------------------------------------------
def _sns_level(J, xd, x_prev, Z, G, box: _Box, lambda_max, eps, tol):
    """One level of the multi-task SNS: returns ``(x_k, SNSInfo)``.

    ``x_k = xt + (J_k Pbar_k)# (s xd_k - J_k xt)`` with ``xt = x_{k-1} + ((I - W_k) P_{k-1})# x_N``
    and ``Pbar_k = (I - ((I - W_k) P_{k-1})#) P_{k-1}``; saturated joint ``j`` gets
    ``x_N,j = bound_j - x_{k-1,j}``, so that ``x_k,j`` is the bound. ``P_{k-1} = Z Z^T``; ``G`` is
    ``(J_k P_{k-1})#`` (:func:`projected_step`); ``tol``: the level's rank tolerance.
    """
    P = Z @ Z.T
    n, m = P.shape[0], J.shape[0]
    free = np.ones(n, dtype=bool)
    xN, xsat = np.zeros(n), np.zeros(n)
    order: list[int] = []
    xt = x_prev
    best = None
    iterations = 0
    while True:
        iterations += 1
        x = xt + G @ (xd - J @ xt)
        viol = box.violated(x)
        if not viol.any():
            return x, SNSInfo(1.0, tuple(order), iterations)
        a = G @ xd
        b = x - a
        factor, smax = _scaling(a, b, box, free)
        if factor >= 0.0 and (best is None or factor > best[0]):
            best = (factor, xt, G, tuple(order))
        j = _critical_joint(smax, free, viol)
        if j >= 0:
            free[j] = False
            xsat[j] = box.up[j] if x[j] > box.up[j] else box.lo[j]
            xN[j] = xsat[j] - x_prev[j]
            order.append(j)
            sat = ~free
            # (I - W_k) P_{k-1} has the rows of P_{k-1} at the saturated joints (zero elsewhere): its
            # pseudo-inverse from the SVD of those rows, which must be independent (see module doc)
            U, sv, Vt = np.linalg.svd(P[sat], full_matrices=False)
            realizable = sv[-1] > REALIZABLE_TOL
            if realizable:
                xt = x_prev + (Vt.T / sv) @ (U.T @ xN[sat])
                xt[sat] = xsat[sat]                       # exact identity: x_N puts them on their bounds
                JPbar = J @ (P - Vt.T @ Vt)               # Pbar_k = P_{k-1} - A# A, A = (I - W_k) P_{k-1}
                JPbar[:, sat] = 0.0                       # exact identity: Pbar_k is zero at saturated joints
        if j < 0 or not realizable or _rank(JPbar, tol) < m:
            if best is None:                              # the task is not executed
                return x_prev, SNSInfo(0.0, (), iterations, False)
            s, xt, G, saturated = best
            return xt + G @ (s * xd - J @ xt), SNSInfo(float(s), saturated, iterations)
        G = pinv(JPbar, lambda_max, eps, tol)
        G[~free] = 0.0                                    # exact identity, removes round-off


def sns(levels: Iterable, lower, upper, *, lambda_max: float = 0.0, eps: float = 0.0,
        return_info: bool = False):
    """Multi-task SNS (T-RO 2015): each level in turn, higher first, with its own scale factor.

    Returns ``(x, scales)`` -- ``scales[i]`` is the factor of ``levels[i]`` (1 for a level with no
    active row) -- or ``(x, scales, SNSStackInfo)`` with ``return_info``. Level ``k`` works in the
    null space ``P_{k-1} = Z Z^T`` of the levels above (``Z`` orthonormal, as in :func:`nullspace`),
    so their task values and saturations are kept; it saturates its own critical joints in that
    null space and, when ``rank(J_k Pbar_k) < m_k``, takes the largest scale that keeps the box. A
    level for which no scale in ``[0, 1]`` keeps the box is not executed (scale 0). ``lambda_max``,
    ``eps`` damp the task pseudo-inverses as in :func:`nullspace`; without an active bound the
    result is :func:`nullspace`'s. If the zero command is outside the box and the result leaves it,
    the stack is solved around ``x0 = clip(0, box)`` instead (module doc; ``info.shifted``).
    """
    lambda_max, eps = check_damping(lambda_max, eps)
    lo, up = _box(lower, upper, None)
    box = _Box(lo, up)
    n = lo.shape[0]
    lv = _levels(levels, n)
    size = max(sum(J.shape[0] for J, _ in equality_stack(lv)), n)
    x = np.zeros(n)
    Z = np.eye(n)                                 # orthonormal basis of the null space of the levels above
    scales, infos = [], []
    for level in lv:
        J, xd = level.as_equality()
        if J.shape[0] == 0:
            scales.append(1.0)
            infos.append(SNSInfo(1.0, (), 0))
            continue
        tol = rank_tol(np.linalg.norm(J), size)
        G, Z_next = projected_step(J, Z, lambda_max, eps, tol)
        x, info = _sns_level(J, xd, x, Z, G, box, lambda_max, eps, tol)
        scales.append(info.scale)
        infos.append(info)
        Z = Z_next
    shifted = False
    x0 = np.clip(0.0, lo, up)
    if box.violated(x, 2.0).any() and x0.any():   # only if 0 is outside the box: solve around x0
        dx, scales, sub = sns(_shifted(lv, x0), lo - x0, up - x0, lambda_max=lambda_max, eps=eps, return_info=True)
        x, infos, shifted = x0 + dx, list(sub.levels), True
    clipped = bool(box.violated(x, 2.0).any())    # round-off beyond tolerance (near-singular, undamped)
    x = np.clip(x, lo, up)
    scales = np.array(scales)
    return (x, scales, SNSStackInfo(tuple(infos), clipped, shifted)) if return_info else (x, scales)

"""Priority-weighted damped least squares (PWDLS) of papers/004, Sec. 5.2, eqs. (37)-(43).

All tasks in one extended Jacobian ``J_E`` (34); the priority is a weight, not a hierarchy:

    qd = J_E^# xd_E,   J_E^# = J_E^T (J_E J_E^T + lambda^2 P)^{-1},   P = diag(p_1 I_1, ..., p_k I_k)   (37)-(39)

with ``Priority(T_i) > Priority(T_j) <=> p_i < p_j`` (41). By the push-through identity this is
``(J_E^T P^{-1} J_E + lambda^2 I)^{-1} J_E^T P^{-1} xd_E``, the minimiser of

    lambda^2 ||qd||^2 + sum_i (1/p_i) ||xd_i - J_i qd||^2

-- the printed (40) has ``p_i`` where (38) gives ``1/p_i`` (with ``p_i`` the lower-priority task would weigh more,
against (41)). :func:`pwdls` uses the n x n form, which stays well conditioned when ``J_E`` has more rows than
columns and ``lambda`` is tiny (Fig. 14: m_t = 6 > n = 4, lambda = 1e-8, where ``J_E J_E^T + lambda^2 P`` is
numerically singular). :func:`task_mapping` is ``A = J_E J_E^#`` of (42)-(43): ``xd_Ea = A xd_E``; its diagonal
blocks ``A_ii`` map a task's desired velocity to its achieved one, the off-diagonal ones the influence between tasks.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from hqp_tpm.errors import NonFiniteError, ShapeError


def _stack(levels: Sequence, priorities: Sequence[float]) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[int]]:
    if len(levels) != len(priorities) or not levels:
        raise ShapeError(f"pwdls: {len(levels)} levels and {len(priorities)} priorities; need one priority per level")
    Js, bs, sizes = [], [], []
    for i, lv in enumerate(levels):
        J, b = (lv.J, lv.b) if hasattr(lv, "J") else lv
        J = np.atleast_2d(np.asarray(J, dtype=float))
        b = np.atleast_1d(np.asarray(b, dtype=float))
        if b.shape != (J.shape[0],) or (Js and J.shape[1] != Js[0].shape[1]):
            raise ShapeError(f"pwdls: level {i} has J {J.shape} and b {b.shape}; expected b ({J.shape[0]},) and "
                             f"{Js[0].shape[1] if Js else J.shape[1]} columns")
        Js.append(J)
        bs.append(b)
        sizes.append(J.shape[0])
    p = np.asarray(priorities, dtype=float)
    if not np.isfinite(p).all() or (p <= 0).any():
        raise NonFiniteError(f"pwdls: priorities must be finite and > 0, got {p.tolist()}")
    return np.vstack(Js), np.concatenate(bs), np.repeat(p, sizes), sizes


def pwdls_inverse(levels: Sequence, priorities: Sequence[float], damping: float) -> np.ndarray:
    """``J_E^#`` of (38) (n x m_t), computed as ``(J_E^T P^-1 J_E + lambda^2 I)^-1 J_E^T P^-1``."""
    J, _, p, _ = _stack(levels, [*priorities])
    if not np.isfinite(damping) or damping < 0:
        raise NonFiniteError(f"pwdls: damping lambda = {damping!r} must be finite and >= 0")
    JtW = J.T / p
    return np.linalg.solve(JtW @ J + damping**2 * np.eye(J.shape[1]), JtW)


def pwdls(levels: Sequence, priorities: Sequence[float], damping: float) -> np.ndarray:
    """``qd = J_E^# xd_E`` (37) for levels ``(J_i, xd_i)`` with priority factors ``p_i`` (smaller = higher)."""
    _, b, _, _ = _stack(levels, priorities)
    return pwdls_inverse(levels, priorities, damping) @ b


def task_mapping(levels: Sequence, priorities: Sequence[float], damping: float) -> list[list[np.ndarray]]:
    """The blocks ``A_ij`` (m_i x m_j) of ``A = J_E J_E^#`` (42)-(43)."""
    J, _, _, sizes = _stack(levels, priorities)
    A = J @ pwdls_inverse(levels, priorities, damping)
    edges = np.cumsum([0, *sizes])
    return [[A[edges[i]:edges[i + 1], edges[j]:edges[j + 1]] for j in range(len(sizes))] for i in range(len(sizes))]

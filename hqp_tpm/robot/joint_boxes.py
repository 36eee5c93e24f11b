"""Joint boxes ``lower <= command <= upper`` (on ``qdot`` or ``qddot``, always ``lower <= upper``) for one period
``dt``: the SNS solvers' box (Flacco, De Luca, Khatib, T-RO 2015), a recovery box outside the (viable) limits.
Position limits may be infinite; ``v_max``, ``a_max`` finite and ``>= 0``, ``dt`` finite and ``> 0``: else
:class:`BoxError` (:class:`ShapeError` for a wrong size) naming the joint and the value. Derivations:
docs/internals.md#joint-boxes."""

from __future__ import annotations

import numpy as np

from hqp_tpm.errors import BoxError, ShapeError
from hqp_tpm.robot import _compiled


def _as_vector(x, n: int | None, what: str, *, finite: bool) -> np.ndarray:
    arr = np.asarray(x, dtype=float)
    if arr.ndim == 0 and n is not None:
        arr = np.full(n, float(arr))
    if arr.ndim != 1 or (n is not None and arr.shape[0] != n):
        expected = "a 1-D array" if n is None else f"({n},), one entry per joint"
        raise ShapeError(f"{what} has shape {np.shape(x)}, expected {expected}")
    bad = np.isnan(arr) if not finite else ~np.isfinite(arr)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        kind = "NaN" if not finite else "a non-finite value"
        raise BoxError(f"{what}[{i}] is {kind} ({arr[i]}) at joint {i}; all {what} entries must be "
                       f"{'numbers' if not finite else 'finite'}")
    return arr


def _check_limits(q, q_min, q_max, v_max, a_max, dt, dq=None):
    """Validate shapes and values; return float arrays (scalars broadcast over the joints)."""
    q = _as_vector(q, None, "q", finite=True)
    n = q.shape[0]
    q_min = _as_vector(q_min, n, "q_min", finite=False)
    q_max = _as_vector(q_max, n, "q_max", finite=False)
    v_max = _as_vector(v_max, n, "v_max", finite=True)
    a_max = _as_vector(a_max, n, "a_max", finite=True)
    if dq is not None:
        dq = _as_vector(dq, n, "dq", finite=True)
    bad = q_min > q_max
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise BoxError(f"joint {i}: lower position limit q_min[{i}] = {q_min[i]} > upper limit q_max[{i}] = {q_max[i]}")
    for name, arr in (("v_max", v_max), ("a_max", a_max)):
        if (arr < 0.0).any():
            i = int(np.flatnonzero(arr < 0.0)[0])
            raise BoxError(f"joint {i}: {name}[{i}] = {arr[i]} is negative; a limit on |.| must be >= 0")
    dt = float(dt)
    if not np.isfinite(dt) or dt <= 0.0:
        raise BoxError(f"dt = {dt} must be a finite positive control period")
    return q, dq, q_min, q_max, v_max, a_max, dt


class BoxLimits:
    """Joint limits validated once (errors as the module's functions), for the boxes of many states: its methods take
    finite float vectors of the right size, not validated, and run the kernels of :mod:`hqp_tpm.robot._compiled`."""

    def __init__(self, q_min, q_max, v_max, a_max, dt):
        n = _as_vector(q_min, None, "q_min", finite=False).shape[0]
        _, _, q_min, q_max, v_max, a_max, dt = _check_limits(np.zeros(n), q_min, q_max, v_max, a_max, dt)
        self.q_min, self.q_max, self.v_max, self.a_max, self.dt = q_min, q_max, v_max, a_max, dt
        #: the kernels' rows: ``q_min, q_max, v_max, a_max, 2 a_max, a_max dt``
        self.rows = np.ascontiguousarray(np.vstack([q_min, q_max, v_max, a_max, 2.0 * a_max, a_max * dt]))
        self._idx = np.vstack([np.arange(n), np.arange(n)]).astype(np.int64)

    def box_into(self, q, v, lo, up, order: int = 1, rate: bool = False, idx=None) -> None:
        """The box at ``(q, v)`` into ``lo[idx[1]]``, ``up[idx[1]]`` (``q`` read at ``idx[0]``; default: every joint):
        the velocity box (``rate``: with the command-rate bound, ``v`` the previous command) or at ``order`` 2 the
        acceleration box."""
        idx = self._idx if idx is None else idx
        if order == 2:
            _compiled.acceleration_box(q, v, self.rows, idx, self.dt, lo, up)
        elif rate:
            _compiled.velocity_box(q, self.rows, idx, self.dt, lo, up, v)
        else:
            _compiled.velocity_box(q, self.rows, idx, self.dt, lo, up)

    def velocity_box(self, q, dq=None) -> tuple[np.ndarray, np.ndarray]:
        """:func:`velocity_box` at ``q``; with ``dq`` (the previous command) the braking term is the discrete one and
        the box is intersected with ``dq +- a_max dt`` (:func:`command_rate_box`; docs/internals.md#joint-boxes)."""
        lo, up = np.empty(self._idx.shape[1]), np.empty(self._idx.shape[1])
        self.box_into(q, dq, lo, up, 1, dq is not None)
        return lo, up

    def acceleration_box(self, q, dq) -> tuple[np.ndarray, np.ndarray]:
        """:func:`acceleration_box` at ``(q, dq)``."""
        lo, up = np.empty(self._idx.shape[1]), np.empty(self._idx.shape[1])
        self.box_into(q, dq, lo, up, 2)
        return lo, up


def velocity_box(q, q_min, q_max, v_max, a_max, dt) -> tuple[np.ndarray, np.ndarray]:
    """Box on ``qdot`` for one period ``dt``: ``Qdot_max = min((q_max - q)/dt, v_max, sqrt(2 a_max (q_max - q)))``,
    ``Qdot_min`` mirrored; outside the limits the recovery box (docs/internals.md#joint-boxes)."""
    q, _, q_min, q_max, v_max, a_max, dt = _check_limits(q, q_min, q_max, v_max, a_max, dt)
    return BoxLimits(q_min, q_max, v_max, a_max, dt).velocity_box(q)


def command_rate_box(lo, up, dq, step) -> tuple[np.ndarray, np.ndarray]:
    """The velocity box ``[lo, up]`` intersected with the command-rate box ``dq +- step`` (``dq`` the previous
    command, ``step = a_max dt``) clipped into it: where they miss, the end of ``[lo, up]`` nearest ``dq``."""
    return np.minimum(np.maximum(dq - step, lo), up), np.minimum(np.maximum(dq + step, lo), up)


def acceleration_box(q, dq, q_min, q_max, v_max, a_max, dt) -> tuple[np.ndarray, np.ndarray]:
    """Box on ``qddot`` for one period ``dt``: ``|qddot| <= a_max``, ``|dq + qddot dt| <= v_max`` and the next state
    able to brake before its limits; for a viable state (:func:`is_viable`) every command in it keeps the state viable,
    else the recovery box (docs/internals.md#joint-boxes)."""
    q, dq, q_min, q_max, v_max, a_max, dt = _check_limits(q, q_min, q_max, v_max, a_max, dt, dq=dq)
    return BoxLimits(q_min, q_max, v_max, a_max, dt).acceleration_box(q, dq)


def is_viable(q, dq, q_min, q_max, v_max, a_max, dt, *, tol: float = 0.0) -> np.ndarray:
    """Per joint: is the state inside the limits and able to stop before them (at ``a_max``, sampled every ``dt``)?"""
    q, dq, q_min, q_max, v_max, a_max, dt = _check_limits(q, q_min, q_max, v_max, a_max, dt, dq=dq)
    brake = np.where(a_max > 0.0, dq * dq / (2.0 * np.where(a_max > 0.0, a_max, 1.0)),  # no division by 0
                     np.where(dq == 0.0, 0.0, np.inf))
    ahead_up = q + np.where(dq > 0.0, brake + 0.5 * dq * dt, 0.0)
    ahead_lo = q - np.where(dq < 0.0, brake - 0.5 * dq * dt, 0.0)
    return ((q >= q_min - tol) & (q <= q_max + tol) & (np.abs(dq) <= v_max + tol)
            & (ahead_up <= q_max + tol) & (ahead_lo >= q_min - tol))

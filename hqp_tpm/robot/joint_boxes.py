"""Joint boxes from joint limits: bounds on the command at velocity and at acceleration level.

SNS-type solvers (:mod:`hqp_tpm.solvers.sns`) take a box ``lower <= command <= upper`` per joint.
This module turns position, velocity and acceleration limits into such boxes for one control
period ``dt`` (Flacco, De Luca, Khatib, T-RO 2015, as restated in reference/romeo_four_tasks.md).

Both functions always return ``lower <= upper``. For a state inside the limits (at acceleration
level: inside the *viable* set, see :func:`acceleration_box`) every command in the box keeps the
next sampled state inside the limits. For a state outside them (a robot that starts outside) the
box is a documented *recovery* box that drives the joint back inside at the maximum admissible
rate; velocity and acceleration limits always take precedence over the position limits.

Position limits may be infinite (a continuous joint); ``v_max``, ``a_max`` must be finite and
``>= 0``, ``dt`` finite and ``> 0``. Errors name the joint index and the offending values.
"""

from __future__ import annotations

import numpy as np

from hqp_tpm.errors import BoxError, ShapeError


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


def _project(p_lo, p_up, lo, up, violated_lo, violated_up):
    """Put the position box ``[p_lo, p_up]`` inside the rate box ``[lo, up]`` (with ``lo <= up``).

    If the position box is empty the side whose limit is violated wins (both bounds are set to
    its value); the result is then clipped into ``[lo, up]``, so ``lower <= upper`` always, and the
    rate limits have precedence: a joint outside its range returns at the largest admissible rate.
    """
    empty = p_lo > p_up
    if empty.any():
        p_up = np.where(empty & violated_lo, p_lo, p_up)
        p_lo = np.where(empty & ~violated_lo & violated_up, p_up, p_lo)
    # the last case (empty box, neither side flagged) cannot occur: keep the ordering anyway
    p_up = np.maximum(p_up, p_lo)
    return np.clip(p_lo, lo, up), np.clip(p_up, lo, up)


class BoxLimits:
    """Joint limits validated once, for the boxes of many states (a controller's every step).

    The parts of the formulas that depend on the limits only are computed here;
    :meth:`velocity_box` and :meth:`acceleration_box` take a state already known to be finite
    float vectors of the right size (the functions :func:`velocity_box`, :func:`acceleration_box`
    validate it first). Errors name the joint and the offending limit, as those functions do.
    """

    def __init__(self, q_min, q_max, v_max, a_max, dt):
        n = _as_vector(q_min, None, "q_min", finite=False).shape[0]
        _, _, q_min, q_max, v_max, a_max, dt = _check_limits(np.zeros(n), q_min, q_max, v_max, a_max, dt)
        self.q_min, self.q_max, self.v_max, self.a_max, self.dt = q_min, q_max, v_max, a_max, dt
        lo_inf, up_inf = np.isneginf(q_min), np.isposinf(q_max)
        # velocity box: the braking term sqrt(2 a_max gap) is used where the limit is finite and a_max > 0;
        # elsewhere it is -inf/+inf (infinite limit) or 0 (a_max = 0). Infinite limits are replaced by 0 in
        # the gap (only the used entries matter; 0 * inf would be NaN).
        self._two_a = 2.0 * a_max
        self._q_min0, self._q_max0 = np.where(lo_inf, 0.0, q_min), np.where(up_inf, 0.0, q_max)
        self._brake_lo, self._brake_up = ~lo_inf & (a_max != 0.0), ~up_inf & (a_max != 0.0)
        self._stop_lo, self._stop_up = np.where(lo_inf, -np.inf, 0.0), np.where(up_inf, np.inf, 0.0)
        self._minus_v = -v_max
        self.rate_step = a_max * dt  # the largest change of a velocity-level command in one period

    def velocity_box(self, q, dq=None) -> tuple[np.ndarray, np.ndarray]:
        """:func:`velocity_box` at ``q`` (finite float vector, not validated).

        With ``dq`` (the previous command): the box that also bounds the command's rate, for a drive that changes
        its velocity by at most ``a_max dt`` per step. Its braking term is the discrete one: the largest ``w`` whose
        stopping distance ``D(w) = dt (w + (w - a_max dt) + (w - 2 a_max dt) + ...)`` (positive terms) fits the gap,
        ``w = (gap / dt + a_max dt m (m + 1) / 2) / (m + 1)`` with ``m = floor((sqrt(1 + 8 gap / (a_max dt**2)) - 1)
        / 2)`` (``D`` is piecewise linear). ``D(w) = w dt + D(w - a_max dt)``, so one step later the term is at least
        ``w - a_max dt``: a command inside the previous box always leaves this box and the rate box intersecting
        (``tests/test_joint_boxes.py``; the continuous ``sqrt(2 a_max gap)`` shrinks faster than ``a_max dt`` per step
        near a limit). ``w <= gap / dt``: the one-period term is implied. Then :func:`command_rate_box` with ``dq``.
        """
        q_min, q_max, dt = self.q_min, self.q_max, self.dt
        g_lo, g_up = np.maximum(q - self._q_min0, 0.0), np.maximum(self._q_max0 - q, 0.0)
        if dq is None:
            r_lo, r_up = np.sqrt(self._two_a * g_lo), np.sqrt(self._two_a * g_up)
        else:
            ad = self.rate_step
            with np.errstate(divide="ignore", invalid="ignore"):  # (a_max = 0: not used, the masks below)
                r_lo, r_up = (_discrete_braking(g, ad, dt) for g in (g_lo, g_up))
        stop_lo = np.where(self._brake_lo, -r_lo, self._stop_lo)
        stop_up = np.where(self._brake_up, r_up, self._stop_up)
        p_lo = np.maximum((q_min - q) / dt, stop_lo)
        p_up = np.minimum((q_max - q) / dt, stop_up)
        lo, up = _project(p_lo, p_up, self._minus_v, self.v_max, q < q_min, q > q_max)
        return (lo, up) if dq is None else command_rate_box(lo, up, dq, self.rate_step)

    def acceleration_box(self, q, dq) -> tuple[np.ndarray, np.ndarray]:
        """:func:`acceleration_box` at ``(q, dq)`` (finite float vectors, not validated)."""
        a_max, dt = self.a_max, self.dt
        lo_v = np.clip((self._minus_v - dq) / dt, -a_max, a_max)
        up_v = np.clip((self.v_max - dq) / dt, -a_max, a_max)
        delta_up = self.q_max - q - 0.5 * dq * dt
        delta_lo = q - self.q_min + 0.5 * dq * dt
        w_up = _braking_velocity(delta_up, a_max, dt)
        w_lo = -_braking_velocity(delta_lo, a_max, dt)
        p_lo = (w_lo - dq) / dt
        p_up = (w_up - dq) / dt
        return _project(p_lo, p_up, lo_v, up_v, delta_lo < 0.0, delta_up < 0.0)


def velocity_box(q, q_min, q_max, v_max, a_max, dt) -> tuple[np.ndarray, np.ndarray]:
    """Box on ``qdot`` for one period ``dt`` (Flacco-De Luca-Khatib T-RO 2015, docs/setups.md).

    ``Qdot_min = max((q_min - q)/dt, -v_max, -sqrt(2 a_max (q - q_min)))`` and
    ``Qdot_max = min((q_max - q)/dt,  v_max,  sqrt(2 a_max (q_max - q)))``: the position limit
    one period ahead, the velocity limit, and the braking term that keeps the joint able to stop
    before its limit with deceleration ``a_max``. For ``q_min <= q <= q_max`` the box contains 0 and
    ``q + qdot dt`` stays in ``[q_min, q_max]`` for every ``qdot`` in it.

    Recovery (``q`` outside ``[q_min, q_max]``): the square-root term of the violated side is taken
    as 0, so the one-period term forces motion back inside. For ``q < q_min`` the lower bound is
    ``min((q_min - q)/dt, v_max) > 0``: back inside in one period if ``v_max`` allows it, else at
    ``v_max``; the upper bound is the usual one, raised to the lower bound if it is below it (the
    violated side wins). Mirrored for ``q > q_max``. ``|qdot| <= v_max`` always.
    """
    q, _, q_min, q_max, v_max, a_max, dt = _check_limits(q, q_min, q_max, v_max, a_max, dt)
    return BoxLimits(q_min, q_max, v_max, a_max, dt).velocity_box(q)


def command_rate_box(lo, up, dq, step) -> tuple[np.ndarray, np.ndarray]:
    """The velocity box ``[lo, up]`` (``lo <= up``) intersected with the command-rate box ``dq +- step``.

    ``dq`` is the previous command and ``step = a_max dt``: a command in the result changes by at most
    ``a_max dt`` from the previous one, so the drive sees an acceleration of at most ``a_max`` (issue 31). The
    result is ``[min(max(dq - step, lo), up), min(max(dq + step, lo), up)]``: the rate box clipped into
    ``[lo, up]``. So ``lower <= upper`` always, and where the two boxes do not intersect (the position or
    velocity limits close in faster than ``a_max`` allows, or a state that starts too fast) the position and
    velocity limits take precedence: both bounds are the end of ``[lo, up]`` nearest the previous command (the
    smallest change the limits allow, larger than ``step`` on that step only).
    """
    return np.minimum(np.maximum(dq - step, lo), up), np.minimum(np.maximum(dq + step, lo), up)


def _discrete_braking(gap, ad, dt):
    """The discrete braking term of :meth:`BoxLimits.velocity_box` with ``dq`` (``ad = a_max dt``; the operations of
    :func:`hqp_tpm.robot._compiled.velocity_rate_box`)."""
    m = np.floor((np.sqrt(1.0 + 8.0 * (gap / (ad * dt))) - 1.0) * 0.5)
    return (gap / dt + ad * (m * (m + 1.0)) * 0.5) / (m + 1.0)


def _braking_velocity(delta, a_max, dt):
    """Largest next velocity ``w`` from which the joint can still stop within the distance ``delta``.

    Solves ``w**2 / (2 a) + w dt <= delta`` (see :func:`acceleration_box`) for ``delta >= 0``:
    ``w = -a dt + sqrt((a dt)**2 + 2 a delta)``; for ``delta < 0`` (not viable) the one-period
    position bound ``w = 2 delta / dt``. Both branches are 0 at ``delta = 0``.
    """
    ad = a_max * dt
    inf = np.isposinf(delta)  # its gap is replaced by 0 (a_max = 0 would give 0 * inf = NaN)
    root = np.where(inf, np.inf, -ad + np.sqrt(ad * ad + 2.0 * a_max * np.where(inf, 0.0, np.maximum(delta, 0.0))))
    return np.where(delta >= 0.0, root, 2.0 * delta / dt)


def acceleration_box(q, dq, q_min, q_max, v_max, a_max, dt) -> tuple[np.ndarray, np.ndarray]:
    """Box on ``qddot`` for one period ``dt``, for the exact integration of a constant ``qddot``.

    Derivation (per joint, ``v = dq``, ``u = qddot``, ``T = dt``, ``a = a_max``). One period gives
    ``v+ = v + u T`` and ``q+ = q + v T + u T**2 / 2 = q + (v + v+) T / 2``. Three constraints:

    1. acceleration limit: ``-a <= u <= a``;
    2. velocity one step ahead: ``-v_max <= v+ <= v_max``, i.e. ``(-v_max - v)/T <= u <= (v_max - v)/T``;
    3. position reachable with braking. Braking at ``-a`` from ``v >= 0`` and stopping exactly in the
       last (partial) period travels at most ``v**2/(2a) + v T/2`` (the continuous ``v**2/(2a)`` plus
       the discretisation excess ``r (T - r/a)/2 <= v T / 2`` of the last period with ``r < a T``).
       Call a state *viable* if ``q + v**2/(2a) + v T/2 <= q_max`` for ``v >= 0`` (and the mirror
       ``q - v**2/(2a) + v T/2 >= q_min`` for ``v <= 0``). Braking keeps a viable state viable (one
       period at ``-a`` lowers the left side by ``a T**2/2``; the final period lands on ``v+ = 0``).
       Requiring the next state to be viable reads, with ``w = v+`` and
       ``delta = q_max - q - v T / 2``: ``w**2/(2a) + w T <= delta`` for ``w >= 0``, and ``q+ <= q_max``
       for ``w < 0``, which together give ``w <= w_up = -a T + sqrt((a T)**2 + 2 a delta)`` (it also
       implies ``q+ <= q_max``); mirrored on the lower side. Hence
       ``(w_lo - v)/T <= u <= (w_up - v)/T``.

    The box is the intersection of 1-3. It is non-empty for every viable state with
    ``q_min <= q <= q_max`` and ``|v| <= v_max`` (each lower term is below each upper term:
    ``w_up >= v - a T`` is the viability condition, and ``w_lo <= 0 <= w_up``), and every command
    in it leads to a viable state inside the position and velocity limits: by induction the box
    stays non-empty and the sampled positions stay in the limits forever. A state inside the
    limits but too fast to stop before a limit is *not* viable: no command can keep it inside.

    Recovery (a state that is not viable, or outside the position or velocity limits): 1 is kept,
    2 is clipped into 1 (``[-a, a]``), and 3 is clipped into the result; if 3 is empty the violated
    side wins. So the joint brakes or returns at the largest admissible rate (``+-a``, then ``v_max``)
    and ``lower <= upper`` always. Positions are checked at the sampling instants only.
    """
    q, dq, q_min, q_max, v_max, a_max, dt = _check_limits(q, q_min, q_max, v_max, a_max, dt, dq=dq)
    return BoxLimits(q_min, q_max, v_max, a_max, dt).acceleration_box(q, dq)


def is_viable(q, dq, q_min, q_max, v_max, a_max, dt, *, tol: float = 0.0) -> np.ndarray:
    """Per joint: is the state inside the limits and able to stop before them (see :func:`acceleration_box`)?"""
    q, dq, q_min, q_max, v_max, a_max, dt = _check_limits(q, q_min, q_max, v_max, a_max, dt, dq=dq)
    brake = np.where(a_max > 0.0, dq * dq / (2.0 * np.where(a_max > 0.0, a_max, 1.0)),  # no division by 0
                     np.where(dq == 0.0, 0.0, np.inf))
    ahead_up = q + np.where(dq > 0.0, brake + 0.5 * dq * dt, 0.0)
    ahead_lo = q - np.where(dq < 0.0, brake - 0.5 * dq * dt, 0.0)
    return ((q >= q_min - tol) & (q <= q_max + tol) & (np.abs(dq) <= v_max + tol)
            & (ahead_up <= q_max + tol) & (ahead_lo >= q_min - tol))

"""``assert_task_derivatives``: a task's Jacobian and J-dot q-dot against finite differences.

At a state ``(q, v)``, with ``q (+) d = pin.integrate(model, q, d)`` (so free-flyer, continuous and
spherical joints move on their manifold):

* column ``k`` of ``J`` against ``(x(q (+) h e_k) (-) x(q (+) -h e_k)) / 2h``;
* ``J-dot q-dot`` against ``(J(q (+) h v) - J(q (+) -h v)) v / 2h`` (the derivative of ``J`` along
  ``q(t) = q (+) t v``, at zero acceleration).

``x (-) y`` is ``x - y`` for a vector-valued task. For the library's tasks whose value lives on
SO(3) (:class:`FrameOrientation`, the orientation rows of :class:`FramePose`,
:class:`QuaternionOrientation`, whose ``J`` is the angular-velocity Jacobian) the frame rotation is
differenced as ``log3(R_+ R_-^T)`` (world frame). Your own task can say the same with ``value=``
(state -> anything) and ``difference=`` (plus, minus -> tangent vector).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from hqp_tpm.robot.state import State
from hqp_tpm.testing.states import random_state


def _views(task) -> tuple[Callable, Callable] | None:
    """(value, difference) of the library's tasks whose value is not a plain vector."""
    from hqp_tpm.tasks import FrameOrientation, FramePose, QuaternionOrientation

    def log_diff(p, m):
        return pin.log3(p @ m.T)

    if isinstance(task, FrameOrientation):
        return (lambda st: st.rotation(task.fid).copy()), log_diff
    if isinstance(task, QuaternionOrientation):
        return (lambda st: st.rotation(task.fid).copy()), (lambda p, m: log_diff(p, m)[task.rows])
    if isinstance(task, FramePose):
        return ((lambda st: st.placement(task.fid).copy()),
                (lambda p, m: np.concatenate([p.translation - m.translation, log_diff(p.rotation, m.rotation)])))
    return None


@dataclass
class DerivativeErrors:
    """At one state: the analytic and finite-difference Jacobian and J-dot q-dot."""

    q: np.ndarray
    v: np.ndarray
    J: np.ndarray
    J_fd: np.ndarray
    jdqd: np.ndarray
    jdqd_fd: np.ndarray

    def jacobian_error(self) -> tuple[float, tuple[int, int]]:
        d = np.abs(self.J - self.J_fd)
        idx = np.unravel_index(int(np.argmax(d)), d.shape) if d.size else (0, 0)
        return (float(d[idx]) if d.size else 0.0), (int(idx[0]), int(idx[1]))

    def jdot_error(self) -> tuple[float, int]:
        d = np.abs(self.jdqd - self.jdqd_fd)
        i = int(np.argmax(d)) if d.size else 0
        return (float(d[i]) if d.size else 0.0), i


def task_derivative_errors(task, robot, q, v, *, h: float = 1e-6, value: Callable | None = None,
                           difference: Callable | None = None) -> DerivativeErrors:
    """The four arrays compared by :func:`assert_task_derivatives` at ``(q, v)``."""
    model = robot.model
    views = _views(task) if value is None and difference is None else None
    if views is not None:
        value, difference = views
    value = value or (lambda st: np.array(task.value(st), dtype=float, copy=True))
    difference = difference or (lambda p, m: np.asarray(p) - np.asarray(m))
    q, v = State(robot).check(q, v)
    st = State(robot).update(q, v)
    J = np.array(task.jacobian(st), dtype=float)
    jdqd = np.array(task.jdot_qdot(st), dtype=float).reshape(-1)
    probe = State(robot)
    cols = []
    for k in range(robot.nv):
        dq = np.zeros(robot.nv)
        dq[k] = h
        plus = value(probe.update(pin.integrate(model, q, dq), v))
        minus = value(probe.update(pin.integrate(model, q, -dq), v))
        cols.append(np.asarray(difference(plus, minus), dtype=float).reshape(-1) / (2.0 * h))
    J_fd = np.column_stack(cols) if cols else np.zeros((J.shape[0], 0))
    J1 = np.array(task.jacobian(probe.update(pin.integrate(model, q, h * v), v)), dtype=float)
    J0 = np.array(task.jacobian(probe.update(pin.integrate(model, q, -h * v), v)), dtype=float)
    return DerivativeErrors(q, v, J, J_fd, jdqd, (J1 - J0) @ v / (2.0 * h))


def _states(robot, states, seed: int):
    if isinstance(states, (int, np.integer)):
        rng = np.random.default_rng(seed)
        return [random_state(robot, rng, margin=0.01) for _ in range(int(states))]
    out = []
    for s in states:
        if isinstance(s, State):
            out.append((s.q, s.v))
        else:
            q, v = s
            out.append((q, v))
    return out


def assert_task_derivatives(task, robot, states: int | Iterable = 5, *, seed: int = 0, h: float = 1e-6,
                            atol: float = 2e-6, rtol: float = 1e-6, jdot_atol: float = 2e-5,
                            value: Callable | None = None,
                            difference: Callable | None = None) -> list[DerivativeErrors]:
    """Check ``task.jacobian`` and ``task.jdot_qdot`` of ``task`` on ``robot`` against finite differences.

    ``states``: a number of random states within the robot's limits (drawn from ``seed``, see
    :mod:`hqp_tpm.testing.states`) or an iterable of ``(q, v)`` pairs / :class:`State`.
    Tolerances: ``|J - J_fd| <= atol + rtol max|J|`` entrywise, ``|Jdot qd - fd| <= jdot_atol + rtol
    max|Jdot qd|``. ``value``/``difference``: how to difference the task's value (module doc).
    Returns the per-state errors; raises ``AssertionError`` with a table (each state, the worst
    entry, the joint it belongs to, and the state to reproduce it) when one is off.
    """
    results, bad = [], []
    names = _column_names(robot)
    for i, (q, v) in enumerate(_states(robot, states, seed)):
        e = task_derivative_errors(task, robot, q, v, h=h, value=value, difference=difference)
        if e.J.shape != e.J_fd.shape:
            raise AssertionError(f"task {task.name!r}: jacobian has shape {e.J.shape}, the finite difference of its "
                                 f"value {e.J_fd.shape} (give value=/difference= for a value on a manifold)")
        je, (r, c) = e.jacobian_error()
        de, k = e.jdot_error()
        jtol = atol + rtol * float(np.abs(e.J).max(initial=0.0))
        dtol = jdot_atol + rtol * float(np.abs(e.jdqd).max(initial=0.0))
        results.append(e)
        if je > jtol or de > dtol:
            bad.append((i, e, je, (r, c), jtol, de, k, dtol))
    if not bad:
        return results
    lines = [f"task {task.name!r} ({type(task).__name__}) on {robot.name!r}: derivatives off at {len(bad)} of "
             f"{len(results)} states (h = {h:g})",
             f"{'state':>5}  {'max|J - J_fd|':>14} {'tol':>8}  {'at (row, joint)':<32} {'max|Jdqd - fd|':>14} "
             f"{'tol':>8}  row"]
    for i, e, je, (r, c), jtol, de, k, dtol in bad:
        at = f"({r}, {names[c] if c < len(names) else c})"
        lines.append(f"{i:>5}  {je:>14.3e} {jtol:>8.1e}  {at:<32} {de:>14.3e} {dtol:>8.1e}  {k}"
                     f"{'  J' if je > jtol else ''}{'  Jdot' if de > dtol else ''}")
        if je > jtol:
            lines.append(f"       J[{r}, {c}] = {e.J[r, c]:+.9g}, finite difference {e.J_fd[r, c]:+.9g}")
        if de > dtol:
            lines.append(f"       Jdot_qdot[{k}] = {e.jdqd[k]:+.9g}, finite difference {e.jdqd_fd[k]:+.9g}")
    i, e = bad[0][0], bad[0][1]
    with np.printoptions(precision=17, linewidth=10_000):
        lines.append(f"reproduce state {i}: q = np.array({e.q.tolist()}), v = np.array({e.v.tolist()})")
    raise AssertionError("\n".join(lines))


def _column_names(robot) -> list[str]:
    """One name per velocity column (joint name, with the component for multi-DOF joints)."""
    model = robot.model
    names = [""] * robot.nv
    for jid in range(1, model.njoints):
        j = model.joints[jid]
        for d in range(j.nv):
            names[j.idx_v + d] = model.names[jid] + (f"[{d}]" if j.nv > 1 else "")
    return names

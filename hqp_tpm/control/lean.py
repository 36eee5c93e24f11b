"""The lean control step: the same step as :meth:`Controller.step` in a fixed, small number of calls.

The readable path (:meth:`hqp_tpm.control.controller.Controller.step`) builds every step a
:class:`~hqp_tpm.control.stack.Stack`, one :class:`~hqp_tpm.solvers.levels.Level` per task (each
validated), stacks them, looks the solver up by name and wraps the result in a ``StepResult``. For a
*fixed* stack of equality tasks all of that is the same every step, so :class:`LeanStep` checks it
once, at construction, and per step does only:

1. the state update (pinocchio: forward kinematics, joint Jacobians, frame placements);
2. each task's Jacobian and command written into one preallocated stacked ``J`` and ``b``;
3. one finiteness check of ``J`` and ``b`` and one call of the TPM kernel
   (:func:`hqp_tpm.solvers.tpm.tpm_stacked`), no Level objects, no solver registry;
4. one integration (:meth:`hqp_tpm.robot.state.State.integrate`).

Same numbers as the readable path, step by step (``tests/test_lean.py``): the task rows come from the
tasks' own ``jacobian`` and ``command`` and the kernel is the one :func:`~hqp_tpm.solvers.tpm.tpm` calls.

Supported (else :meth:`LeanStep.of` returns ``None`` and says why in ``LeanStep.why_not(ctrl)``): a
:class:`~hqp_tpm.control.stack.FixedStack` without extra commands whose tasks are equality tasks (their
``level`` is :meth:`Task.level`), solver ``tpm``, no box, no crosscheck, a policy that neither updates
nor blends. A step whose rows are not finite is handed to the readable path, which raises the same
typed error naming the task.
"""

from __future__ import annotations

import math

import numpy as np

from hqp_tpm.control.policy import Policy
from hqp_tpm.control.stack import FixedStack
from hqp_tpm.errors import NonFiniteError, SolverFailedError
from hqp_tpm.solvers.tpm import tpm_stacked
from hqp_tpm.tasks.base import Task


class LeanStep:
    """The lean step of a :class:`~hqp_tpm.control.controller.Controller` (build it with :meth:`of`).

    :meth:`step` advances the controller exactly like ``ctrl.step()`` and returns the command;
    :meth:`compute` returns the command at the current state without integrating. The controller stays
    the owner of the state (``ctrl.q``, ``ctrl.v``, ``ctrl.t``, ``ctrl.steps``): lean and readable steps
    can be mixed.
    """

    __slots__ = ("ctrl", "tasks", "rows", "sizes", "J", "b", "n", "order", "lambda_max", "eps", "damping")

    @staticmethod
    def why_not(ctrl) -> str | None:
        """Why the lean step does not apply to ``ctrl`` (None when it does)."""
        policy = ctrl.policy
        if type(policy) is not FixedStack:
            return f"the policy is a {type(policy).__name__}, not a FixedStack"
        if type(policy).update is not Policy.update or policy.blends:
            return "the policy updates or blends"
        if policy.stack.extras:
            return "the stack has extra commands"
        if ctrl.solver != "tpm":
            return f"solver {ctrl.solver!r} (the lean step solves with 'tpm')"
        if ctrl.box is not None:
            return "a box is set"
        if ctrl.crosscheck is not None:
            return "a crosscheck solver is set"
        for task in policy.stack.tasks():
            if type(task).level is not Task.level:
                return f"task {task.name!r} builds its own level (inequality rows)"
        if not policy.stack.levels:
            return "the stack is empty"
        return None

    @classmethod
    def of(cls, ctrl) -> LeanStep | None:
        """The lean step of ``ctrl``, or None when its set-up is not supported (:meth:`why_not`)."""
        if cls.why_not(ctrl) is not None:
            return None
        self = cls.__new__(cls)
        self.ctrl = ctrl
        self.n = ctrl.robot.nv
        self.order = ctrl.order
        self.lambda_max, self.eps = ctrl.lambda_max, ctrl.eps
        self.damping = ctrl.nullspace_damping if ctrl.order == 2 else 0.0
        tasks, rows, sizes = [], [], []
        a = 0
        for level in ctrl.policy.stack.levels:
            m = 0
            for task in level:
                tasks.append(task)
                rows.append(slice(a + m, a + m + task.dim))
                m += task.dim
            sizes.append(m)
            a += m
        sizes = [m for m in sizes if m]
        self.tasks, self.rows, self.sizes = tuple(tasks), tuple(rows), tuple(sizes)
        self.J = np.zeros((a, self.n))
        self.b = np.zeros(a)
        return self

    def compute(self) -> np.ndarray:
        """The command at the controller's current state (state update, rows, one solve)."""
        ctrl = self.ctrl
        if not ctrl._started:
            ctrl.start()
        t, order = ctrl.t, self.order
        st = ctrl.state.update(ctrl._q, ctrl._v, t, validate=False)
        J, b = self.J, self.b
        for task, r in zip(self.tasks, self.rows, strict=True):
            Jt = task.jacobian(st)
            J[r] = Jt
            b[r] = task.command(st, t, order, None, Jt)
        Jf = J.ravel()                              # a view: J is C-contiguous
        if not math.isfinite(Jf @ Jf + b @ b):      # NaN or inf anywhere (an overflow only costs the slow path)
            return ctrl._compute().command          # the readable path raises the typed error naming the task
        x0 = -self.damping * ctrl._v if self.damping else None
        if self.sizes:
            x = tpm_stacked(J, b, self.sizes, self.n, self.lambda_max, self.eps, x0)
        else:
            x = np.zeros(self.n) if x0 is None else x0.copy()
        if not (math.isfinite(x @ x) or np.isfinite(x).all()):
            raise SolverFailedError(f"solver 'tpm' returned a non-finite command at t = {t:.6f}")
        return x

    def step(self) -> np.ndarray:
        """One control step (as :meth:`Controller.step`, transactional); returns the command."""
        ctrl = self.ctrl
        started = ctrl._started
        try:
            x = self.compute()
            q, v = ctrl.state.integrate(ctrl._q, ctrl._v, x, ctrl.dt, self.order)
            if not (np.isfinite(q).all() and np.isfinite(v).all()):
                raise NonFiniteError(f"integration produced a non-finite state at t = {ctrl.t:.6f}")
        except BaseException:
            ctrl._started = started
            raise
        ctrl._q, ctrl._v = q, v
        if self.order == 2:
            ctrl.a = x.copy()
        ctrl.t += ctrl.dt
        ctrl.steps += 1
        return x

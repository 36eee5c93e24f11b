"""The lean step: ``ctrl.step()`` of a fixed stack of equality tasks (:meth:`LeanStep.why_not` says when not), its
rows, finiteness test and solve in one compiled call where it can. Same numbers as the readable step
(``tests/test_lean.py``). Details: docs/architecture.md, "How ctrl.step() runs compiled"."""

from __future__ import annotations

import numpy as np

from hqp_tpm.control import _compiled_step
from hqp_tpm.control._task_rows import program_rows, write_own_rows
from hqp_tpm.control.command_rate import rate_limited, solve_around
from hqp_tpm.control.policy import FixedStack, Policy
from hqp_tpm.control.step_result import CompiledStep, StepResult
from hqp_tpm.errors import SolverFailedError
from hqp_tpm.robot import _compiled
from hqp_tpm.robot.limits import JointLimits
from hqp_tpm.solvers import _compiled as _solvers_compiled
from hqp_tpm.solvers.levels import MAX_SUMSQ, Level, all_finite, sumsq
from hqp_tpm.solvers.registry import ANALYTIC, solve
from hqp_tpm.solvers.sns import sns_tpm_stacked
from hqp_tpm.solvers.tpm import tpm_stacked
from hqp_tpm.tasks.base import Task

_new = object.__new__


def _writer(task: Task, state, order: int, J: np.ndarray, b: np.ndarray):
    """``write(t)``: ``task``'s own rows at ``state`` into ``J``, ``b`` (:func:`write_own_rows`)."""
    return lambda t: write_own_rows(task, state, t, order, J, b)


class JointBox:
    """:class:`~hqp_tpm.robot.limits.JointLimits`' box at a state, written into two preallocated arrays by
    :meth:`JointLimits.kernel_box` (``BoxLimits``' bits) or :meth:`JointLimits.reference_box` (recovery rules)."""

    __slots__ = ("limits", "order", "lo", "up", "fast", "_P", "_idx", "_dt")

    def __init__(self, limits: JointLimits, out: tuple[np.ndarray, np.ndarray] | None = None):
        """``out``: the two arrays to write the box into (default: new ones)."""
        self.limits, self.order = limits, limits.order
        nv = limits.robot.nv
        self.lo, self.up = (np.empty(nv), np.empty(nv)) if out is None else out
        self.lo[...], self.up[...] = -np.inf, np.inf
        self.fast = limits.kernel_limits is not None  # (finite position limits, a_max > 0)
        # the compiled kernels' inputs (hqp_tpm.robot._compiled): the limits as rows, the joint indices (JointLimits')
        self._P, self._idx, self._dt = limits.kernel_limits, limits.kernel_indices, limits.limits.dt

    def __call__(self, state) -> tuple[np.ndarray, np.ndarray]:
        """``(lower, upper)`` at ``state`` (the arrays are this object's, overwritten by the next call)."""
        if not self.limits.kernel_box(state.q, state.v, self.lo, self.up):
            self.lo[...], self.up[...] = self.limits.reference_box(state)
        return self.lo, self.up


class LeanStep(CompiledStep):
    """The lean step of a :class:`~hqp_tpm.control.controller.Controller` (build it with :meth:`of`).

    :meth:`compute` returns the command at the controller's state (``ctrl.step()`` runs it:
    :class:`~hqp_tpm.control.step_result.CompiledStep`). The controller stays the owner of the state (``ctrl.q``,
    ``ctrl.v``, ``ctrl.t``, ``ctrl.steps``): compiled and readable steps can be mixed."""

    __slots__ = ("ctrl", "tasks", "rows", "sizes", "J", "b", "n", "order", "lambda_max", "eps", "damping",
                 "writers", "levels", "box", "x0", "solver", "frames", "_flat", "_info", "_program", "_buf", "_out",
                 "_velocities", "_positions", "_kernel", "_fused", "_fused_frames", "_com", "_rate", "_stack",
                 "_levels", "_spans", "_label", "_ints", "_floats", "_sns", "_box_writer",
                 "planned_box")

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
        self.n = n = ctrl.robot.nv
        self.order = ctrl.order
        self.solver = ctrl.solver
        self.lambda_max, self.eps = ctrl.lambda_max, ctrl.eps
        self.damping = ctrl.nullspace_damping if ctrl.order == 2 else 0.0
        tasks, rows, sizes, spans = [], [], [], []
        a = 0
        for level in ctrl.policy.stack.levels:
            m = 0
            for task in level:
                tasks.append(task)
                rows.append(slice(a + m, a + m + task.dim))
                m += task.dim
            if m:
                sizes.append(m)
                spans.append((slice(a, a + m), "+".join(task.name for task in level)))
            a += m
        self.tasks, self.rows, self.sizes = tuple(tasks), tuple(rows), tuple(sizes)
        stack = self._stack = ctrl.policy.stack
        self._levels, self._spans, self._label = list(stack.levels), tuple(spans), stack.label()
        # what the fused kernel solves (hqp_tpm.control._compiled_step): TPM; SNS-TPM without the x0 level, in no
        # box or the joint limits' box (written into the buffer); any other solver or box: the rows only
        box = ctrl.box
        joint_box = type(box) is JointLimits and box.order == self.order
        # the box bounds the command's rate: solve_around solves (hqp_tpm.control.command_rate), the kernel the rows
        self._rate = joint_box and self.order == 1 and rate_limited(box) and self.solver not in ANALYTIC
        if self.solver == "tpm":
            mode = _compiled_step.TPM
        elif self._rate:
            mode = _compiled_step.ROWS
        elif self.solver == "sns_tpm" and not self.damping and (box is None or joint_box):
            mode = _compiled_step.SNS
        else:
            mode = _compiled_step.ROWS
        # J, b, x0, the fused kernel's x (and the SNS box) in one buffer (J and b: one finiteness test per step)
        self._buf = np.zeros(_compiled_step.Program.buffer_size(a, n, mode))
        self._flat = self._buf[: a * n + a]
        self.J = self._flat[: a * n].reshape(a, n)
        self.b = self._flat[a * n:]
        self._out = self._buf[a * n + a + n: a * n + a + 2 * n]
        st = ctrl.state
        self.writers = tuple(_writer(task, st, self.order, self.J[r], self.b[r]) for task, r in zip(tasks, rows,
                                                                                                     strict=True))
        # the solver's levels, built once: views of J and b (their rows change in place every step)
        levels = [Level(self.J[r], self.b[r], name=name, defer_finite=True) for r, name in spans]
        self.x0 = self._buf[a * n + a: a * n + a + n] if self.damping else None
        if self.x0 is not None and self.solver == "sns_tpm":  # as the registry does: one more level
            levels.append(Level(np.eye(n), self.x0, name="x0", defer_finite=True))
        self.levels = tuple(levels)
        # the frames of the frame tasks, placed by the state update (but those the fused kernel places, below)
        self.frames = tuple(dict.fromkeys(ctrl.robot.frame_id(task.frame) for task in tasks if task.frame is not None))
        lo_up = (self._buf[a * n + a + 2 * n: a * n + a + 3 * n], self._buf[a * n + a + 3 * n: a * n + a + 4 * n])
        if mode == _compiled_step.SNS:
            lo_up[0][...], lo_up[1][...] = -np.inf, np.inf  # (no box: these stay)
        self.box = JointBox(box, lo_up if mode == _compiled_step.SNS else None) if joint_box else box
        self.planned_box = box
        self._info = {}
        self._velocities = self.order == 2
        # the fused step (hqp_tpm.control._compiled_step): the rows of the tasks that have a row program,
        # finiteness and (tpm) the solve in one compiled call; the other tasks' row writers run before it
        self._kernel = self._program = self._fused = self._box_writer = None
        self._fused_frames = self.frames
        self._com = self._positions = False
        if self.sizes and _compiled.AVAILABLE and _solvers_compiled.ENABLED:  # (other solvers: the rows only)
            program = _compiled_step.Program(a, n, self.sizes, self.order, self.lambda_max, self.eps,
                                             self.x0 is not None, solve=mode)
            fused, written = [], set()
            for task, r, write in zip(tasks, rows, self.writers, strict=True):
                gather = program_rows(task, st, self.order, program, r.start, self.J[r])
                fused.append(write if gather is None else gather)
                if gather is None and task.frame is not None:
                    written.add(ctrl.robot.frame_id(task.frame))
            self._fused = tuple(fused)
            # the frames the kernel places itself are left out of the state update (unless a row writer, which
            # runs before the kernel, reads one)
            self._fused_frames = tuple(f for f in self.frames if f not in program.placed or f in written)
            if mode == _compiled_step.SNS and type(self.box) is JointBox and self.box.fast:  # the box in the kernel
                program.set_box(_compiled_step.BOX_VELOCITY if self.order == 1 else _compiled_step.BOX_ACCELERATION,
                                self.box._P, self.box._idx, self.box._dt)
            self._program = program.build()
            self._ints, self._floats = program.ints, program.floats  # (written in place, never replaced)
            self._com = program.com_in_update  # (set by a row program at velocity level only)
            # order 1, or order 2 with every task in the program and every Jdot qd computed in the kernel: the
            # position pass only
            self._positions = not self._velocities or not program.velocity_pass and all(
                gather is not write for gather, write in zip(self._fused, self.writers, strict=True))
            self._sns = mode == _compiled_step.SNS
            if self._sns and program.box_given and self.box is not None:
                self._box_writer = self.box
            kernel = _compiled_step.kernel(mode, tall=a > n)  # (its code for these arrays and the controller's q, v)
            self._kernel = kernel and _compiled.typed(kernel, self._buf, self._ints, self._floats, ctrl._q, ctrl._v)
        return self

    def current(self) -> bool:
        """Whether the controller's stack is still the one this step was planned for (no level replaced or added)."""
        stack = self.ctrl._policy.stack
        return stack is self._stack and stack.levels == self._levels and not stack.extras

    def result(self, t: float, q: np.ndarray, v: np.ndarray, x: np.ndarray) -> StepResult:
        """The :class:`StepResult` of the command ``x`` computed at ``(q, v, t)``, keeping a copy of the stacked rows
        (the readable step's levels, bit for bit, built when asked) and of the fused SNS solve's info."""
        r = _new(StepResult)  # (the fields not set here are computed on first read: StepResult's defaults)
        r.t, r.command, r._stack = t, x, self._stack
        if self._info is None:  # (the fused SNS kernel's: its outputs copied, the info built when asked)
            r._kept = (self, q, v, self._buf.copy())  # (the rows and the solve's info)
        else:
            r._kept, r._info = (self, q, v, self._flat.copy()), self._info
        return r

    def info_of(self, kept: tuple) -> dict:
        return self._program.sns_info(kept[3])

    def levels_of(self, kept: tuple) -> list[Level]:
        rows, m, n = kept[3], self.b.size, self.n
        J, b = rows[: m * n].reshape(m, n), rows[m * n: m * n + m]
        return [Level(J[r], b[r], name=name, defer_finite=True) for r, name in self._spans]

    def label_of(self, kept: tuple) -> str:
        return self._label

    def _box(self, st, t):
        box = self.box
        return None if box is None else box(st) if type(box) is JointBox else box(st, t)

    def compute(self) -> np.ndarray:
        """The command at the controller's current state (state update, rows, one solve)."""
        ctrl = self.ctrl
        if not ctrl._started:
            ctrl.start()
        t, q, v = ctrl.t, ctrl._q, ctrl._v
        status, x0 = None, self.x0
        if self._kernel is not None and _compiled.ENABLED:  # (one switch: hqp_tpm._jit, shared by the kernel modules)
            if self._positions:  # (the kernel places the frames its tasks read; the CoM here when it reads it)
                st = ctrl.state.update_positions(q, v, t, self._fused_frames, self._com)
            else:
                st = ctrl.state.update(q, v, t, validate=False, frames=self._fused_frames)
            for write in self._fused:  # the program's tasks gather their arrays, the others write their rows
                write(t)
            if x0 is not None:
                np.multiply(v, -self.damping, out=x0)
            if self._box_writer is not None:
                self._box_writer(st)  # the JointBox writes into the buffer's lo, up (else the kernel does)
            status = self._kernel(self._buf, self._ints, self._floats, q, v)
            if status == 0:  # SOLVED
                self._info = None if self._sns else {}  # (None: the kernel's, in the kept buffer)
                return self._out.copy()
            if status == _compiled_step.NONFINITE_ROWS:
                return ctrl._compute().command  # the readable path raises the typed error naming the task
            if status == _compiled_step.NONFINITE_X:
                raise SolverFailedError(f"solver {self.solver!r} returned a non-finite command at t = {t:.6f}")
            if status == _compiled_step.PIVOT_SVD:  # a pivot block only its SVD decides: from now on the kernel
                kernel = _compiled_step.kernel(_compiled_step.TPM, svd=True)  # that decides every pivot at once
                self._kernel = kernel and _compiled.typed(kernel, self._buf, self._ints, self._floats, q, v)
            # WRITTEN (another solver's turn), DECLINED/UNDECIDED (tpm_stacked's numpy reference decides),
            # BOX_HANDED_BACK (the JointBox's recovery rules) or SNS_HANDED_BACK (sns_tpm_stacked): below
        else:
            if self._velocities:
                st = ctrl.state.update(q, v, t, validate=False, frames=self.frames)
            else:
                st = ctrl.state.update_positions(q, v, t, self.frames)
            for write in self.writers:
                write(t)
            if not sumsq(self._flat) <= MAX_SUMSQ:  # NaN, inf or too large (one sum fails for all three):
                return ctrl._compute().command      # the readable path raises the typed error naming the task
            if x0 is not None:
                np.multiply(v, -self.damping, out=x0)
        J, b = self.J, self.b
        solver = self.solver
        info = {}
        if self._rate:  # as Controller._solve_step: the stack solved for the change of the command
            x, info = solve_around(solver, self.levels, self.n, ctrl._v, self._box(st, t), lambda_max=self.lambda_max,
                                   eps=self.eps)
        elif solver == "tpm":
            if self.sizes:  # (after the fused kernel declined, its answer: tpm_stacked does not run it again)
                declined = status in (_compiled_step.DECLINED, _compiled_step.UNDECIDED, _compiled_step.PIVOT_SVD)
                x = tpm_stacked(J, b, self.sizes, self.n, self.lambda_max, self.eps, x0,
                                kernel_status=status if declined else None)
            else:
                x = np.zeros(self.n) if x0 is None else x0.copy()
        elif solver == "sns_tpm":
            lo, up = self._box(st, t) or (np.full(self.n, -np.inf), np.full(self.n, np.inf))
            x, sinfo = sns_tpm_stacked(J, b, self.sizes, lo, up, lambda_max=self.lambda_max, eps=self.eps,
                                       return_info=True, x0=x0)
            info = {"scale": sinfo.scale, "saturated": list(sinfo.saturated), "iterations": sinfo.iterations}
        else:
            x, info = solve(solver, self.levels, self.n, x0=x0, box=self._box(st, t), lambda_max=self.lambda_max,
                            eps=self.eps)
        if not all_finite(x):
            raise SolverFailedError(f"solver {solver!r} returned a non-finite command at t = {t:.6f}")
        self._info = info  # the solver's info of this command, as the readable step's StepResult.info
        return x


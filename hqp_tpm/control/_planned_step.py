"""The compiled step of every planning or stack policy, fixed stack and stack function: state update, the plan, the
rows written into one stacked ``J``, ``b``, one solve, the blend; a fixed stack of equality tasks fused into one
compiled call (:mod:`hqp_tpm.control._compiled_step`). Details: docs/architecture.md, "How ctrl.step() runs compiled".
"""

from __future__ import annotations

from functools import partial

import numpy as np

from hqp_tpm.control import _compiled_step
from hqp_tpm.control._task_rows import TaskProgram, program_rows, write_own_rows
from hqp_tpm.control.command_rate import rate_limited, shift_rows, shifted
from hqp_tpm.control.policy import FixedStack, FunctionPolicy, PlanningPolicy, Policy, StackPolicy
from hqp_tpm.control.stack import Stack, merge_levels
from hqp_tpm.control.step_result import StepResult
from hqp_tpm.errors import NonFiniteError, SolverFailedError
from hqp_tpm.robot import _compiled as _robot_kernels
from hqp_tpm.robot.limits import JointLimits
from hqp_tpm.solvers import _compiled
from hqp_tpm.solvers._fullrank import COND, MARGIN
from hqp_tpm.solvers.levels import MAX_SUMSQ, Level, all_finite, sumsq
from hqp_tpm.solvers.sns import sns_tpm_stacked
from hqp_tpm.solvers.tpm import tpm_stacked
from hqp_tpm.tasks.avoidance import Avoidance, PairAvoidance
from hqp_tpm.tasks.base import Task
from hqp_tpm.tasks.pointing import Pointing

_new = object.__new__


def planned(policy: Policy) -> bool:
    """Whether the planned step takes ``policy``: a planning or stack policy, a fixed stack or a stack function."""
    return isinstance(policy, (PlanningPolicy, StackPolicy)) or type(policy) in (FixedStack, FunctionPolicy)


def joint_box(limits: JointLimits, lo: np.ndarray, up: np.ndarray):
    """``box(state) -> (lo, up)``: :class:`~hqp_tpm.robot.limits.JointLimits`' box at a state, written into ``lo``,
    ``up`` by :meth:`JointLimits.kernel_box` (``BoxLimits``' bits, recovery rules included)."""
    lo[...], up[...] = -np.inf, np.inf

    def box(state) -> tuple[np.ndarray, np.ndarray]:
        limits.kernel_box(state.q, state.v, lo, up)
        return lo, up
    return box


class PlannedStep:
    """A controller's compiled step (:meth:`of`): :meth:`compute` gives the readable step's command, :meth:`result` its
    :class:`StepResult`, keeping ``(step, q, v, rows, made, tasks, extras, stack)`` for the fields read later."""

    __slots__ = ("ctrl", "policy", "n", "order", "lambda_max", "eps", "damping", "J", "b", "tasks", "_placed",
                 "_stacked", "_x0", "_extras", "_made", "sns", "rate", "box", "info", "_bs", "_stack", "_box_now",
                 "other", "_unchecked", "planned_box",
                 # the fused step of a fixed stack of equality tasks (_fuse)
                 "_program", "_kernel", "_buf", "_flat", "_out", "_ints", "_floats", "_sizes", "_gathers", "_frames",
                 "_positions", "_com", "_box_writer", "_levels_planned", "_label")

    @staticmethod
    def why_not(ctrl) -> str | None:
        """Why the planned step does not apply to ``ctrl`` (None when it does)."""
        policy = ctrl.policy
        if not planned(policy):
            return (f"the policy {type(policy).__name__} is not a PlanningPolicy (no plan()), StackPolicy, FixedStack "
                    "nor FunctionPolicy")
        if ctrl.crosscheck is not None:
            return "a crosscheck solver is set"
        return None

    @classmethod
    def of(cls, ctrl) -> PlannedStep | None:
        """The planned step of ``ctrl``, or None when its set-up is not supported (:meth:`why_not`)."""
        if cls.why_not(ctrl) is not None:
            return None
        self = cls.__new__(cls)
        self.ctrl, self.policy = ctrl, ctrl.policy
        self.n, self.order = ctrl.robot.nv, ctrl.order
        self.lambda_max, self.eps = ctrl.lambda_max, ctrl.eps
        self.damping = ctrl.nullspace_damping if ctrl.order == 2 else 0.0
        self.J, self.b = np.zeros((8, self.n)), np.zeros(8)
        self.tasks: tuple[Task, ...] = ()
        self._extras: dict = {}
        self._made: list = []  # per level of the last step: (task, first row, rows, its Level or None: equality rows)
        # the row writers writing straight into the stacked rows, by (task, first row), built on first use (_place)
        self._placed: dict[tuple[int, int], tuple | bool] = {}
        # the compiled TPM solve (_compiled_step.stacked_kernel), its x0 and x (in the fused step's buffer: _fuse)
        self._stacked, self._x0, self._out = None, np.zeros(self.n), np.zeros(self.n)
        self.sns = ctrl.solver == "sns_tpm"  # the stacked rows solved in the box (_sns); other: as levels (_registry)
        self.other = ctrl.solver not in ("tpm", "sns_tpm")
        self.rate = self.sns and ctrl.order == 1 and rate_limited(ctrl.box)
        joint = type(ctrl.box) is JointLimits
        self.planned_box = box = ctrl.box
        self.box = None if box is None else joint_box(box, np.empty(self.n), np.empty(self.n)) if joint else (
            lambda st: box(st, ctrl.t))
        self.info: dict | None = {}
        self._bs = np.zeros(8)  # (rate: the shifted right-hand sides b - J v)
        self._stack = self._box_now = self._program = self._kernel = self._label = None
        self._unchecked = False  # (an inactive cone's row not finite: the readable step decides, _solve)
        policy = self.policy
        if type(policy) is FixedStack and type(policy).update is Policy.update and not policy.blends \
                and not policy.stack.extras and all(type(task).level is Task.level for task in policy.stack.tasks()) \
                and _robot_kernels.AVAILABLE and _compiled.ENABLED:
            self._fuse(policy.stack)
        return self

    def _fuse(self, stack: Stack) -> None:
        """A fixed stack of equality tasks planned once: its rows, their finiteness and the solve (TPM; SNS-TPM without
        x0, in no box or the joint limits'; else none) in one compiled call (:mod:`hqp_tpm.control._compiled_step`)."""
        ctrl, n, order = self.ctrl, self.n, self.order
        made, sizes, a = [], [], 0
        for g, level in enumerate(stack.levels):
            a0 = a
            for task in level:
                if task.dim:
                    made.append((task, a, task.dim, False, g))
                    a += task.dim
            if a > a0:
                sizes.append(a - a0)
        if not sizes:
            return
        box = self.planned_box
        if ctrl.solver == "tpm":
            mode = _compiled_step.TPM
        elif self.sns and not self.rate and not self.damping and (box is None or type(box) is JointLimits):
            mode = _compiled_step.SNS
        else:
            mode = _compiled_step.ROWS
        # J, b, x0, the kernel's x (and the SNS box) in one buffer (J and b: one finiteness test per step)
        buf = self._buf = np.zeros(_compiled_step.Program.buffer_size(a, n, mode))
        o = a * n + a
        self._flat = buf[:o]
        self.J, self.b = self._flat[: a * n].reshape(a, n), self._flat[a * n:]
        self._x0, self._out = buf[o: o + n], buf[o + n: o + 2 * n]
        if mode == _compiled_step.SNS:  # the box written into the buffer (no box: they stay infinite)
            lo, up = buf[o + 2 * n: o + 3 * n], buf[o + 3 * n: o + 4 * n]
            lo[...], up[...] = -np.inf, np.inf
            self.box = None if box is None else joint_box(box, lo, up)
        program = _compiled_step.Program(a, n, sizes, order, self.lambda_max, self.eps, bool(self.damping), solve=mode)
        st, gathers, written, frames, own = ctrl.state, [], set(), {}, False
        for task, r0, k, _, _ in made:
            J, b = self.J[r0:r0 + k], self.b[r0:r0 + k]
            gather = program_rows(task, st, order, program, r0, J)
            if task.frame is not None:
                frames[ctrl.robot.frame_id(task.frame)] = True
            if gather is None:  # its own rows, written before the kernel runs (it reads its frame: placed here)
                gather, own = partial(write_own_rows, task, st, order=order, J=J, b=b), True
                if task.frame is not None:
                    written.add(ctrl.robot.frame_id(task.frame))
            gathers.append(gather)
        self._frames = tuple(f for f in frames if f not in program.placed or f in written)
        if mode == _compiled_step.SNS and box is not None and box.kernel_limits is not None:  # the box in the kernel
            program.set_box(_compiled_step.BOX_VELOCITY if order == 1 else _compiled_step.BOX_ACCELERATION,
                            box.kernel_limits, box.kernel_indices, box.limits.dt)
        self._program = program.build()
        self._ints, self._floats = program.ints, program.floats  # (written in place, never replaced)
        self._com = program.com_in_update  # (set by a row program at velocity level only)
        # order 1, or order 2 with every task in the program and every Jdot qd computed in the kernel: the position
        # pass only (the kernel places the frames its tasks read)
        self._positions = order == 1 or not program.velocity_pass and not own
        self._box_writer = self.box if mode == _compiled_step.SNS and program.box_given else None
        self._made, self._sizes, self._gathers, self._bs = made, tuple(sizes), tuple(gathers), np.zeros(a)
        self.tasks, self._stack = tuple(task for task, *_ in made), stack
        self._levels_planned, self._label = list(stack.levels), stack.label()
        kernel = _compiled_step.kernel(mode, tall=a > n)  # (its code for these arrays and the controller's q, v)
        self._kernel = kernel and _robot_kernels.typed(kernel, buf, self._ints, self._floats, ctrl._q, ctrl._v)

    def _place(self, task: Task, a: int) -> tuple | bool:
        """``task``'s row writer into rows ``a...`` as ``(write, cone, takes_extra, dim, task)``, or False (a cone's
        ``write`` returns its error: its row is in the stack while it is positive, :meth:`Pointing.level`)."""
        kind, dim, w = type(task), task.dim, False
        if a + dim > self.J.shape[0]:
            self._grow(a + dim)
        J, b = self.J[a:a + dim], self.b[a:a + dim]
        if kind is Avoidance or (kind is Pointing and not (self.rate and task.inequality)):
            w = (task.row_writer(self.ctrl.state, self.order, J, b), kind is Pointing and task.inequality, False, dim,
                 task)
        elif kind.level is Task.level and (write := TaskProgram.of(task, self.ctrl.state, self.order, J, b)):
            w = (write, False, True, dim, task)  # (its row source: the compiled rows kernel)
        self._placed[(id(task), a)] = w
        return w

    def _rows(self, st, t: float, levels, extras) -> tuple[int, tuple[int, ...]]:
        """The planned levels' active rows (each level's tasks in turn) written into ``self.J``, ``self.b``: row count
        and level sizes."""
        order, a, sizes, placed = self.order, 0, [], self._placed
        made = self._made = []
        self._unchecked = False
        for g, level in enumerate(levels):
            a0 = a
            for task in level:
                extra = extras.get(task.name) if extras else None
                w = placed.get((id(task), a))
                if w is None or (w is not False and w[4] is not task):
                    w = self._place(task, a)
                if w is not False and (extra is None or w[2]):  # a row writer, writing in place
                    if w[1]:                  # the cone (21): its row while e > 0 (else an inactive level)
                        if not w[0](t) > 0.0:
                            made.append((task, a, 0, (self.J[a:a + 1].copy(), self.b[a:a + 1].copy()), g))
                            self._unchecked |= not sumsq(self.J[a]) + sumsq(self.b[a:a + 1]) <= MAX_SUMSQ
                            continue
                    elif extra is None:
                        w[0](t)
                    else:                     # with the extra command (Algorithm 1's EE repulsion (30))
                        w[0](t, extra)
                    if w[3]:
                        made.append((task, a, w[3], w[1], g))
                        a += w[3]
                    continue
                kind = type(task)
                lv = False                    # (the level of the result: False, equality rows; True, the cone row)
                if kind.level is Task.level or kind is Pointing and task.inequality and not self.rate:
                    Jt = task.jacobian(st)    # an equality task's own rows, no Level object; or Pointing.level's
                    bt = task.command(st, t, order, extra, Jt)
                    if kind is Pointing:      # cone row while e > 0 (else an inactive level, as the readable levels)
                        if not task.pointing_error(st) > 0.0:
                            made.append((task, a, 0, (Jt, bt), g))
                            self._unchecked |= not sumsq(Jt) + sumsq(bt) <= MAX_SUMSQ
                            continue
                        lv = True
                elif kind is PairAvoidance and self.rate and task.J.ndim == 2 and task.J.shape[0] == task.lower.size \
                        and (rows := task.rows_from(st.v)) is not None:
                    Jt, bt = rows  # its active rows seen from v; its level (PairAvoidance.level's) when a result asks
                    lv = partial(task.level_of, task.J, task.lower)
                else:
                    lv = task.level(st, t, order, extra)
                    if lv.b is not None:
                        Jt, bt = lv.J, lv.b
                    elif self.rate:  # its active rows seen from v, written shifted
                        Jt, bt = shifted(lv.check_finite(), st.v).as_equality()
                    else:
                        Jt, bt = lv.check_finite().as_equality()
                m = Jt.shape[0]
                if m:
                    if a + m > self.J.shape[0]:
                        self._grow(a + m)
                    self.J[a:a + m] = Jt
                    self.b[a:a + m] = bt
                if m or lv is not False and lv is not True:  # (a level without active rows: in the readable levels)
                    made.append((task, a, m, lv, g))
                a += m
            if a > a0:
                sizes.append(a - a0)
        return a, tuple(sizes)

    def _grow(self, rows: int) -> None:
        J, b = np.zeros((2 * rows, self.n)), np.zeros(2 * rows)
        J[: self.J.shape[0]], b[: self.b.shape[0]] = self.J, self.b
        self.J, self.b, self._bs = J, b, np.zeros(2 * rows)
        self._placed.clear()  # the writers wrote into the old arrays

    def compute(self) -> np.ndarray:
        """The command at the controller's current state (policy state advanced as in a step)."""
        ctrl = self.ctrl
        if not ctrl._started:
            ctrl.start()
        t, q, v = ctrl.t, ctrl._q, ctrl._v
        if self._kernel is not None and _robot_kernels.ENABLED:  # (one switch: hqp_tpm._jit's)
            if self._positions:  # (the kernel places the frames its tasks read; the CoM here when it reads it)
                st = ctrl.state.update_positions(q, v, t, self._frames, self._com)
            else:
                st = ctrl.state.update(q, v, t, validate=False, frames=self._frames)
            for gather in self._gathers:  # the program's tasks gather their arrays, the others write their rows
                gather(t)
            if self.damping:
                np.multiply(v, -self.damping, out=self._x0)
            if self._box_writer is not None:
                self._box_writer(st)  # the joint_box writes into the buffer's lo, up (else the kernel does)
            status = self._kernel(self._buf, self._ints, self._floats, q, v)
            if status == _compiled_step.PIVOT_SVD:  # a pivot block only its SVD decides: from now on the kernel
                kernel = _compiled_step.kernel(_compiled_step.TPM, svd=True)  # that decides every pivot at once
                self._kernel = kernel and _robot_kernels.typed(kernel, self._buf, self._ints, self._floats, q, v)
            return self._solve(st, t, self.J, self.b, self._sizes, status)
        st, policy = ctrl.state.update(q, v, t, validate=False), self.policy
        policy.update(st, t)
        if isinstance(policy, PlanningPolicy):
            tasks, extras = policy.plan(st, t)
            stack, levels = None, tuple((task,) for task in tasks)
        else:  # a StackPolicy
            stack = policy(st, t)
            levels, extras = stack.levels, stack.extras
            tasks = tuple(task for level in levels for task in level)
        self.tasks, self._extras, self._stack = tasks, extras, stack
        m, sizes = self._rows(st, t, levels, extras)
        x = self._solve(st, t, self.J[:m], self.b[:m], sizes)
        if policy.blends:
            x = self._blend(st, t, x)
        return x

    def _blend(self, st, t: float, x: np.ndarray) -> np.ndarray:
        """The policy's blend of ``x`` as the readable step blends (:meth:`Controller._blend`)."""
        ctrl = self.ctrl
        stack = self._stack if self._stack is not None else Stack([(task,) for task in self.tasks], self._extras)
        try:
            x = ctrl._blend(st, stack, x, ctrl.null_space_term(ctrl._v), self._box_now)
        except NonFiniteError as exc:  # named as the readable step names it (Controller._compute)
            raise type(exc)(f"{exc}{ctrl._where()}") from exc
        if not np.isfinite(x).all():
            raise SolverFailedError(f"solver {ctrl.solver!r} returned a non-finite command at t = {t:.6f}")
        return x

    def _solve(self, st, t: float, J: np.ndarray, b: np.ndarray, sizes: tuple[int, ...],
               status: int | None = None) -> np.ndarray:
        """The solution of the rows written (the readable step's solve); ``status``: the fused kernel's (None: no kernel
        ran yet; ``tpm``: finiteness, ``x0`` and the TPM kernel in one compiled call here)."""
        ctrl, kernel = self.ctrl, None
        if status is None:
            if not (self.sns or self.other) and sizes and _compiled.ENABLED:
                kernel = self._stacked = self._stacked or _compiled_step.stacked_kernel()
            # an inactive cone's row, or the rows NaN, inf or too large (one sum fails for all three; else the
            # kernel's test): the readable path raises the typed error naming the task
            if self._unchecked or kernel is None and not sumsq(J) + sumsq(b) <= MAX_SUMSQ:
                return ctrl._compute().command
            if kernel is not None:
                status = kernel(J, b, _compiled._sizes(sizes), ctrl._v, self.damping, self.lambda_max, self.eps,
                                _compiled._UNIT, MARGIN, COND, self._x0, self._out)
        if status == _compiled_step.SOLVED:
            if self.sns:
                self.info = None  # (the fused SNS kernel's, in the kept buffer)
            return self._out.copy()
        if status == _compiled_step.NONFINITE_ROWS:
            return ctrl._compute().command  # the readable path raises the typed error naming the task
        if status == _compiled_step.NONFINITE_X:
            raise SolverFailedError(f"solver {ctrl.solver!r} returned a non-finite command at t = {t:.6f}")
        # any other status hands the rows (found finite) back: WRITTEN (another solver's turn), DECLINED, UNDECIDED
        # or PIVOT_SVD (tpm_stacked's numpy reference decides), BOX_HANDED_BACK (the joint_box's recovery rules) or
        # SNS_HANDED_BACK (sns_tpm_stacked)
        if self.sns:
            return self._sns(st, t, J, b, sizes)
        if self.other:
            return self._registry(st, t, J, b)
        x0 = self._null_space_term(ctrl._v)  # (the kernels' x0 to the bit)
        if sizes:
            x = tpm_stacked(J, b, sizes, self.n, self.lambda_max, self.eps, x0, kernel_status=status)
        else:
            x = np.zeros(self.n) if x0 is None else x0.copy()
        if not all_finite(x):
            raise SolverFailedError(f"solver 'tpm' returned a non-finite command at t = {t:.6f}")
        return x

    def _sns(self, st, t: float, J: np.ndarray, b: np.ndarray, sizes: tuple[int, ...]) -> np.ndarray:
        """The SNS-TPM command from the stacked (finite) rows, as registry.solve (a rate box: as
        command_rate.solve_around, docs/internals.md#compiled-step)."""
        ctrl, n, v = self.ctrl, self.n, self.ctrl._v
        self._box_now = self.box(st) if self.box is not None else None
        lo, up = box = self._box_now or (np.full(n, -np.inf), np.full(n, np.inf))
        x0 = self._null_space_term(v)
        if self.rate:  # each run of a level's equality rows shifted at once (the readable step's bits of J v); an
            # inequality level's rows were written shifted
            bs, runs = self._bs[:J.shape[0]], []  # runs: [first row, end, level or -1]
            for _task, a, k, lv, g in self._made:
                if lv is not False and (type(lv) is partial or lv.b is None):
                    bs[a:a + k], g = b[a:a + k], -1
                if runs and runs[-1][2] == g:
                    runs[-1][1] = a + k
                else:
                    runs.append([a, a + k, g])
            for a0, e, g in runs:
                if g >= 0 and e > a0:
                    shift_rows(J[a0:e], b[a0:e], v, bs[a0:e])
            if not sumsq(bs) <= MAX_SUMSQ:
                return ctrl._compute().command
            b, x0, box = bs, -v, (lo - v, up - v)
        x, sinfo = sns_tpm_stacked(J, b, sizes, *box, lambda_max=self.lambda_max, eps=self.eps, return_info=True,
                                   x0=x0)
        if self.rate:
            x = np.minimum(np.maximum(v + x, lo), up)
        if not all_finite(x):
            raise SolverFailedError(f"solver 'sns_tpm' returned a non-finite command at t = {t:.6f}")
        self.info = {"scale": sinfo.scale, "saturated": list(sinfo.saturated), "iterations": sinfo.iterations}
        return x

    def _registry(self, st, t: float, J: np.ndarray, b: np.ndarray) -> np.ndarray:
        """Any other solver's command: the readable step's levels of the rows written, solved as
        :meth:`Controller._solve_levels` solves."""
        ctrl = self.ctrl
        self._box_now = box = self.box(st) if self.box is not None else None
        x, info = ctrl._solve_levels(self._levels(J, b, self._made), ctrl.null_space_term(ctrl._v), box)
        if not all_finite(x):
            raise SolverFailedError(f"solver {ctrl.solver!r} returned a non-finite command at t = {t:.6f}")
        self.info = info
        return x

    def current(self) -> bool:
        """Whether the step still fits the controller's policy (a fused stack: no level replaced or added)."""
        if self._program is None:
            return True
        stack = self.ctrl._policy.stack
        return stack is self._stack and stack.levels == self._levels_planned and not stack.extras

    def result(self, t: float, q: np.ndarray, v: np.ndarray, x: np.ndarray) -> StepResult:
        """The :class:`StepResult` of ``x`` computed at ``(q, v, t)``, keeping a copy of the rows written."""
        r = _new(StepResult)  # (the fields not set here are computed on first read: StepResult's defaults)
        r.t, r.command, info, box = t, x, self.info, self._box_now
        if box is not None and type(self.planned_box) is not JointLimits:  # (a box function may read more than the
            r._box = box[0].copy(), box[1].copy()  # state: the box the step used, not one computed when read)
        if self._program is not None:  # (J and b in one buffer, with the fused SNS solve's info when it solved)
            r._stack = self._stack
            if info is None:
                r._kept = (self, q, v, self._buf.copy(), self._made)
            else:
                r._kept, r._info = (self, q, v, self._flat.copy(), self._made), info or {}
            return r
        made = self._made
        m = made[-1][1] + made[-1][2] if made else 0
        r._info = info if self.sns or self.other else {}
        r._kept = (self, q, v, (self.J[:m].copy(), self.b[:m].copy()), made, self.tasks, self._extras, self._stack)
        return r

    def info_of(self, r: StepResult) -> dict:
        return self._program.sns_info(r._kept[3])

    def stack_of(self, r: StepResult) -> Stack:
        kept = r._kept  # (kept[7]: the stack a StackPolicy gave)
        return kept[7] if kept[7] is not None else Stack([(task,) for task in kept[5]], kept[6])

    def levels_of(self, r: StepResult) -> list[Level]:
        rows = r._kept[3]
        if type(rows) is not tuple:  # (the fused step's buffer)
            m, n = self.b.size, self.n
            rows = rows[: m * n].reshape(m, n), rows[m * n: m * n + m]
        return self._levels(*rows, r._kept[4])

    def x0_of(self, r: StepResult) -> np.ndarray | None:
        """The null-space term ``-D qd`` at the kept state, with the damping ``D`` the step was planned with."""
        return self._null_space_term(r._kept[2])

    def _null_space_term(self, v: np.ndarray) -> np.ndarray | None:
        """``x0 = -D v`` with the damping ``D`` the step was planned with (eq. (15) of papers/000; None without)."""
        return -self.damping * v if self.damping else None

    def box_of(self, r: StepResult) -> tuple[np.ndarray, np.ndarray] | None:
        """The box the step was planned with at the kept state (in :meth:`Controller.scratch_state`)."""
        box = self.planned_box
        if box is None:
            return None
        return box(self.ctrl.scratch_state().update(r._kept[1], r._kept[2], r.t, validate=False), r.t)

    @staticmethod
    def _levels(J: np.ndarray, b: np.ndarray, made: list) -> list[Level]:
        """The readable step's levels of the rows ``J``, ``b`` written as ``made`` says."""
        groups: dict[int, list[Level]] = {}
        for task, a, k, lv, g in made:
            if lv is False:
                lv = Level(J[a:a + k], b[a:a + k], name=task.name, defer_finite=True)
            elif lv is True:  # a pointing cone's row while e > 0 (Pointing.level)
                lv = task.cone_level(J[a:a + k], b[a:a + k], True)
            elif type(lv) is tuple:  # its row while e <= 0: an inactive level
                lv = task.cone_level(*lv, False)
            elif type(lv) is partial:  # a PairAvoidance's level (_rows)
                lv = lv()
            groups.setdefault(g, []).append(lv)
        return [parts[0] if len(parts) == 1 else merge_levels(parts) for parts in groups.values()]

    def label_of(self, kept: tuple) -> str:
        if self._label is not None:  # (a fused stack's)
            return self._label
        if kept[7] is not None:
            return kept[7].label()
        return " > ".join(task.name for task in kept[5])

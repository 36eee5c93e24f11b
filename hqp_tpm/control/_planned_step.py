"""The planned step: ``ctrl.step()`` of every policy that plans (:class:`PlanningPolicy`, :class:`StackPolicy`),
of a fixed stack the lean step does not take (a pointing cone) and of a stack function. Per step: state update,
``policy.update``, the plan, the rows written into one stacked ``J``, ``b``, one solve, the blend. Same numbers as
the readable step (``tests/test_planned_step.py``). Details: docs/architecture.md, "How ctrl.step() runs compiled".
"""

from __future__ import annotations

import numpy as np

from hqp_tpm.control import _compiled_step
from hqp_tpm.control._lean import JointBox
from hqp_tpm.control._task_rows import TaskProgram
from hqp_tpm.control.command_rate import rate_limited, shifted, solve_around
from hqp_tpm.control.policy import FixedStack, FunctionPolicy, PlanningPolicy, Policy, StackPolicy
from hqp_tpm.control.stack import Stack, merge_levels
from hqp_tpm.control.step_result import LAZY, CompiledStep, StepResult
from hqp_tpm.errors import NonFiniteError, SolverFailedError
from hqp_tpm.robot.limits import JointLimits
from hqp_tpm.solvers import _compiled
from hqp_tpm.solvers._fullrank import COND, MARGIN
from hqp_tpm.solvers.levels import MAX_SUMSQ, Level, all_finite, sumsq
from hqp_tpm.solvers.registry import ANALYTIC, solve
from hqp_tpm.solvers.sns import sns_tpm_stacked
from hqp_tpm.solvers.tpm import tpm_stacked
from hqp_tpm.tasks.avoidance import Avoidance, PairAvoidance
from hqp_tpm.tasks.base import Task
from hqp_tpm.tasks.pointing import Pointing


def planned(policy: Policy) -> bool:
    """Whether the planned step takes ``policy``'s stacks: a :class:`PlanningPolicy` or :class:`StackPolicy` (every
    shipped policy), a :class:`FixedStack` or a stack function (:class:`FunctionPolicy`)."""
    return isinstance(policy, (PlanningPolicy, StackPolicy)) or type(policy) in (FixedStack, FunctionPolicy)


class PlannedStep(CompiledStep):
    """The lean step of a :class:`~hqp_tpm.control.controller.Controller` whose policy plans (build it with :meth:`of`).

    :meth:`compute` gives the command of the readable step at the controller's state (``ctrl.step()`` runs it:
    :class:`~hqp_tpm.control.step_result.CompiledStep`). The controller stays the owner of the state.
    """

    __slots__ = ("ctrl", "policy", "n", "order", "lambda_max", "eps", "damping", "J", "b", "tasks", "_labels",
                 "_placed", "_kernel", "_x0", "_extras", "_made", "sns", "rate", "box", "info",
                 "_bs", "_stack", "_box_now", "other", "_unchecked",
                 "planned_box")

    @staticmethod
    def why_not(ctrl) -> str | None:
        """Why the planned step does not apply to ``ctrl`` (None when it does)."""
        policy = ctrl.policy
        if not planned(policy):
            return (f"the policy {type(policy).__name__} is not a PlanningPolicy (no plan()), StackPolicy, FixedStack "
                    "nor FunctionPolicy")
        if ctrl.box is not None and ctrl.solver == "tpm":
            return "a box with solver 'tpm', which ignores it"
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
        self.J = np.zeros((8, self.n))
        self.b = np.zeros(8)
        self.tasks: tuple[Task, ...] = ()
        self._extras: dict = {}
        self._made: list = []  # per level of the last step: (task, first row, rows, its Level or None: equality rows)
        self._labels: dict[tuple[str, ...], str] = {}
        # the pointing and the avoidance tasks write straight into the stacked rows (their row writers: one compiled
        # call each): one writer per (task, first row), built on first use (_place)
        self._placed: dict[tuple[int, int], tuple | bool] = {}
        self._kernel, self._x0 = [None, None], np.zeros(self.n)  # the compiled solves of m <= n, m > n
        # sns_tpm: the stacked rows solved in the joint limits' box (JointBox: the box's numbers in fewer calls), the
        # null-space term x0 one more, lowest level (as the registry adds it); the box bounds the command's rate
        # (velocity level): the rows shifted by J v and solved for the change (command_rate.solve_around)
        self.sns = ctrl.solver == "sns_tpm"
        # any other solver (nullspace, sns, the cascaded QP): the readable step's levels, made of the rows written
        # here, solved through the registry (hqp_tpm.solvers.registry.solve), as Controller._solve_step does
        self.other = ctrl.solver not in ("tpm", "sns_tpm")
        self.rate = ctrl.solver not in ANALYTIC and ctrl.order == 1 and rate_limited(ctrl.box)
        joint = type(ctrl.box) is JointLimits
        self.planned_box = box = ctrl.box
        self.box = JointBox(box) if joint else None if box is None else (lambda st: box(st, ctrl.t))
        self.info: dict = {}
        self._bs = np.zeros(8)  # (rate: the shifted right-hand sides b - J v)
        self._stack = self._box_now = None
        self._unchecked = False  # (an inactive cone's row not finite: the readable step decides, _solve)
        return self

    def _place(self, task: Task, a: int) -> tuple | bool:
        """The row writer of ``task`` writing rows ``a...`` of ``self.J``, ``self.b`` as ``(write, cone, takes_extra,
        dim, task)``, or False for a task without one (an inequality pointing task's ``write`` returns its error: its
        row is in the stack while it is positive, as :meth:`Pointing.level` says)."""
        kind, dim, w = type(task), task.dim, False
        if a + dim > self.J.shape[0]:
            self._grow(a + dim)
        J, b = self.J[a:a + dim], self.b[a:a + dim]
        if kind is Avoidance or (kind is Pointing and not (self.rate and not self.other and task.inequality)):
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
                    m = w[3]
                    if not m:
                        continue
                    made.append((task, a, m, w[1], g))
                    a += m
                    continue
                kind = type(task)
                lv = False                    # (the level of the result: False, equality rows; True, the cone row)
                if kind.level is Task.level:  # an equality task: its own rows, no Level object
                    Jt = task.jacobian(st)
                    bt = task.command(st, t, order, extra, Jt)
                elif kind is Avoidance:       # Avoidance.level: the equality (J, command), extra unused
                    Jt, bt = task.jacobian(st), task.command(st, t, order)
                elif kind is Pointing and task.inequality and (self.other or not self.rate):  # Pointing.level: its
                    # cone row while e > 0
                    Jt = task.jacobian(st)
                    bt = task.command(st, t, order, extra, Jt)
                    if not task.pointing_error(st) > 0.0:  # (an inactive level, as in the readable levels)
                        made.append((task, a, 0, (Jt, bt), g))
                        self._unchecked |= not sumsq(Jt) + sumsq(bt) <= MAX_SUMSQ
                        continue
                    lv = True
                elif kind is PairAvoidance and self.rate and not self.other and task.J.ndim == 2 \
                        and task.J.shape[0] == task.lower.size and (rows := task.rows_from(st.v)) is not None:
                    Jt, bt = rows  # its active rows seen from v; its level built when a result asks
                    lv = _PairLevel(task, task.J, task.lower)
                else:
                    lv = task.level(st, t, order, extra)
                    if lv.b is not None:
                        Jt, bt = lv.J, lv.b
                    elif self.rate and not self.other:  # its active rows seen from v, written shifted
                        Jt, bt = shifted(lv.check_finite(), st.v).as_equality()
                    else:
                        Jt, bt = lv.check_finite().as_equality()
                m = Jt.shape[0]
                if not m:
                    if lv is not False and lv is not True:  # a level without active rows, in the readable levels too
                        made.append((task, a, 0, lv, g))
                    continue
                if a + m > self.J.shape[0]:
                    self._grow(a + m)
                self.J[a:a + m] = Jt
                self.b[a:a + m] = bt
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
        ctrl, policy = self.ctrl, self.policy
        if not ctrl._started:
            ctrl.start()
        t = ctrl.t
        st = ctrl.state.update(ctrl._q, ctrl._v, t, validate=False)
        policy.update(st, t)
        if isinstance(policy, PlanningPolicy):
            tasks, extras = policy.plan(st, t)
            stack, levels = None, tuple((task,) for task in tasks)
        else:  # a StackPolicy
            stack = policy(st, t)
            levels, extras = stack.levels, stack.extras
            tasks = tuple(task for level in levels for task in level)
        self.tasks, self._extras, self._stack = tasks, extras, stack
        x = self._solve(st, t, levels, extras)
        if policy.blends:
            x = self._blend(st, t, x)
        return x

    def _blend(self, st, t: float, x: np.ndarray) -> np.ndarray:
        """The policy's blend of ``x`` with other stacks solved as the readable step solves them
        (:meth:`Controller._solve_step`), clipped into the box when there is one."""
        ctrl, n, box = self.ctrl, self.n, self._box_now
        x0 = ctrl.null_space_term(ctrl._v)

        def resolve(other: Stack) -> np.ndarray:
            try:
                levels = other.to_levels(st, t, self.order)
                if self.rate:
                    return solve_around(ctrl.solver, levels, n, ctrl._v, box, lambda_max=self.lambda_max,
                                        eps=self.eps, solve=solve)[0]
                return solve(ctrl.solver, levels, n, x0=x0, box=box, lambda_max=self.lambda_max, eps=self.eps)[0]
            except NonFiniteError as exc:  # named as the readable step names it (Controller._compute)
                raise type(exc)(f"{exc}{ctrl._where()}") from exc

        stack = self._stack if self._stack is not None else Stack([(task,) for task in self.tasks], self._extras)
        x = self.policy.blend(st, t, stack, x, resolve)
        if box is not None:
            x = np.minimum(np.maximum(x, box[0]), box[1])
        if not np.isfinite(x).all():
            raise SolverFailedError(f"solver {ctrl.solver!r} returned a non-finite command at t = {t:.6f}")
        return x

    def _solve(self, st, t: float, levels, extras) -> np.ndarray:
        """The solution of the planned levels' rows (the readable step's solve)."""
        ctrl = self.ctrl
        m, sizes = self._rows(st, t, levels, extras)
        J, b = self.J[:m], self.b[:m]
        # an inactive cone's row, or (sns_tpm, other solvers) the rows, NaN, inf or too large (one sum fails for all
        # three): the readable path raises the typed error naming the task
        if self._unchecked or (self.sns or self.other) and not sumsq(J) + sumsq(b) <= MAX_SUMSQ:
            return ctrl._compute().command
        if self.sns:
            return self._sns(st, t, J, b, sizes)
        if self.other:
            return self._registry(st, t, J, b)
        status = None  # (the compiled kernel's answer, if it ran and declined)
        if sizes and _compiled.ENABLED:  # finiteness, x0 and the TPM kernel in one compiled call (same numbers)
            tall = m > self.n
            kernel = self._kernel[tall] or self._load_kernel(tall)
            if kernel is not None:
                x, x0 = np.empty(self.n), self._x0
                status = kernel(J, b, _compiled._sizes(sizes), ctrl._v, self.damping, self.lambda_max, self.eps,
                                _compiled._UNIT, MARGIN, COND, x0, x)
                if status == _compiled_step.SOLVED:
                    return x
                if status == _compiled_step.NONFINITE_ROWS:
                    return ctrl._compute().command  # the readable path raises the typed error naming the task
                if status == _compiled_step.NONFINITE_X:
                    raise SolverFailedError(f"solver 'tpm' returned a non-finite command at t = {t:.6f}")
                # DECLINED / UNDECIDED: tpm_stacked's numpy reference decides, below, on the rows the kernel found
                # finite, with the x0 it wrote
        if status is None:
            if not sumsq(J) + sumsq(b) <= MAX_SUMSQ:  # NaN, inf or too large rows (one sum fails for all three):
                return ctrl._compute().command      # the readable path raises the typed error naming the task
            x0 = -self.damping * ctrl._v if self.damping else None
        else:
            x0 = self._x0 if self.damping else None
        if sizes:
            x = tpm_stacked(J, b, sizes, self.n, self.lambda_max, self.eps, x0, kernel_status=status)
        else:
            x = np.zeros(self.n) if x0 is None else x0.copy()
        if not all_finite(x):
            raise SolverFailedError(f"solver 'tpm' returned a non-finite command at t = {t:.6f}")
        return x

    def _sns(self, st, t: float, J: np.ndarray, b: np.ndarray, sizes: tuple[int, ...]) -> np.ndarray:
        """The SNS-TPM command from the stacked (finite) rows, as the readable step solves them (registry.solve, and
        command_rate.solve_around when the box bounds the command's rate)."""
        ctrl, n = self.ctrl, self.n
        self._box_now = self.box(st) if self.box is not None else None
        lo, up = self._box_now or (np.full(n, -np.inf), np.full(n, np.inf))
        if self.rate:  # the levels seen from v, one more level d = -v, the box around v (solve_around)
            v = ctrl._v
            bs = self._bs[:J.shape[0]]
            for _task, a, k, lv, _g in self._made:
                if lv is False or lv.b is not None:  # equality rows (an inequality level's are written shifted)
                    np.subtract(b[a:a + k], J[a:a + k] @ v, out=bs[a:a + k])
                else:
                    bs[a:a + k] = b[a:a + k]
            if not sumsq(bs) <= MAX_SUMSQ:
                return ctrl._compute().command
            d, sinfo = sns_tpm_stacked(J, bs, sizes, lo - v, up - v, lambda_max=self.lambda_max, eps=self.eps,
                                       return_info=True, x0=-v)
            x = np.minimum(np.maximum(v + d, lo), up)
        else:
            x, sinfo = sns_tpm_stacked(J, b, sizes, lo, up, lambda_max=self.lambda_max, eps=self.eps,
                                       return_info=True, x0=ctrl.null_space_term(ctrl._v))
        if not all_finite(x):
            raise SolverFailedError(f"solver 'sns_tpm' returned a non-finite command at t = {t:.6f}")
        self.info = {"scale": sinfo.scale, "saturated": list(sinfo.saturated), "iterations": sinfo.iterations}
        return x

    def _registry(self, st, t: float, J: np.ndarray, b: np.ndarray) -> np.ndarray:
        """The command of any other solver: the readable step's levels (:meth:`levels_of` of the rows written)
        solved through the registry, or around ``v`` when the box bounds the command's rate (as
        :meth:`Controller._solve_step`)."""
        ctrl = self.ctrl
        self._box_now = box = self.box(st) if self.box is not None else None
        levels = self._levels(J, b, self._made)
        if self.rate:
            x, info = solve_around(ctrl.solver, levels, self.n, ctrl._v, box, lambda_max=self.lambda_max,
                                   eps=self.eps, solve=solve)
        else:
            x, info = solve(ctrl.solver, levels, self.n, x0=ctrl.null_space_term(ctrl._v), box=box,
                            lambda_max=self.lambda_max, eps=self.eps)
        if not all_finite(x):
            raise SolverFailedError(f"solver {ctrl.solver!r} returned a non-finite command at t = {t:.6f}")
        self.info = info
        return x

    def _load_kernel(self, tall: bool):
        """The compiled solve of :meth:`compute` for ``m > n`` rows (``tall``) or not
        (:func:`hqp_tpm.control._compiled_step.stacked_kernel`)."""
        self._kernel[tall] = _compiled_step.stacked_kernel(tall)
        return self._kernel[tall]

    def current(self) -> bool:
        """Always: the stack is planned at every step."""
        return True

    def result(self, t: float, q: np.ndarray, v: np.ndarray, x: np.ndarray) -> StepResult:
        """The :class:`StepResult` of the command ``x`` computed at ``(q, v, t)``, keeping a copy of the rows written
        (its stack and levels, the readable step's, built when asked)."""
        made = self._made
        m = made[-1][1] + made[-1][2] if made else 0
        rows = (self.J[:m].copy(), self.b[:m].copy(), made, self.tasks, self._extras, self._stack)
        return StepResult(t, LAZY, LAZY, x, self.info if self.sns or self.other else {}, LAZY, LAZY, (self, q, v, rows))

    def stack_of(self, kept: tuple) -> Stack:
        if kept[3][5] is not None:  # (the stack a StackPolicy policy gave)
            return kept[3][5]
        return Stack([(task,) for task in kept[3][3]], kept[3][4])

    def levels_of(self, kept: tuple) -> list[Level]:
        return self._levels(*kept[3][:3])

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
            elif type(lv) is _PairLevel:
                lv = lv.level()
            groups.setdefault(g, []).append(lv)
        return [parts[0] if len(parts) == 1 else merge_levels(parts) for parts in groups.values()]

    def label_of(self, kept: tuple) -> str:
        if kept[3][5] is not None:
            return kept[3][5].label()
        key = tuple(task.name for task in kept[3][3])
        text = self._labels.get(key)
        if text is None:
            text = self._labels[key] = " > ".join(key)
        return text


class _PairLevel:
    """A :class:`PairAvoidance`'s level at a step (its ``J`` and ``lower`` then), built when a result asks for it:
    :meth:`PairAvoidance.level`'s numbers."""

    __slots__ = ("task", "J", "lower")
    b = None  # (an inequality level)

    def __init__(self, task: PairAvoidance, J: np.ndarray, lower: np.ndarray):
        self.task, self.J, self.lower = task, J, lower

    def level(self) -> Level:
        return self.task.level_of(self.J, self.lower)

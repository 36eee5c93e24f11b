"""The control loop: one state update, the policy's stack, one solve, one integration per step.

Velocity level: ``qd = solve(levels)``, ``q <- q + qd T``. Acceleration level: ``qdd = solve(levels) + (I - J# J)
qdd_0``, ``qdd_0 = -D qd`` (eqs. (14)-(15) of papers/000), ``q <- q + qd T + qdd T^2 / 2``, ``qd <- qd + qdd T``. A
policy that ``blends`` (eq. (8) of papers/003) turns the solution into the command (clipped into a hard box). A step is
transactional: on any error the controller and the policy (:meth:`Policy.snapshot`) keep their state."""

from __future__ import annotations

import math
from collections.abc import Callable
from numbers import Real

import numpy as np
from scipy.linalg.blas import ddot as _ddot

from hqp_tpm.control._planned_step import PlannedStep, planned
from hqp_tpm.control.command_rate import rate_limited, solve_around
from hqp_tpm.control.crosscheck import CrosscheckLog, crosscheck_step
from hqp_tpm.control.policy import FixedStack, FunctionPolicy, Policy
from hqp_tpm.control.stack import Stack
from hqp_tpm.control.step_result import StepResult
from hqp_tpm.errors import ArgumentTypeError, NonFiniteError, ParameterError, SolverFailedError
from hqp_tpm.robot.limits import JointLimits
from hqp_tpm.robot.model import Robot
from hqp_tpm.robot.state import State
from hqp_tpm.solvers.damping import check_damping, nonnegative
from hqp_tpm.solvers.levels import all_finite
from hqp_tpm.solvers.registry import ANALYTIC, BOXED, check_solver_name, solve
from hqp_tpm.tasks.base import Task

BoxFn = Callable[[State, float], tuple[np.ndarray, np.ndarray]]


class Controller:
    """Holds the robot state, a policy, a solver name and the integration rule. ``policy``: a :class:`Policy`, a
    :class:`Stack` or list of levels (a :class:`FixedStack`), or a callable ``f(state, t) -> Stack``."""

    def __init__(self, robot: Robot, policy, *, order: int = 2, dt: float = 1e-3, solver: str = "tpm",
                 lambda_max: float = 0.0, eps: float = 0.0, nullspace_damping: float = 0.0,
                 box: BoxFn | None = None, q0=None, v0=None, t0: float = 0.0, crosscheck: str | None = None):
        self.robot = robot
        self._policy = as_policy(policy)
        self.order, self.dt, self.solver, self.lambda_max, self.eps = order, dt, solver, lambda_max, eps
        self.nullspace_damping, self.box = nullspace_damping, box
        self.crosscheck = crosscheck  # a second solver run on every step, like for like (hqp_tpm.control.crosscheck)
        self._check_settings()
        self.crosscheck_log = CrosscheckLog()
        self.state = State(robot)
        q = robot.neutral() if q0 is None else q0
        v = np.zeros(robot.nv) if v0 is None else v0
        self._q, self._v = self.state.check(q, v)
        self.a = np.zeros(robot.nv)
        self.t = float(t0)
        self.steps = 0
        self._started, self._begun = False, {}  # (id -> task: the tasks this controller started)
        self._fast, self._checked, self._scratch = False, None, None  # the compiled step (False: not planned), the
        # settings it was planned for (and last checked)

    def __getstate__(self) -> dict:
        """Copied and pickled without its compiled step (it reads this controller's arrays by address)."""
        return {**self.__dict__, "_fast": False}

    def __repr__(self) -> str:
        level = "velocity" if self.order == 1 else "acceleration"
        return (f"Controller({self.robot.name!r}, {level} level, dt={self.dt:g}, solver={self.solver!r}, "
                f"t={self.t:.4f}, steps={self.steps})")

    # ------------------------------------------------------------------------------------------
    @property
    def q(self) -> np.ndarray:
        """Joint configuration (assigning it validates it, like :meth:`set_state`)."""
        return self._q

    @q.setter
    def q(self, value) -> None:
        self._q, _ = self.state.check(value, self._v)

    @property
    def policy(self) -> Policy:
        """The policy (assigning a Stack, list of levels or callable wraps it, like the constructor; after the first
        step, the tasks it brings are started at the current state)."""
        return self._policy

    @policy.setter
    def policy(self, value) -> None:
        new = as_policy(value)
        if self._started:  # the tasks it brings start at the current state (not those started before: they go on)
            self._begun.update((id(task), task) for task in self._policy.tasks())
            entering = [task for task in new.tasks() if id(task) not in self._begun]
            if entering:  # (no kinematics update for a policy that brings none)
                self.start(entering)
            if isinstance(new, FunctionPolicy):
                new.started(self._begun.values())
        self._policy = new

    @property
    def v(self) -> np.ndarray:
        """Joint velocity (assigning it validates it)."""
        return self._v

    @v.setter
    def v(self, value) -> None:
        _, self._v = self.state.check(self._q, value)

    def tasks(self) -> list[Task]:
        """All tasks the policy may use (for start-up and logging)."""
        return list(self.policy.tasks())

    def start(self, tasks=None) -> None:
        """Initialise relative targets from the current state (the first step: every task; ``tasks``: those, e.g. a
        task given a relative target after the first step)."""
        self.state.update(self.q, self.v, self.t)
        for task in self.tasks() if tasks is None else tasks:
            task.start(self.state)
            self._begun[id(task)] = task
        self._started = True

    def solve_inputs(self, state: State, t: float, v: np.ndarray):
        """``(x0, box)`` of the solve at ``state``: the null-space damping term ``-D qd`` (acceleration level, eq. (15)
        of papers/000) and the hard box of the command (None when unused)."""
        box = self.box(state, t) if self.box is not None else None
        return self.null_space_term(v), box

    def null_space_term(self, v: np.ndarray) -> np.ndarray | None:
        """``x0 = -D qd`` at acceleration level (eq. (15) of papers/000), None without damping or at velocity level."""
        return -self.nullspace_damping * v if (self.order == 2 and self.nullspace_damping) else None

    def scratch_state(self) -> State:
        """A second :class:`State` of the robot (where a compiled step's :class:`StepResult` computes its fields)."""
        if self._scratch is None:
            self._scratch = State(self.robot)
        return self._scratch

    def _where(self) -> str:
        """Where a step failed: the time and the size of the state it started from (a run that diverged overflows into
        NaN long after the cause; ``max|v|`` of 1e250 says so at once)."""
        return (f" (step at t = {self.t:.6f} from max|q| = {np.abs(self._q).max():.3g}, "
                f"max|v| = {np.abs(self._v).max():.3g})")

    def _compute(self) -> StepResult:
        try:
            return self._solve_step()
        except NonFiniteError as exc:  # name the state: a NaN in a level may come from a diverged state
            raise type(exc)(f"{exc}{self._where()}") from exc  # (its kind kept: MagnitudeError stays one)

    def _solve_step(self) -> StepResult:
        if not self._started:
            self.start()
        st = self.state.update(self._q, self._v, self.t, validate=False)  # checked whenever they are set
        policy = self.policy
        policy.update(st, self.t)
        stack = policy(st, self.t)
        levels = stack.to_levels(st, self.t, self.order)
        x0, box = self.solve_inputs(st, self.t, self.v)
        x, info = self._solve_levels(levels, x0, box)
        check = crosscheck_step(self, st, stack, levels, x0, box, x) if self.crosscheck else None
        if policy.blends:
            x = self._blend(st, stack, x, x0, box)
        if not np.isfinite(x).all():
            raise SolverFailedError(f"solver {self.solver!r} returned a non-finite command at t = {self.t:.6f}")
        if check is not None:
            info = {**info, "crosscheck": check(x)}
        return StepResult(self.t, stack, levels, x, info, x0, box)

    def _blend(self, st: State, stack: Stack, x: np.ndarray, x0: np.ndarray | None, box) -> np.ndarray:
        """The policy's blend of the solution ``x`` of ``stack`` (smooth stack transitions, eq. (8) of papers/003):
        ``resolve`` solves another stack as the step does; the solver's hard box holds for the blend too."""
        def resolve(other: Stack) -> np.ndarray:
            return self._solve_levels(other.to_levels(st, self.t, self.order), x0, box)[0]
        x = self._policy.blend(st, self.t, stack, x, resolve)
        if box is not None and self.solver not in ANALYTIC:
            x = np.minimum(np.maximum(x, box[0]), box[1])
        return x

    def _solve_levels(self, levels, x0: np.ndarray | None, box) -> tuple[np.ndarray, dict]:
        """``(x, info)``: ``levels`` solved with this controller's solver and settings, ``x0`` and ``box`` (when the box
        bounds the command's rate: the stack solved for the change, :func:`solve_around`)."""
        if box is not None and self.order == 1 and rate_limited(self.box) and self.solver not in ANALYTIC:
            return solve_around(self.solver, levels, self.robot.nv, self._v, box, lambda_max=self.lambda_max,
                                eps=self.eps, solve=solve)
        return solve(self.solver, levels, self.robot.nv, x0=x0, box=box, lambda_max=self.lambda_max, eps=self.eps)

    def _check_settings(self) -> None:
        """The settings checked (and normalized) as the constructor checks them; a setting assigned later is checked by
        the next step (a refused one raises there, and the step changes nothing)."""
        if self.order not in (1, 2) or type(self.order) is bool:
            raise ParameterError(f"order must be 1 (velocity level) or 2 (acceleration level), got {self.order!r}")
        if not (isinstance(self.dt, Real) and not isinstance(self.dt, bool) and math.isfinite(self.dt) and self.dt > 0):
            raise ParameterError(f"period dt = {self.dt!r} must be a finite number > 0 (seconds)")
        self.order, self.dt, self.solver = int(self.order), float(self.dt), check_solver_name(self.solver)
        self.lambda_max, self.eps = check_damping(self.lambda_max, self.eps)
        self.nullspace_damping = nonnegative("nullspace_damping", self.nullspace_damping)
        self.box = check_box(self.box, self.solver, self.order, self.dt)
        self.crosscheck = None if self.crosscheck is None else check_solver_name(self.crosscheck)

    def _compiled_step(self, record: bool = False):
        """The compiled step (None: the readable step, or ``record``), planned again when the policy, a setting (then
        checked again) or its stack's structure changed: a :class:`PlannedStep` where :func:`planned`, else
        :meth:`Policy.compiled_step`."""
        key = (self._policy, self.solver, self.order, self.dt, self.box, self.crosscheck, self.lambda_max, self.eps,
               self.nullspace_damping)
        if key != self._checked:
            self._check_settings()
            self._checked, self._fast = key, False
        fast = self._fast
        if record:
            return None
        if fast is False or (fast is not None and not fast.current()):
            policy = self._policy
            fast = self._fast = PlannedStep.of(self) if planned(policy) else policy.compiled_step(self)
        return fast

    def compiled(self) -> bool:
        """Whether :meth:`step` runs its planned step under the current set-up (compiled by numba unless
        ``HQP_TPM_COMPILED=0``; else the readable path)."""
        return self._compiled_step() is not None

    def compute(self, record: bool = False) -> StepResult:
        """State update, policy, solve: the command at the current state (no integration; the policy's state advances,
        restored on an error). ``record``: the readable path (Task -> Level -> solver), every field computed at once;
        else the compiled step where there is one (the same numbers, fields computed on demand)."""
        fast = self._compiled_step(record)
        started, saved = self._started, self._policy.snapshot()
        try:
            if fast is None:
                return self._compute()
            return fast.result(self.t, self._q, self._v, fast.compute())
        except BaseException:
            self._policy.restore(saved)
            self._started = started
            raise

    def step(self, record: bool = False) -> StepResult:
        """One control step, transactional: on any error the controller and its policy keep their state. ``record``: as
        in :meth:`compute` (the readable path; ``--explain`` and the crosscheck read its record)."""
        t, q, v = self.t, self._q, self._v
        fast = self._compiled_step(record)
        if fast is not None:
            return fast.result(t, q, v, self.advance(fast.compute))
        out = []
        self.advance(lambda: out.append(self._compute()) or out[0].command)
        res = out[0]
        if "crosscheck" in res.info:
            self.crosscheck_log.append(t, res.info["crosscheck"])
        return res

    def advance(self, command: Callable[[], np.ndarray]) -> np.ndarray:
        """Compute a command with ``command()``, integrate it over ``dt`` and advance the controller; returns the
        command. Transactional (the one place a step is committed)."""
        started, saved = self._started, self._policy.snapshot()
        try:
            x = command()
            q, v = self.state.integrate(self._q, self._v, x, self.dt, self.order)
            if not (math.isfinite(_ddot(q, q) + _ddot(v, v)) or (all_finite(q) and all_finite(v))):
                raise NonFiniteError(f"integration produced a non-finite state{self._where()}")
        except BaseException:
            self._policy.restore(saved)
            self._started = started
            raise
        self._q, self._v = q, v
        if self.order == 2:
            self.a = x.copy()
        self.t += self.dt
        self.steps += 1
        return x

    def set_state(self, q, v=None) -> None:
        """Replace the state after validation (nothing changes if it is rejected)."""
        self._q, self._v = self.state.check(q, v)


def as_policy(policy) -> Policy:
    """A :class:`Policy` from a policy, a :class:`Stack`/list of levels, or a callable ``f(state, t) -> Stack``."""
    if isinstance(policy, Policy):
        return policy
    if isinstance(policy, (Stack, list, tuple)):
        return FixedStack(policy)
    if callable(policy):
        return FunctionPolicy(policy)
    raise ArgumentTypeError(f"a policy must be a Policy, a Stack, a list of levels or a callable, got "
                            f"{type(policy).__name__}")


def check_box(box: BoxFn | None, solver: str, order: int, dt: float) -> BoxFn | None:
    """``box`` if the controller can use it: refused with an analytic solver (it would be ignored, as a scenario file's
    ``[limits]`` is refused), and a :class:`JointLimits` must have the controller's ``order`` and ``dt``."""
    if box is None:
        return None
    if not callable(box):
        raise ArgumentTypeError(f"box must be None or a callable box(state, t) -> (lower, upper), e.g. "
                                f"JointLimits(robot, order=..., dt=...); got {type(box).__name__}")
    if solver in ANALYTIC:
        raise ParameterError(f"box: a hard joint box, which solver {solver!r} ignores; valid: a boxed solver "
                             f"({', '.join(BOXED)}, qp, qp:<backend>), or box=None")
    if isinstance(box, JointLimits) and (box.order != order or not np.isclose(box.dt, dt, rtol=1e-9, atol=0.0)):
        raise ParameterError(f"box: JointLimits(order={box.order}, dt={box.dt:g}) does not match the controller's "
                             f"order={order}, dt={dt:g}: build it with JointLimits(robot, order={order}, dt={dt:g})")
    return box

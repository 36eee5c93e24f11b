"""The task interface and the tracking command it turns into a solver level.

Velocity level (order 1):      ``b = xd_d + kp e``                      (CLIK, eq. (7) of papers/000)
Acceleration level (order 2):  ``b = xdd_d + kd (xd_d - J qd) + kp e - Jdot qd``  (eq. (12))
with ``e = x_d - x``. An ``extra`` vector (e.g. the EE repulsion of eq. (30)) is added to the desired
velocity/acceleration before the feedback terms."""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass
from functools import cache, partial

import numpy as np
from scipy.linalg.blas import ddot as _ddot

from hqp_tpm.errors import NonFiniteError, ParameterError, ShapeError, shown
from hqp_tpm.references.trajectories import Constant, Trajectory, as_trajectory
from hqp_tpm.robot.state import State
from hqp_tpm.solvers.levels import Level


@dataclass(frozen=True)
class Gains:
    """Feedback gains: ``kp`` (position) and ``kd`` (velocity, acceleration level only)."""

    kp: float = 1.0
    kd: float = 0.0

    def __post_init__(self):
        for k in ("kp", "kd"):
            v = getattr(self, k)
            if not np.isfinite(v) or v < 0:
                raise ParameterError(f"gain {k} = {v!r} must be finite and >= 0")


class Task(ABC):
    """A task knows its value, Jacobian and J-dot q-dot on a :class:`State`, and its target."""

    name: str = "task"
    dim: int = 0
    #: the robot frame the task acts on (frame tasks set it; None: not a frame task)
    frame: str | None = None

    def __init__(self, name: str, target, gains: Gains | None = None):
        self.name = name
        self.gains = gains or Gains()
        self.trajectory: Trajectory = self._trajectory_of(target)

    def _trajectory_of(self, target) -> Trajectory:
        """``target`` (a constant, None/``"hold"``, a trajectory) as this task's trajectory, the errors naming it."""
        try:
            return as_trajectory(target, self.dim)
        except (ShapeError, NonFiniteError) as exc:  # name the task whose target is wrong
            raise type(exc)(f"task {self.name!r}: {exc}") from None

    # robot-side quantities --------------------------------------------------------------
    @abstractmethod
    def value(self, state: State) -> np.ndarray: ...

    @abstractmethod
    def jacobian(self, state: State) -> np.ndarray: ...

    @abstractmethod
    def jdot_qdot(self, state: State) -> np.ndarray: ...

    def error(self, state: State, x_d: np.ndarray) -> np.ndarray:
        """``e = x_d - x`` (tasks on manifolds override it)."""
        return x_d - self.value(state)

    def tracking_error(self, state: State, t: float) -> np.ndarray:
        """``e = x_d(t) - x`` at ``state``: the error against the task's own reference at time ``t``."""
        return self.error(state, self.reference(t)[0])

    def rate(self, state: State) -> np.ndarray:
        """Task velocity ``J qd``."""
        return self.jacobian(state).dot(state.v)

    # lifecycle --------------------------------------------------------------------------
    def start(self, state: State) -> None:
        """Called once at the start of a run: relative targets take the current value."""
        self.trajectory.start(self.value(state))

    def reference(self, t: float):
        return self.trajectory.reference(t)

    # command ----------------------------------------------------------------------------
    def command(self, state: State, t: float, order: int, extra: np.ndarray | None = None,
                J: np.ndarray | None = None) -> np.ndarray:
        """Right-hand side ``b`` of the task at velocity (1) or acceleration (2) level (``J``: if known)."""
        x_d, xd_d, xdd_d = self.reference(t)
        e = self.error(state, x_d)
        if extra is not None:
            extra = np.asarray(extra, dtype=float)
            if extra.shape != (self.dim,):
                raise ShapeError(f"task {self.name!r}: extra command has shape {extra.shape}, expected ({self.dim},)")
            if not np.isfinite(extra).all():
                raise NonFiniteError(f"task {self.name!r}: extra command holds non-finite values: {extra}")
        if order == 1:
            b = xd_d + self.gains.kp * e
            return b if extra is None else b + extra
        if order != 2:
            raise ParameterError(f"order must be 1 (velocity) or 2 (acceleration), got {order!r}")
        xdd = xdd_d if extra is None else xdd_d + extra
        rate = (self.jacobian(state) if J is None else J).dot(state.v)
        return xdd + self.gains.kd * (xd_d - rate) + self.gains.kp * e - self.jdot_qdot(state)

    #: Whether :meth:`row_writer`'s ``write`` also takes an extra command, ``write(t, extra)`` (added to the command
    #: as :meth:`command` adds it; Algorithm 1's planned step passes its EE repulsion so).
    row_writer_takes_extra: bool = False

    def row_writer(self, state: State, order: int, J: np.ndarray, b: np.ndarray) -> Callable[[float], None]:
        """``write(t)`` for the lean step (:mod:`hqp_tpm.control._lean`): this task's rows at ``state``'s current
        kinematics written in place into ``J`` (``dim x n``) and ``b`` (``dim``), views of the stacked arrays.

        The numbers of :meth:`jacobian` and :meth:`command` (without an extra command); built once, called every step
        after the state update. This default calls them; the frame, CoM, posture and joint velocity tasks write with
        fewer calls (``tests/test_lean.py`` compares every writer with them)."""
        def write(t: float) -> None:
            Jt = self.jacobian(state)
            J[...] = Jt
            b[...] = self.command(state, t, order, None, Jt)
        return write

    def row_program(self, state: State, order: int, program, row: int) -> Callable[[float], None] | None:
        """For the lean step's fused kernel (:mod:`hqp_tpm.control._compiled_step`): register this task's rows (starting
        at stacked row ``row``) with ``program`` and return ``gather(t)``, which writes the step's pinocchio outputs
        into the program's slot arrays (``program.mats``, ``program.vecs``; a replaced array is bound with
        ``program.bind_mat``/``bind_vec``) and changed references into ``program.floats``; the kernel then writes the
        numbers of :meth:`jacobian` and :meth:`command`. None (this default): the task's row writer runs instead."""
        return None

    def level(self, state: State, t: float, order: int, extra: np.ndarray | None = None) -> Level:
        """The task as a solver level (equality ``J x = b``)."""
        J = self.jacobian(state)
        return Level(J, self.command(state, t, order, extra, J), name=self.name, defer_finite=True)

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.name!r}, dim={self.dim})"


_FLOAT64 = np.dtype(np.float64)


def _set_target(self, value) -> None:
    tr = self.trajectory
    if type(value) is np.ndarray and type(tr) is Constant and tr.origin is None and value.shape == (self.dim,) \
            and value.dtype is _FLOAT64 and math.isfinite(_ddot(value, value)):  # the common case, cheap
        tr.assign(value.copy())
        return
    if value is None or (isinstance(value, str) and value == "hold"):
        raise ParameterError(f"task {self.name!r}: target {shown(value)} (the start value) is a constructor's "
                             f"target only; assign {self.dim} values or a Trajectory")
    new = self._trajectory_of(value)
    if type(tr) is Constant and type(new) is Constant and not isinstance(value, Trajectory):
        tr.value = new.value  # (a relative constant keeps its origin)
    else:
        self.trajectory = new


#: ``target`` of the tasks whose trajectory is their target (:class:`~hqp_tpm.tasks.posture.Posture`,
#: :class:`~hqp_tpm.tasks.frame_position.FramePosition`, :class:`~hqp_tpm.tasks.com.CenterOfMass`)
trajectory_target = property(lambda self: self.trajectory, _set_target, doc="""The reference the task tracks (its
    :attr:`trajectory`). Assigning a constant (``dim`` values) or a :class:`Trajectory` replaces it, validated as the
    constructor's target (:class:`ShapeError`, :class:`NonFiniteError` naming the task; a relative constant stays
    relative); a constant array given to a constant trajectory is stored in it with one copy (:meth:`Constant.assign`).
    """)


#: The methods a row writer or row program repeats (:func:`own_rows`).
_REPEATED = ("value", "jacobian", "jdot_qdot", "error", "reference", "command", "level")


@cache
def own_rows(kind: type[Task]) -> bool:
    """Whether the row writer and row program of task class ``kind`` repeat its own methods: no class below the one that
    defines them overrides one of the methods they repeat (a subclass that changes ``jacobian`` only, say, is written by
    the default :meth:`Task.row_writer`, which calls it)."""
    def owner(name: str) -> type:
        return next(k for k in kind.__mro__ if name in vars(k))

    writers = [k for k in (owner("row_writer"), owner("row_program")) if k is not Task]  # (Task's: the methods)
    return all(issubclass(w, owner(name)) for name in _REPEATED for w in writers)


def row_writer(task: Task, state: State, order: int, J: np.ndarray, b: np.ndarray) -> Callable[[float], None]:
    """``task``'s row writer (:meth:`Task.row_writer`) where it repeats the task's own methods (:func:`own_rows`), else
    the default one, which calls them."""
    kind = task.row_writer if own_rows(type(task)) else partial(Task.row_writer, task)
    return kind(state, order, J, b)


def kernel_placement(state: State, fid: int, inside: bool):
    """``add_frame``'s ``placement`` (:meth:`hqp_tpm.control._compiled_step.Program.add_frame`) of a frame task's row
    program: frame ``fid`` placed by the fused kernel when it also computes the frame's Jacobian (``inside``) and the
    state gives views (:meth:`~hqp_tpm.robot.state.State.frame_placement_source`); else None. (At order 2 the row
    programs read ``Jdot qd`` with ``getFrameClassicalAcceleration``, which reads the joint's placement, not the
    frame's.)"""
    if not inside:
        return None
    source = state.frame_placement_source(fid)
    return None if source is None else (fid, *source)


class ReferenceSlots:
    """Copies a task's reference ``(x_d, xd_d, xdd_d)`` (the parts named by ``parts``) and gains into a fused program's
    floats (:meth:`Task.row_program`) when they are not the ones copied last (compared by identity, part by part): a
    constant reference is one read-only tuple between starts and assignments (copied once; an assigned constant changes
    ``x_d`` only, :meth:`Constant.assign`); any other is copied every step."""

    __slots__ = ("program", "parts", "last", "gains", "gains_at", "task", "views")

    def __init__(self, task: Task, program, gains_at: int, at: int, parts: tuple[tuple[int, int], ...]):
        """``kp, kd`` at ``program.floats[gains_at:]``, the reference parts ``(index, entries)`` from ``at`` on."""
        self.task, self.program, self.gains_at, self.parts = task, program, gains_at, []
        for i, size in parts:  # (index into the reference, its slice of the floats), laid out one after the other
            self.parts.append((i, slice(at, at + size)))
            at += size
        self.last, self.gains, self.views = (None, None, None), task.gains, None

    def refresh(self, t: float) -> None:
        task = self.task
        ref = task.trajectory.reference(t)
        last = self.last
        if ref is not last:
            if self.views is None:  # (the program's floats exist once its row programs are built)
                self.views = [self.program.floats[s] for _, s in self.parts]
            for (i, _), view in zip(self.parts, self.views, strict=True):
                if ref[i] is not last[i]:
                    view[...] = ref[i]
            frozen = not (ref[0].flags.writeable or ref[1].flags.writeable or ref[2].flags.writeable)
            self.last = ref if frozen else (None, None, None)
        if task.gains is not self.gains:
            self.gains = g = task.gains
            self.program.floats[self.gains_at: self.gains_at + 2] = g.kp, g.kd


def select_axes(axes: str) -> np.ndarray:
    """Row indices of ``axes`` (a subset of ``"xyz"``), validated."""
    if not axes or any(a not in "xyz" for a in axes) or len(set(axes)) != len(axes):
        raise ParameterError(f"axes {axes!r} must be distinct letters among 'x', 'y', 'z'")
    return np.array(["xyz".index(a) for a in axes])


def row_selector(rows: np.ndarray) -> slice | np.ndarray:
    """``rows`` as a slice if they are contiguous and increasing (indexing then gives a view), else ``rows``."""
    if rows.size and np.array_equal(rows, np.arange(rows[0], rows[0] + rows.size)):
        return slice(int(rows[0]), int(rows[0]) + rows.size)
    return rows

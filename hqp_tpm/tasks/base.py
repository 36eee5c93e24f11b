"""The task interface and the tracking command it turns into a solver level.

Velocity level (order 1):      ``b = xd_d + kp e``                      (CLIK, eq. (7) of papers/000)
Acceleration level (order 2):  ``b = xdd_d + kd (xd_d - J qd) + kp e - Jdot qd``  (eq. (12))
with ``e = x_d - x``. An ``extra`` vector (e.g. the EE repulsion of eq. (30)) is added to the desired
velocity/acceleration before the feedback terms."""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from hqp_tpm.errors import ArgumentTypeError, NonFiniteError, ParameterError, ShapeError, shown
from hqp_tpm.references.trajectories import Constant, Trajectory, as_trajectory
from hqp_tpm.robot.state import State
from hqp_tpm.solvers.levels import Level


def tracking_command(order: int, e, xd, xdd, rate, jdq, kp: float, kd: float):
    """The module's ``b`` (``rate = J qd``, ``jdq = Jdot qd``): this law's one home, on arrays and kernel scalars."""
    if order == 1:
        return xd + kp * e
    return xdd + kd * (xd - rate) + kp * e - jdq


class FrameRows(NamedTuple):
    """A frame task's rows ``rows`` (0-2 linear, 3-5 angular) of its world-aligned Jacobian: error ``x_d -
    p[position]`` (``x_d``: the reference or ``p_d``), then ``log3(R_d R^T)`` (``p_d``, ``R_d`` updated in place)."""

    fid: int
    rows: tuple[int, ...]
    position: tuple[int, ...]
    p_d: np.ndarray | None = None
    R_d: np.ndarray | None = None


class SelectionRows(NamedTuple):
    """Rows of a constant selection Jacobian: ``x = q[qidx]``, ``J qd = v[vidx]``, ``Jdot qd = 0``."""

    qidx: tuple[int, ...]
    vidx: tuple[int, ...]


class CenterOfMassRows(NamedTuple):
    """Rows ``rows`` of the centre of mass and its Jacobian."""

    rows: tuple[int, ...]


@dataclass(frozen=True)
class Gains:
    """Feedback gains: ``kp`` (position) and ``kd`` (velocity, acceleration level only)."""

    kp: float = 1.0
    kd: float = 0.0

    def __post_init__(self):
        for k, v in (("kp", self.kp), ("kd", self.kd)):
            if not np.isfinite(v) or v < 0:
                raise ParameterError(f"gain {k} = {v!r} must be finite and >= 0")


class _GainsField:
    """``task.gains``: a :class:`Gains` (None: the defaults), else refused; read as a plain attribute (no getter)."""

    def __set__(self, task, gains) -> None:
        if gains is not None and not isinstance(gains, Gains):
            raise ArgumentTypeError(f"task {task.name!r}: gains {shown(gains)} is not a Gains; use Gains(kp, kd)")
        task.__dict__["gains"] = gains or Gains()


class Task(ABC):
    """A task knows its value, Jacobian and J-dot q-dot on a :class:`State`, and its target."""

    name: str = "task"
    dim: int = 0
    #: the robot frame the task acts on (frame tasks set it; None: not a frame task)
    frame: str | None = None
    gains = _GainsField()  # the feedback Gains (None: the defaults; anything else is refused)

    def __init__(self, name: str, target, gains: Gains | None = None):
        self.name = name
        self.gains = gains
        self.trajectory: Trajectory = self._trajectory_of(target)

    def _trajectory_of(self, target) -> Trajectory:
        """``target`` (a constant, None/``"hold"``, a trajectory) as this task's trajectory, the errors naming it."""
        try:
            return as_trajectory(target, self.dim, self.name)
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
        g = self.gains
        if order == 1:
            b = tracking_command(1, e, xd_d, 0.0, 0.0, 0.0, g.kp, g.kd)
            return b if extra is None else b + extra
        if order != 2:
            raise ParameterError(f"order must be 1 (velocity) or 2 (acceleration), got {order!r}")
        xdd = xdd_d if extra is None else xdd_d + extra
        rate = (self.jacobian(state) if J is None else J).dot(state.v)
        return tracking_command(2, e, xd_d, xdd, rate, self.jdot_qdot(state), g.kp, g.kd)

    def row_source(self) -> FrameRows | SelectionRows | CenterOfMassRows | None:
        """What the compiled step writes this task's rows from (None: it calls :meth:`jacobian`, :meth:`command`)."""
        return None

    def level(self, state: State, t: float, order: int, extra: np.ndarray | None = None) -> Level:
        """The task as a solver level (equality ``J x = b``)."""
        J = self.jacobian(state)
        return Level(J, self.command(state, t, order, extra, J), name=self.name, defer_finite=True)

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.name!r}, dim={self.dim})"


class FrameTask(Task):
    """A task on the rows ``_sel`` of frame ``fid``'s world-aligned Jacobian and ``J̇ q̇`` (linear rows first)."""

    fid: int
    _sel: slice | np.ndarray = slice(None)

    def jacobian(self, state: State) -> np.ndarray:
        return state.jacobian(self.fid)[self._sel]

    def jdot_qdot(self, state: State) -> np.ndarray:
        return state.jdot_qdot(self.fid)[self._sel]


class AssignedTask(Task):
    """A task whose rows are assigned every step, without a target: nothing to start, a zero error."""

    def start(self, state: State) -> None:
        return None

    def error(self, state: State, x_d) -> np.ndarray:
        return np.zeros(self.dim)


def _set_target(self, value) -> None:
    tr = self.trajectory
    if type(tr) is Constant and tr.assign(value):  # the common case: checked and copied in one call
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
trajectory_target = property(lambda self: self.trajectory, _set_target, doc="""The reference the task tracks. Assign
    ``dim`` values or a :class:`Trajectory`: validated as the constructor's target (a refused one changes nothing).""")


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

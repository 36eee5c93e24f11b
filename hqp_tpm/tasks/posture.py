"""Joint posture: selected 1-DOF joints towards target angles (``J`` a selection matrix; a continuous joint by its
angle, the error wrapped into ``(-pi, pi]``: :class:`~hqp_tpm.tasks.manipulability.JointAngles`)."""

from __future__ import annotations

import numpy as np

from hqp_tpm.errors import ShapeError
from hqp_tpm.references.trajectories import Trajectory
from hqp_tpm.robot.model import Robot
from hqp_tpm.robot.state import State
from hqp_tpm.tasks.base import Gains, SelectionRows, Task, trajectory_target
from hqp_tpm.tasks.manipulability import joint_columns


class Posture(Task):
    """``x = q[joints]``; ``joints=None`` means every 1-DOF joint. Target ``None`` holds the start posture.

    The target is either the joints' angles (``dim`` values) or a whole configuration (``robot.nq`` values, e.g.
    ``robot.reference("half_sitting")`` of a floating-base robot): the joints' angles are read from it."""

    target = trajectory_target

    def __init__(self, robot: Robot, target=None, gains: Gains | None = None, *, joints=None, name: str = "posture"):
        self.joints, self.cols, self.angles = joint_columns(robot, joints)
        self.dim = len(self.cols)
        self._J = np.zeros((self.dim, robot.nv))
        self._J[np.arange(self.dim), self.cols] = 1.0
        self._nq = robot.nq
        super().__init__(name, target, gains)

    def _trajectory_of(self, target):
        return super()._trajectory_of(self.joint_target(target))

    def joint_target(self, target):
        """``target`` as this task's joint angles: a full configuration (``robot.nq``) gives its ``q[joints]``, another
        array must hold one angle per joint (else :class:`ShapeError`); trajectories, None and "hold" pass through."""
        if target is None or isinstance(target, (str, Trajectory)):
            return target
        try:
            value = np.asarray(target, dtype=float)
        except (TypeError, ValueError):
            return target  # (not numbers: the base class's error names it)
        if value.shape == (self.dim,):
            return value
        if value.shape == (self._nq,):
            return self.angles.of(value)
        idx = self.angles.idx
        where = (f"q[{idx[0]}:{idx[-1] + 1}]" if self.dim and np.all(np.diff(idx) == 1) else f"q[{idx.tolist()}]")
        raise ShapeError(f"task {self.name!r}: target has shape {value.shape}; expected ({self.dim},), "
                         f"one angle per joint ({where} of a full configuration), or a full configuration "
                         f"({self._nq},)")

    def value(self, state: State) -> np.ndarray:
        return self.angles.of(state.q)

    def error(self, state: State, x_d: np.ndarray) -> np.ndarray:
        return self.angles.difference(x_d, self.value(state))

    def jacobian(self, state: State) -> np.ndarray:
        return self._J

    def jdot_qdot(self, state: State) -> np.ndarray:
        return np.zeros(self.dim)

    def row_source(self) -> SelectionRows | None:
        """Revolute and prismatic joints only (a continuous joint's error is a wrapped difference)."""
        if not self.angles._plain:
            return None
        return SelectionRows(tuple(int(i) for i in self.angles.idx), tuple(int(c) for c in self.cols))

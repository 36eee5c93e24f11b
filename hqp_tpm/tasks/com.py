"""Centre of mass position (possibly only some axes, e.g. ``"xy"``)."""

from __future__ import annotations

import numpy as np

from hqp_tpm.robot.model import Robot
from hqp_tpm.robot.state import State
from hqp_tpm.tasks.base import CenterOfMassRows, Gains, Task, row_selector, select_axes, trajectory_target


class CenterOfMass(Task):
    """``x = com[axes]``, ``J = J_com[axes]``, ``Jdot qd`` = CoM acceleration at zero q-ddot.

    ``CenterOfMass(robot, target, gains, axes="xy")``; ``CenterOfMass(target, gains)`` (no robot) is accepted too."""

    target = trajectory_target

    def __init__(self, robot: Robot | None = None, target=None, gains: Gains | None = None, *, axes: str = "xyz",
                 name: str = "com"):
        if robot is not None and not isinstance(robot, Robot):  # CenterOfMass(target[, gains]): the older form
            robot, target, gains = None, robot, target if gains is None else gains
        elif robot is None and isinstance(target, Gains) and gains is None:  # CenterOfMass(None, gains)
            target, gains = None, target
        self.rows = select_axes(axes)
        self._sel = row_selector(self.rows)  # a view of the cached CoM Jacobian for "xy", "xyz"
        self.dim = len(self.rows)
        super().__init__(name, target, gains)

    def value(self, state: State) -> np.ndarray:
        return state.com()[self.rows]

    def jacobian(self, state: State) -> np.ndarray:
        return state.com_jacobian()[self._sel]

    def jdot_qdot(self, state: State) -> np.ndarray:
        return state.com_jdot_qdot()[self._sel]

    def row_source(self) -> CenterOfMassRows:
        return CenterOfMassRows(tuple(int(r) for r in self.rows))

"""Centre of mass position (possibly only some axes, e.g. ``"xy"``)."""

from __future__ import annotations

import numpy as np

from hqp_tpm.robot.state import State
from hqp_tpm.tasks.base import Gains, Task, row_selector, select_axes


class CenterOfMass(Task):
    """``x = com[axes]``, ``J = J_com[axes]``, ``Jdot qd`` = CoM acceleration at zero q-ddot."""

    def __init__(self, target=None, gains: Gains | None = None, *, axes: str = "xyz", name: str = "com"):
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

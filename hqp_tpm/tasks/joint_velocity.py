"""A joint-space velocity as a task: ``J = I``, command ``qd_0`` (velocity level only); below other levels the
projected term ``N_T qd_0`` of papers/004's solution (5) (docs/internals.md#tasks)."""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from hqp_tpm.errors import NonFiniteError, ParameterError, ShapeError
from hqp_tpm.robot.state import State
from hqp_tpm.tasks.base import AssignedTask


class JointVelocity(AssignedTask):
    """``J = I_n``; velocity command ``qd_0`` (set by :meth:`assign`)."""

    def __init__(self, n: int, name: str = "joint_velocity"):
        self.dim = int(n)
        super().__init__(name, np.zeros(self.dim))
        self._I = np.eye(self.dim)
        self.qd0 = np.zeros(self.dim)

    def assign(self, qd0) -> None:
        qd0 = np.asarray(qd0, dtype=float)
        if qd0.shape != (self.dim,):
            raise ShapeError(f"task {self.name!r}: qd_0 has shape {qd0.shape}, expected ({self.dim},)")
        if not np.isfinite(qd0).all():
            raise NonFiniteError(f"task {self.name!r}: qd_0 holds non-finite values: {qd0}")
        self.qd0 = qd0

    def value(self, state: State) -> np.ndarray:
        """The configuration as a velocity-space vector: ``pinocchio.difference(neutral, q)`` (``q`` itself
        for a robot of revolute and prismatic joints; right for continuous and free-flyer joints too)."""
        model = state.model
        if model.nq == model.nv:
            return state.q[: self.dim].copy()
        return pin.difference(model, pin.neutral(model), state.q)

    def jacobian(self, state: State) -> np.ndarray:
        return self._I

    def jdot_qdot(self, state: State) -> np.ndarray:
        return np.zeros(self.dim)

    def command(self, state: State, t: float, order: int, extra=None, J=None) -> np.ndarray:
        if order != 1:
            raise ParameterError(f"task {self.name!r}: a joint velocity is a velocity-level task (order 1), "
                                 f"got {order!r}")
        return self.qd0

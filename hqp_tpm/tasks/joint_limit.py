"""Joint-limit task of papers/003, eqs. (11)-(12): distance from the middle of the joint ranges."""

from __future__ import annotations

import numpy as np

from hqp_tpm.errors import BoxError
from hqp_tpm.robot.model import Robot
from hqp_tpm.robot.state import State
from hqp_tpm.tasks.base import Gains, Task
from hqp_tpm.tasks.manipulability import joint_columns


class JointLimit(Task):
    """``sigma_l = 1/(2n) sum ((q_i - q_i^*)/(q_Hi - q_Li))^2`` (11), ``q^* = (q_L + q_H)/2``, target 0, ``J_l`` (12)
    its gradient. ``joints``: default every 1-DOF joint (each needs finite limits, else :class:`BoxError`)."""

    dim = 1

    def __init__(self, robot: Robot, target=(0.0,), gains: Gains | None = None, *, joints=None,
                 name: str = "joint_limit"):
        self.joints, self.cols, self.angles = joint_columns(robot, joints)
        lo, up = robot.position_limits()
        self.q_low, self.q_high = lo[self.cols], up[self.cols]
        bad = [j for j, a, b in zip(self.joints, self.q_low, self.q_high, strict=True)
               if not (np.isfinite(a) and np.isfinite(b) and a < b)]
        if bad:
            raise BoxError(f"joint-limit task: joints without a finite range lower < upper: {bad}")
        self.q_mid = self.q_low + 0.5 * (self.q_high - self.q_low)  # q^* of (11)
        self.w = 1.0 / (self.q_high - self.q_low) ** 2
        self.n = self.cols.size
        self.nv = robot.nv
        super().__init__(name, target, gains)

    def deviation(self, state: State) -> np.ndarray:
        """``|q_i - q_i^*|`` per joint (rad; the switching policy compares it with ``sigma_bar_l``)."""
        return np.abs(self.angles.of(state.q) - self.q_mid)

    def margin(self, state: State) -> np.ndarray:
        """Distance of each joint to its nearer limit (rad; negative beyond it)."""
        q = self.angles.of(state.q)
        return np.minimum(q - self.q_low, self.q_high - q)

    def value(self, state: State) -> np.ndarray:
        d = self.angles.of(state.q) - self.q_mid
        return np.array([float(d * d @ self.w) / (2 * self.n)])  # eq. (11)

    def jacobian(self, state: State) -> np.ndarray:
        J = np.zeros((1, self.nv))
        J[0, self.cols] = (self.angles.of(state.q) - self.q_mid) * self.w / self.n  # eq. (12)
        return J

    def jdot_qdot(self, state: State) -> np.ndarray:
        qd = state.v[self.cols]
        return np.array([float(qd * qd @ self.w) / self.n])

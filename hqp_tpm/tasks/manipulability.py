"""Manipulability index of papers/003, eq. (14): ``sigma_m = 1/2 sum_{i=2}^{n-1} sin^2 q_i``."""

from __future__ import annotations

import numpy as np

from hqp_tpm.errors import ParameterError
from hqp_tpm.robot.model import Robot
from hqp_tpm.robot.state import State
from hqp_tpm.tasks.base import Gains, Task


def joint_columns(robot: Robot, joints=None) -> tuple[list[str], np.ndarray, JointAngles]:
    """Names, velocity columns and the :class:`JointAngles` of ``joints`` (default: every 1-DOF joint)."""
    names = list(joints) if joints is not None else [
        n for n in robot.joint_names if not robot.has_free_flyer or robot.joint_names.index(n) >= 6]
    cols = np.array([robot.joint_index(j) for j in names], dtype=int)
    return names, cols, JointAngles(robot, names)


class JointAngles:
    """The angles of 1-DOF joints read from a configuration ``q``: a continuous joint (``q`` holds ``cos theta, sin
    theta``) as ``atan2(sin, cos)``, and :meth:`difference` wrapped as ``pinocchio.difference`` for it."""

    __slots__ = ("idx", "continuous", "_cos", "_sin", "_plain")

    def __init__(self, robot: Robot, names):
        model = robot.model
        joints = [model.joints[model.getJointId(j)] for j in names]
        self.idx = np.array([j.idx_q for j in joints], dtype=int)
        self.continuous = np.array([j.nq == 2 and j.nv == 1 for j in joints], dtype=bool)
        self._plain = not self.continuous.any()
        self._cos = self.idx[self.continuous]
        self._sin = self._cos + 1

    def of(self, q: np.ndarray) -> np.ndarray:
        """The joint angles (rad; a prismatic joint's coordinate)."""
        out = q[self.idx]
        if not self._plain:
            out[self.continuous] = np.arctan2(q[self._sin], q[self._cos])
        return out

    def difference(self, target: np.ndarray, angles: np.ndarray) -> np.ndarray:
        """``target - angles``, wrapped into ``(-pi, pi]`` for continuous joints (``pinocchio.difference``)."""
        d = np.asarray(target, dtype=float) - angles
        if not self._plain:
            c = self.continuous
            d[c] = -np.remainder(-d[c] + np.pi, 2.0 * np.pi) + np.pi
        return d


class Manipulability(Task):
    """``sigma_m`` (14) over ``joints`` (default: the 1-DOF joints but the first and the last), ``J_m`` its gradient
    (not the printed (15): docs/internals.md#tasks). ``target``: the paper's ``sigma_m^*`` (default 2.0)."""

    dim = 1

    def __init__(self, robot: Robot, target=2.0, gains: Gains | None = None, *, joints=None,
                 name: str = "manipulability"):
        if joints is None:
            joints = joint_columns(robot)[0][1:-1]
        self.joints, self.cols, self.angles = joint_columns(robot, joints)
        if self.cols.size == 0:
            raise ParameterError("manipulability task: no joints in the sum (the robot needs at least 3 joints)")
        self.nv = robot.nv
        super().__init__(name, [float(target)] if np.isscalar(target) and not isinstance(target, str) else target,
                         gains)

    def value(self, state: State) -> np.ndarray:
        s = np.sin(self.angles.of(state.q))
        return np.array([0.5 * float(s @ s)])  # eq. (14)

    def jacobian(self, state: State) -> np.ndarray:
        q = self.angles.of(state.q)
        J = np.zeros((1, self.nv))
        J[0, self.cols] = np.sin(q) * np.cos(q)  # the gradient of (14), not the printed (15)
        return J

    def jdot_qdot(self, state: State) -> np.ndarray:
        q, qd = self.angles.of(state.q), state.v[self.cols]
        return np.array([float(np.cos(2.0 * q) @ (qd * qd))])

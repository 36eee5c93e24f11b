"""Full pose of a frame (6 rows: position then orientation), e.g. a sole held on the ground."""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from hqp_tpm.references.trajectories import Hold
from hqp_tpm.robot.model import Robot
from hqp_tpm.robot.state import State
from hqp_tpm.tasks.base import Gains, Task


class FramePose(Task):
    """``e = [p_d - p; log3(R_d R^T)]`` (world), ``J`` = 6-row world-aligned frame Jacobian.

    The target is an ``pin.SE3`` or ``None``/``"hold"`` for the start pose.
    """

    dim = 6

    def __init__(self, robot: Robot, frame: str, target=None, gains: Gains | None = None, *, name: str | None = None):
        self.frame = frame
        self.fid = robot.frame_id(frame)
        self._M_target = target if isinstance(target, pin.SE3) else None
        super().__init__(name or f"{frame}_pose", None, gains)
        self.trajectory = Hold()

    def start(self, state: State) -> None:
        if self._M_target is None:
            self._M_target = state.placement(self.fid).copy()
        self.trajectory.start(np.zeros(6))

    def value(self, state: State) -> np.ndarray:
        M = state.placement(self.fid)
        return np.concatenate([M.translation, pin.log3(M.rotation)])

    def error(self, state: State, x_d) -> np.ndarray:
        M = state.placement(self.fid)
        return np.concatenate([self._M_target.translation - M.translation,
                               pin.log3(self._M_target.rotation.dot(M.rotation.T))])

    def jacobian(self, state: State) -> np.ndarray:
        return state.jacobian(self.fid)

    def jdot_qdot(self, state: State) -> np.ndarray:
        return state.jdot_qdot(self.fid)

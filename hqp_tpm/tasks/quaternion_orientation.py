"""Orientation by the quaternion error of papers/003, eq. (10), on selected components (the 2-D task):
``e_o = eta epsilon^* - eta^* epsilon - S(epsilon^*) epsilon``, the vector part of ``Q^* Q^{-1}`` (rotation
``R^* R^T``, world frame, sign chosen so that its scalar part is >= 0)."""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from hqp_tpm.errors import ShapeError
from hqp_tpm.robot.model import Robot
from hqp_tpm.robot.state import State
from hqp_tpm.tasks.base import FrameTask, Gains, select_axes
from hqp_tpm.tasks.frame_pose import rotation_matrix


def quaternion_error(R_d: np.ndarray, R: np.ndarray) -> np.ndarray:
    """Eq. (10): vector part of ``Q_d Q^{-1}`` (scalar part made >= 0)."""
    qd, q = pin.Quaternion(R_d), pin.Quaternion(R)
    eta_d, eps_d, eta, eps = qd.w, qd.vec(), q.w, q.vec()
    e = eta * eps_d - eta_d * eps - np.cross(eps_d, eps)
    return -e if eta_d * eta + eps_d @ eps < 0 else e


class QuaternionOrientation(FrameTask):
    """``sigma_o = Sigma e_o`` (10), itself the error as in the paper, ``J = Sigma J_o`` (world angular rows; not the
    derivative of :meth:`value`: docs/internals.md#tasks). ``target``: a rotation matrix or None (the start
    orientation); ``axes``: the rows (``"xy"``, the paper's 2-D task: the flange z axis keeps its direction)."""

    def __init__(self, robot: Robot, frame: str, target=None, gains: Gains | None = None, *,
                 axes: str = "xy", name: str | None = None):
        self.frame = frame
        self.fid = robot.frame_id(frame)
        self.rows = select_axes(axes)
        self._sel = 3 + self.rows
        self.dim = len(self.rows)
        if target is None or (isinstance(target, str) and target == "hold"):
            self.R_target = None
        else:
            R = np.asarray(target, dtype=float)
            if R.shape not in ((3, 3), (9,)):
                raise ShapeError(f"orientation target must be a 3x3 rotation matrix, got shape {R.shape}")
            self.R_target = rotation_matrix(R.reshape(3, 3), f"task {name or frame + '_orientation'!r}")
        super().__init__(name or f"{frame}_orientation", np.zeros(self.dim), gains)

    def start(self, state: State) -> None:
        if self.R_target is None:
            self.R_target = state.rotation(self.fid).copy()
        self.trajectory.start(np.zeros(self.dim))

    def full_error(self, state: State) -> np.ndarray:
        """All three components of (10)."""
        if self.R_target is None:
            raise ShapeError(f"task {self.name!r}: no target orientation before start()")
        return quaternion_error(self.R_target, state.rotation(self.fid))

    def value(self, state: State) -> np.ndarray:
        return self.full_error(state)[self.rows]

    def error(self, state: State, x_d: np.ndarray) -> np.ndarray:
        """``sigma_o`` (desired 0): the quaternion error, the command is ``Lambda_o sigma_o``."""
        return self.value(state) - x_d

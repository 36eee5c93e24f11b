"""Full orientation of a frame, error ``log3(R_d R^T)`` in the world frame."""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from hqp_tpm.errors import ShapeError, shown
from hqp_tpm.robot.model import Robot
from hqp_tpm.robot.state import State
from hqp_tpm.tasks.base import FrameRows, FrameTask, Gains
from hqp_tpm.tasks.frame_pose import rotation_matrix


class FrameOrientation(FrameTask):
    """``J = J_omega`` (world), ``Jdot qd`` = angular acceleration at zero q-ddot. The target is a rotation matrix
    (constant) or ``None``/``"hold"`` for the start orientation; the error is the world rotation vector to it."""

    dim = 3
    _sel = slice(3, None)

    def __init__(self, robot: Robot, frame: str, target=None, gains: Gains | None = None, *, name: str | None = None):
        self.frame = frame
        self.fid = robot.frame_id(frame)
        self._R_d = np.asfortranarray(np.eye(3))  # the target rotation, written in place (the compiled step reads it)
        self._held = target is None or (isinstance(target, str) and target == "hold")
        name = name or f"{frame}_orientation"
        if not self._held:
            self._R_d[:] = self._rotation(target, name)
        super().__init__(name, None if self._held else np.zeros(3), gains)  # (a Hold, or a Constant of zeros)

    @staticmethod
    def _rotation(value, task: str) -> np.ndarray:
        """``value`` as a rotation matrix, else :class:`ShapeError` or :class:`ParameterError` naming it."""
        what = f"FrameOrientation {task!r}"
        try:
            R = None if value is None or isinstance(value, str) else np.asarray(value, dtype=float)
        except (TypeError, ValueError):
            R = None
        if R is None or R.shape != (3, 3):
            raise ShapeError(f"{what}: target {shown(value if R is None else R.tolist())} is not a 3x3 rotation "
                             "matrix; expected a 3x3 rotation matrix (None / 'hold': the start orientation, a "
                             "constructor's target only)")
        return rotation_matrix(R, what)

    @property
    def target(self) -> np.ndarray | None:
        """The target rotation (a copy; None: the start orientation, until the first step); assigned validated."""
        return None if self._held else np.array(self._R_d)

    @target.setter
    def target(self, value) -> None:
        self._R_d[:] = self._rotation(value, self.name)
        self._held = False

    def start(self, state: State) -> None:
        if self._held:
            self._R_d[:] = state.rotation(self.fid)
            self._held = False
        self.trajectory.start(np.zeros(3))

    def value(self, state: State) -> np.ndarray:
        return pin.log3(state.rotation(self.fid))

    def error(self, state: State, x_d: np.ndarray) -> np.ndarray:
        return pin.log3(self._R_d.dot(state.rotation(self.fid).T))

    def row_source(self) -> FrameRows:
        return FrameRows(self.fid, (3, 4, 5), (), None, self._R_d)

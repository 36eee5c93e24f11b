"""Full orientation of a frame, error ``log3(R_d R^T)`` in the world frame."""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from hqp_tpm.errors import ShapeError, shown
from hqp_tpm.references.trajectories import Constant, Hold
from hqp_tpm.robot.model import Robot
from hqp_tpm.robot.state import LWA, State
from hqp_tpm.tasks.base import Gains, ReferenceSlots, Task, kernel_placement
from hqp_tpm.tasks.frame_pose import rotation_matrix


class FrameOrientation(Task):
    """``J = J_omega`` (world), ``Jdot qd`` = angular acceleration at zero q-ddot.

    The target is a rotation matrix (constant) or ``None``/``"hold"`` for the start orientation. The 'value' is the
    rotation flattened; the error is the world rotation vector to the target."""

    dim = 3

    def __init__(self, robot: Robot, frame: str, target=None, gains: Gains | None = None, *, name: str | None = None):
        self.frame = frame
        self.fid = robot.frame_id(frame)
        self._R_target = None if target is None or isinstance(target, str) else np.asarray(target, float)
        if (self._R_target is not None and self._R_target.shape != (3, 3)) or (isinstance(target, str)
                                                                               and target != "hold"):
            task = name or f"{frame}_orientation"
            raise ShapeError(f"FrameOrientation {task!r}: target {shown(np.asarray(target).tolist())} has shape "
                             f"{np.shape(target)}, expected a 3x3 rotation matrix (or None / 'hold': the start "
                             "orientation)")
        if self._R_target is not None:
            self._R_target = rotation_matrix(self._R_target, f"FrameOrientation {name or f'{frame}_orientation'!r}")
        super().__init__(name or f"{frame}_orientation", np.zeros(3), gains)
        self.trajectory = Hold() if self._R_target is None else Constant(value=np.zeros(3))

    @property
    def target(self) -> np.ndarray | None:
        """The target rotation (a copy; None: the start orientation, until the first step). Assigning a 3x3 rotation
        matrix sets it, validated (:class:`ShapeError`, :class:`ParameterError` naming the value)."""
        return None if self._R_target is None else self._R_target.copy()

    @target.setter
    def target(self, value) -> None:
        what = f"FrameOrientation {self.name!r}"
        try:
            R = None if value is None or isinstance(value, str) else np.asarray(value, dtype=float)
        except (TypeError, ValueError):
            R = None
        if R is None or R.shape != (3, 3):
            raise ShapeError(f"{what}: target {shown(value)} is not a 3x3 rotation matrix (None / 'hold': the start "
                             "orientation, a constructor's target only)")
        self._R_target = rotation_matrix(R, what)

    def start(self, state: State) -> None:
        if self._R_target is None:
            self._R_target = state.rotation(self.fid).copy()
        self.trajectory.start(np.zeros(3))

    def value(self, state: State) -> np.ndarray:
        return pin.log3(state.rotation(self.fid))

    def error(self, state: State, x_d: np.ndarray) -> np.ndarray:
        return pin.log3(self._R_target.dot(state.rotation(self.fid).T))

    def jacobian(self, state: State) -> np.ndarray:
        return state.jacobian(self.fid)[3:]

    def jdot_qdot(self, state: State) -> np.ndarray:
        return state.jdot_qdot(self.fid)[3:]

    def row_program(self, state: State, order: int, program, row: int):
        """:meth:`Task.row_program`: the frame Jacobian and ``w = log3(R_d R^T)`` (at order 2 also the angular ``J qd``
        and ``Jdot qd``) into the kernel's slots; the reference into its floats."""
        views = state.frame_views(self.fid)
        if views is None:
            return None
        model, data, fid = state.model, state.data, self.fid
        p, R = views
        g = self.gains
        source = state.frame_jacobian_source(fid)
        inside = source is not None  # the frame Jacobian, w = log3(R_d R^T) (and J qd) computed in the kernel
        at, mat, vec, rot = program.add_frame(row, range(3, 6), (), g.kp, g.kd, x_d_vec=False,
                                              jacobian=(*source, p) if inside else None,
                                              rotation=(R.T, np.eye(3)) if inside else None,  # (the target's: below)
                                              placement=kernel_placement(state, fid, inside))
        refresh = ReferenceSlots(self, program, at - 2, at, ((1, 3), (2, 3))).refresh
        target = [None]  # the target rotation whose transpose the kernel reads
        S, w = program.mats[mat], program.vecs[vec]  # the program's arrays (written here if not inside)
        rate, jdq = (program.vecs[vec + 1][:3], program.vecs[vec + 2][:3]) if order == 2 else (None, None)

        def gather(t: float) -> None:
            refresh(t)
            if inside:
                Rd = self._R_target
                if Rd is not target[0]:
                    target[0] = Rd
                    program.bind_mat(rot + 1, np.ascontiguousarray(Rd.T))  # (a view if Rd is column-major)
            else:
                S[...] = pin.getFrameJacobian(model, data, fid, LWA)
                w[:3] = pin.log3(self._R_target.dot(R.T))
                if order == 2:
                    np.dot(S[3:], state.v, out=rate)
            if order == 2:
                jdq[...] = pin.getFrameClassicalAcceleration(model, data, fid, LWA).vector[3:]
        return gather

"""Full pose of a frame (6 rows: position then orientation), e.g. a sole held on the ground."""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from hqp_tpm.references.trajectories import Hold
from hqp_tpm.robot.model import Robot
from hqp_tpm.robot.state import LWA, State
from hqp_tpm.tasks.base import Gains, ReferenceSlots, Task, kernel_placement


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

    def row_program(self, state: State, order: int, program, row: int):
        """:meth:`Task.row_program`: ``p`` and the target translation (at order 2 also ``Jdot qd``) into the kernel's
        slots; the kernel computes the frame Jacobian from the joint Jacobians and ``w = log3(R_d R^T)`` where the
        state gives views of them (:meth:`State.frame_jacobian_source`), else they are gathered here."""
        views = state.frame_views(self.fid)
        if views is None:
            return None
        model, data, fid = state.model, state.data, self.fid
        p, R = views
        g = self.gains
        RT = R.T  # a view, as R
        source = state.frame_jacobian_source(fid)
        inside = source is not None  # the frame Jacobian and the rotation error computed in the kernel
        at, mat, vec, rot = program.add_frame(row, range(6), range(3), g.kp, g.kd, x_d_vec=True, x=p,
                                              jacobian=(*source, p) if inside else None,
                                              rotation=(RT, np.eye(3)) if inside else None,  # (the target's: below)
                                              placement=kernel_placement(state, fid, order, inside))
        refresh = ReferenceSlots(self, program, at - 2, at + 3, ((1, 6), (2, 6))).refresh
        target = [None, None, None]  # the target placement and views of its translation and rotation
        xd_slot = vec + (4 if order == 2 else 2)
        S, w = program.mats[mat], program.vecs[vec + 1]  # the program's arrays (written here if not inside)
        rate, jdq = (program.vecs[vec + 2], program.vecs[vec + 3]) if order == 2 else (None, None)

        def gather(t: float) -> None:
            refresh(t)
            M = self._M_target
            if M is not target[0]:
                target[:] = M, M.translation, M.rotation
                program.bind_vec(xd_slot, target[1])
                if inside:
                    program.bind_mat(rot + 1, target[2].T)
            if not inside:
                S[...] = pin.getFrameJacobian(model, data, fid, LWA)
                w[:3] = pin.log3(target[2].dot(RT))
                if order == 2:
                    np.dot(S, state.v, out=rate)
            if order == 2:
                jdq[...] = pin.getFrameClassicalAcceleration(model, data, fid, LWA).vector
        return gather

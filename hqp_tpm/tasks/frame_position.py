"""Position of a frame origin (possibly only some axes), world frame."""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from hqp_tpm.robot import _compiled
from hqp_tpm.robot.model import Robot
from hqp_tpm.robot.state import LWA, State
from hqp_tpm.tasks.base import Gains, ReferenceSlots, Task, feedback, row_selector, select_axes


class FramePosition(Task):
    """``x = p_frame[axes]``, ``J = J_v[axes]``, ``Jdot qd`` = classical linear acceleration at zero q-ddot."""

    def __init__(self, robot: Robot, frame: str, target=None, gains: Gains | None = None, *,
                 axes: str = "xyz", name: str | None = None):
        self.frame = frame
        self.fid = robot.frame_id(frame)
        self.rows = select_axes(axes)
        self._sel = row_selector(self.rows)  # a view of the cached frame Jacobian for "xyz"
        self.dim = len(self.rows)
        super().__init__(name or f"{frame}_position", target, gains)

    def value(self, state: State) -> np.ndarray:
        return state.position(self.fid)[self.rows]

    def jacobian(self, state: State) -> np.ndarray:
        return state.jacobian(self.fid)[self._sel]

    def jdot_qdot(self, state: State) -> np.ndarray:
        return state.jdot_qdot(self.fid)[self._sel]

    def row_writer(self, state: State, order: int, J: np.ndarray, b: np.ndarray):
        """:meth:`Task.row_writer`: the selected linear rows of the frame Jacobian and ``b``, the same numbers."""
        model, data, fid, sel = state.model, state.data, self.fid, self._sel
        views = state.frame_views(fid)
        if views is None:
            return super().row_writer(state, order, J, b)
        p = views[0]
        p_sel = p[sel] if isinstance(sel, slice) else None  # a view pinocchio updates (else indexed per step)
        e = np.zeros(self.dim)
        rate = np.zeros(self.dim)

        rows, none = self.rows, np.zeros(0)

        def write(t: float) -> None:
            ref = self.trajectory.reference(t)
            if _compiled.ENABLED:  # one compiled call, the same operations
                g, Jt = self.gains, pin.getFrameJacobian(model, data, fid, LWA)
                if order == 1:
                    _compiled.rows1(J, Jt, rows, b, ref[0], p, rows, none, ref[1], g.kp)
                else:
                    np.dot(Jt[sel], state.v, out=rate)
                    jdq = pin.getFrameClassicalAcceleration(model, data, fid, LWA).vector[sel]
                    _compiled.rows2(J, Jt, rows, b, ref[0], p, rows, none, rate, jdq, ref[1], ref[2], g.kp, g.kd)
                return
            Jt = pin.getFrameJacobian(model, data, fid, LWA)[sel]
            J[...] = Jt
            np.subtract(ref[0], p[sel] if p_sel is None else p_sel, out=e)
            if order == 1:
                feedback(b, e, ref, self.gains, 1)
            else:
                np.dot(Jt, state.v, out=rate)
                feedback(b, e, ref, self.gains, 2, rate,
                         pin.getFrameClassicalAcceleration(model, data, fid, LWA).vector[sel])
        return write

    def row_program(self, state: State, order: int, program, row: int):
        """:meth:`Task.row_program`: the frame Jacobian and ``p`` (at order 2 also the selected ``J qd`` and
        ``Jdot qd``) into the kernel's slots; the reference into its floats."""
        views = state.frame_views(self.fid)
        if views is None:
            return None
        model, data, fid, sel, d = state.model, state.data, self.fid, self._sel, self.dim
        p = views[0]
        g = self.gains
        at, mat, vec = program.add_frame(row, self.rows, self.rows, g.kp, g.kd, x_d_vec=False)
        refresh = ReferenceSlots(self, program, at - 2, at, ((0, d), (1, d), (2, d))).refresh
        rate = np.zeros(d)
        mats, vecs = program.mats, program.vecs
        vecs[vec] = p  # pinocchio updates it in place

        def gather(t: float) -> None:
            refresh(t)
            Jt = pin.getFrameJacobian(model, data, fid, LWA)
            mats[mat] = Jt
            if order == 2:
                np.dot(Jt[sel], state.v, out=rate)
                vecs[vec + 1] = rate
                vecs[vec + 2] = np.ascontiguousarray(pin.getFrameClassicalAcceleration(model, data, fid, LWA)
                                                     .vector[sel])
        return gather

"""Position of a frame origin (possibly only some axes), world frame."""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from hqp_tpm.references.trajectories import Harmonic
from hqp_tpm.robot import _compiled
from hqp_tpm.robot.model import Robot
from hqp_tpm.robot.state import LWA, State
from hqp_tpm.tasks import _compiled_rows
from hqp_tpm.tasks.base import (
    Gains,
    ReferenceSlots,
    Task,
    kernel_placement,
    row_selector,
    select_axes,
    trajectory_target,
)


class FramePosition(Task):
    """``x = p_frame[axes]``, ``J = J_v[axes]``, ``Jdot qd`` = classical linear acceleration at zero q-ddot."""

    target = trajectory_target  # (assigned: validated, stored in a constant trajectory with one copy)
    """The reference the task tracks (its trajectory). Assign a position (one value per axis) or a Trajectory between
    steps to move it: validated as the constructor's target (ShapeError, NonFiniteError naming the task and
    the value; a refused target changes nothing), then followed by the next step, compiled or not."""

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

    row_writer_takes_extra = True

    def row_writer(self, state: State, order: int, J: np.ndarray, b: np.ndarray):
        """:meth:`Task.row_writer`: the selected linear rows of the frame Jacobian and ``b``, the same numbers.

        ``write(t, extra=None)`` also takes an extra command (added to the command as :meth:`Task.command` adds it:
        Algorithm 1's EE repulsion (30)); with a :class:`~hqp_tpm.references.trajectories.Harmonic` reference the
        reference and the rows are one compiled call (:func:`~hqp_tpm.tasks._compiled_rows.harmonic_position_rows`)."""
        model, data, fid, sel = state.model, state.data, self.fid, self._sel
        views = state.frame_views(fid)
        if views is None:
            plain = super().row_writer(state, order, J, b)

            def write_plain(t: float, extra=None) -> None:
                if extra is None:
                    plain(t)
                else:
                    self._write_readable(state, t, order, extra, J, b)
            return write_plain
        p = views[0]
        rate = np.zeros(self.dim)

        rows, none = self.rows, np.zeros(0)

        harmonic = _HarmonicParams()
        zero = np.zeros(self.dim)

        def write(t: float, extra=None) -> None:
            if extra is not None and (type(extra) is not np.ndarray or extra.shape != zero.shape
                                      or extra.dtype != zero.dtype):
                self._write_readable(state, t, order, extra, J, b)  # converted or refused as Task.command does
                return
            tr = self.trajectory
            if _compiled.ENABLED and type(tr) is Harmonic:  # reference and rows in one compiled call
                g, Jt = self.gains, pin.getFrameJacobian(model, data, fid, LWA)
                if order == 2:
                    np.dot(Jt[sel], state.v, out=rate)
                    acc = pin.getFrameClassicalAcceleration(model, data, fid, LWA).vector
                else:
                    acc = zero
                _compiled_rows.harmonic_position_rows(J, b, Jt, rows, p, rate, acc, harmonic.of(tr), t, g.kp, g.kd,
                                                      zero if extra is None else extra, extra is not None, order)
                return
            if extra is not None or not _compiled.ENABLED:
                self._write_readable(state, t, order, extra, J, b)
                return
            ref = tr.reference(t)  # one compiled call, the same operations
            g, Jt = self.gains, pin.getFrameJacobian(model, data, fid, LWA)
            if order == 1:
                _compiled.rows1(J, Jt, rows, b, ref[0], p, rows, none, ref[1], g.kp)
            else:
                np.dot(Jt[sel], state.v, out=rate)
                jdq = pin.getFrameClassicalAcceleration(model, data, fid, LWA).vector[sel]
                _compiled.rows2(J, Jt, rows, b, ref[0], p, rows, none, rate, jdq, ref[1], ref[2], g.kp, g.kd)
        return write

    def _write_readable(self, state: State, t: float, order: int, extra, J: np.ndarray, b: np.ndarray) -> None:
        """:meth:`jacobian` and :meth:`command` with the extra command into ``J``, ``b``."""
        Jt = self.jacobian(state)
        J[...] = Jt
        b[...] = self.command(state, t, order, extra, Jt)

    def row_program(self, state: State, order: int, program, row: int):
        """:meth:`Task.row_program`: the frame Jacobian and ``p`` (at order 2 also the selected ``J qd`` and ``Jdot
        qd``) into the kernel's slots; the reference into its floats. None (the row writer runs) with a
        :class:`~hqp_tpm.references.trajectories.Harmonic` reference: the writer computes it inside its one compiled
        call, where the program would copy ``Harmonic.reference``'s three arrays every step."""
        views = state.frame_views(self.fid)
        if views is None or (type(self.trajectory) is Harmonic and _compiled.ENABLED):
            return None
        model, data, fid, sel, d = state.model, state.data, self.fid, self._sel, self.dim
        p = views[0]
        g = self.gains
        source = state.frame_jacobian_source(fid)
        inside = source is not None  # the frame Jacobian (and J qd) computed in the kernel
        at, mat, vec, _ = program.add_frame(row, self.rows, self.rows, g.kp, g.kd, x_d_vec=False, x=p,
                                            jacobian=(*source, p) if inside else None,  # (p: pinocchio's view)
                                            placement=kernel_placement(state, fid, inside))
        refresh = ReferenceSlots(self, program, at - 2, at, ((0, d), (1, d), (2, d))).refresh
        S = program.mats[mat]  # the program's arrays (written here if not inside)
        rate, jdq = (program.vecs[vec + 1][:d], program.vecs[vec + 2][:d]) if order == 2 else (None, None)
        if inside and order == 1:
            return refresh  # (the kernel computes the rest)

        def gather(t: float) -> None:
            refresh(t)
            if not inside:
                S[...] = pin.getFrameJacobian(model, data, fid, LWA)
                if order == 2:
                    np.dot(S[sel], state.v, out=rate)
            if order == 2:
                jdq[...] = pin.getFrameClassicalAcceleration(model, data, fid, LWA).vector[sel]
        return gather


class _HarmonicParams:
    """A :class:`~hqp_tpm.references.trajectories.Harmonic`'s numbers packed for the compiled row writer, ``[omega,
    phase, (center, offset, cos_amplitude, sin_amplitude) per entry]``: packed again whenever the trajectory or one of
    its attributes is replaced (the offset is the origin of a relative trajectory, set by ``start``)."""

    __slots__ = ("key", "h")

    def __init__(self):
        self.key, self.h = (None,) * 7, None

    def of(self, tr: Harmonic) -> np.ndarray:
        k = self.key
        if (tr is k[0] and tr.origin is k[1] and tr.center is k[2] and tr.cos_amplitude is k[3]
                and tr.sin_amplitude is k[4] and tr.omega is k[5] and tr.phase is k[6]):
            return self.h
        n = tr.center.size
        offset = np.zeros(n) if tr.origin is None else np.asarray(tr.origin, dtype=float)
        body = np.stack([tr.center, offset, tr.cos_amplitude, tr.sin_amplitude], axis=1).ravel()
        self.h = np.concatenate([[float(tr.omega), float(tr.phase)], body])
        self.key = (tr, tr.origin, tr.center, tr.cos_amplitude, tr.sin_amplitude, tr.omega, tr.phase)
        return self.h

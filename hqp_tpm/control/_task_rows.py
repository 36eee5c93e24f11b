"""The task rows the compiled steps write (private): a task's :meth:`~hqp_tpm.tasks.base.Task.row_source` registered
with a :class:`~hqp_tpm.control._compiled_step.Program` (the fused step's, or one task's: :class:`TaskProgram`)."""

from __future__ import annotations

from collections.abc import Callable
from functools import cache

import numpy as np
import pinocchio as pin

from hqp_tpm.control import _compiled_step
from hqp_tpm.references.trajectories import Constant, Harmonic, Hold
from hqp_tpm.robot.state import LWA, State
from hqp_tpm.tasks.base import CenterOfMassRows, FrameRows, SelectionRows, Task, row_selector

#: The methods whose numbers a row source stands for (:func:`described`).
_DESCRIBED = ("value", "jacobian", "jdot_qdot", "error", "reference", "command", "level")


@cache
def described(kind: type[Task]) -> bool:
    """Whether task class ``kind``'s :meth:`~Task.row_source` stands for its rows: no class below the one that defines
    it overrides a method whose numbers it stands for."""
    def owner(name: str) -> type:
        return next(k for k in kind.__mro__ if name in vars(k))

    source = owner("row_source")
    return source is not Task and all(issubclass(source, owner(name)) for name in _DESCRIBED)


def source_of(task: Task) -> FrameRows | SelectionRows | CenterOfMassRows | None:
    """``task``'s row source where it stands for its rows (:func:`described`), else None."""
    return task.row_source() if described(type(task)) else None


def write_own_rows(task: Task, state: State, t: float, order: int, J: np.ndarray, b: np.ndarray,
                   extra=None) -> None:
    """``task``'s own :meth:`~Task.jacobian` and :meth:`~Task.command` (with ``extra``) at ``state`` into ``J``,
    ``b`` (views of stacked rows): the steps' rows of a task without compiled ones."""
    Jt = task.jacobian(state)
    J[...] = Jt
    b[...] = task.command(state, t, order, extra, Jt)


class ReferenceSlots:
    """Keeps a program's copy of a task's reference ``(x_d, xd_d, xdd_d)`` and gains current: ``x_d`` in vecs slot
    ``slot`` (None: the task's own array) bound to the trajectory's ``live`` array or copied; a frame entry's
    :class:`~hqp_tpm.references.trajectories.Harmonic` (``harmonic``: its ``ixd`` in ``ints``): in the kernel."""

    __slots__ = ("task", "program", "gains", "gains_at", "at", "d", "slot", "own", "bound", "last", "harmonic",
                 "terms")

    def __init__(self, task: Task, program, gains_at: int, at: int, d: int, slot: int | None,
                 harmonic: int | None = None):
        """``kp, kd`` at ``program.floats[gains_at:]``, ``xd_d, xdd_d`` (``d`` entries each) from ``at`` on (a
        Harmonic's terms from ``at - d``: base, a, b per row, omega, phase)."""
        self.task, self.program, self.gains_at, self.at, self.d, self.slot = task, program, gains_at, at, d, slot
        self.own = None if slot is None else program.vecs[slot]
        self.bound = self.last = self.terms = None
        self.harmonic, self.gains = harmonic, task.gains

    def refresh(self, t: float) -> None:
        task = self.task
        live = task.trajectory.live
        if live is None or live is not self.bound:
            self._copy(task.trajectory, live, t)
        if task.gains is not self.gains:
            self.gains = g = task.gains
            self.program.floats[self.gains_at: self.gains_at + 2] = g.kp, g.kd

    def _copy(self, tr, live, t: float) -> None:
        program, at, d = self.program, self.at, self.d
        floats = program.floats
        bind = live is not None and live.shape == (d,) and type(tr) in (Constant, Hold)  # x_d read in place
        if self.bound is not None and not bind:  # (x_d in this object's array again, before any other branch)
            if self.slot is not None:
                program.bind_vec(self.slot, self.own)
            self.bound = None
        if self.harmonic is not None:
            if type(tr) is Harmonic:  # its terms into the floats of x_d, xd, xdd (base, a, b), then omega, phase
                floats[_compiled_step.TIME] = t
                terms = tr.terms()
                if terms is not self.terms:
                    w, phase, fields = terms
                    floats[at - d: at + 2 * d] = np.array(fields).T.ravel()
                    floats[at + 2 * d], floats[at + 2 * d + 1] = w, phase
                    program.ints[self.harmonic] = _compiled_step.HARMONIC
                    self.terms, self.last = terms, None
                return
            if self.terms is not None:  # (no longer a Harmonic: x_d from its slot again)
                program.ints[self.harmonic], self.terms = self.slot, None
        ref = tr.reference(t)
        if bind:
            if self.slot is not None:
                program.bind_vec(self.slot, live)
            floats[at: at + d], floats[at + d: at + 2 * d] = ref[1], ref[2]
            self.bound, self.last = live, None
            return
        last = self.last or (None, None, None)
        if self.slot is not None and ref[0] is not last[0]:
            self.own[...] = ref[0]
        if ref[1] is not last[1]:
            floats[at: at + d] = ref[1]
        if ref[2] is not last[2]:
            floats[at + d: at + 2 * d] = ref[2]
        frozen = not (ref[0].flags.writeable or ref[1].flags.writeable or ref[2].flags.writeable)
        self.last = ref if frozen else None


def program_rows(task: Task, state: State, order: int, program, row: int, J: np.ndarray,
                 place: bool = True, rate: bool = True) -> Callable[[float], None] | None:
    """Register ``task``'s rows (stacked rows ``row...``, ``J`` their view) with ``program``: ``gather(t)``, run before
    each kernel call, or None. ``place``: the kernel places the frames it reads; ``rate``: at order 2 it computes a
    frame's Jacobian and ``J qd`` (else pinocchio's and numpy's, the bits of ``command``), each where it can."""
    source = source_of(task)
    if type(source) is SelectionRows:
        J[...] = task.jacobian(state)  # (constant: written once, the kernel writes b only)
        g, d = task.gains, len(source.qidx)
        at, slot = program.add_selection(row, source.qidx, source.vidx, g.kp, g.kd)
        return ReferenceSlots(task, program, at - 2, at, d, slot).refresh
    if type(source) is CenterOfMassRows:
        return _center_of_mass(task, source, state, order, program, row)
    if type(source) is FrameRows:
        return _frame(task, source, state, order, program, row, place, rate or order == 1)
    return None


def _center_of_mass(task: Task, source: CenterOfMassRows, state: State, order: int, program, row: int):
    """At velocity level: pinocchio's CoM and CoM Jacobian (transposed) as views in the kernel's slots, filled every
    step (:meth:`State.update_positions` with ``com``, else :meth:`State.com_kinematics`). Else None."""
    views = state.com_views()
    if views is None or order != 1:
        return None
    com, Jcom, _ = views
    d, g = len(source.rows), task.gains
    at, _, _, _, slot = program.add_frame(row, source.rows, source.rows, g.kp, g.kd, x=com,
                                          transposed=Jcom.T)  # (pinocchio updates both in place)
    refresh = ReferenceSlots(task, program, at - 2, at + d, d, slot, program.switches[0]).refresh
    program.com_in_update = True  # (the fused step's state update computes them: com_kinematics then returns)

    def gather(t: float) -> None:
        refresh(t)
        state.com_kinematics(1)  # (nothing when the fused step's state update computed them: com_in_update)
    return gather


def _frame(task: Task, source: FrameRows, state: State, order: int, program, row: int, place: bool, inside: bool):
    """A frame task's rows: the kernel places the frame, computes its Jacobian, ``log3(R_d R^T)``, ``J qd``, ``Jdot qd``
    where the state gives their sources (``frame_*_source``); else they are gathered here."""
    fid, rows, position = source.fid, source.rows, source.position
    views = state.frame_views(fid)
    if views is None:
        return None
    model, data = state.model, state.data
    p, R = views
    RT = R.T  # a view, as R
    d, k, g = len(rows), len(position), task.gains
    angular = k < d
    jsource = state.frame_jacobian_source(fid) if inside else None
    inside = jsource is not None  # the frame Jacobian, the rotation error (and J qd) computed in the kernel
    placed = state.frame_placement_source(fid) if place and inside else None
    placement = None if placed is None else (fid, *placed)
    ends = state.frame_jdot_source(fid) if inside and order == 2 else None  # (then Jdot qd in the kernel too)
    at, mat, vec, _, slot = program.add_frame(
        row, rows, position, g.kp, g.kd, x=p if k else None, jacobian=(*jsource, p) if inside else None,
        rotation=(RT, source.R_d.T) if inside and angular else None,  # (R_d: Fortran-ordered, R_d.T row-major)
        placement=placement, jdot=ends)
    if source.p_d is not None:  # x_d: the task's array (bound once: the task writes it in place)
        program.vecs[slot], slot = source.p_d, None
    refresh = ReferenceSlots(task, program, at - 2, at + k, d, None if slot == -1 else slot,
                             program.switches[0] if k == d and source.p_d is None else None).refresh
    if inside and order == 1:
        return refresh  # (the kernel computes the rest)
    S = program.mats[mat]  # the program's arrays (written here if not inside)
    ws = vec + (1 if k else 0)  # w's slot, then at order 2 J qd's and Jdot qd's
    w = program.vecs[ws] if angular else None
    rs = ws + (1 if angular else 0)
    rate, jdq = (program.vecs[rs][:d], program.vecs[rs + 1][:d]) if order == 2 else (None, None)
    sel = row_selector(np.array(rows))  # (contiguous rows: a slice, views)
    R_d = source.R_d

    def gather(t: float) -> None:
        refresh(t)
        if not inside:
            S[...] = pin.getFrameJacobian(model, data, fid, LWA)
            if angular:
                w[:3] = pin.log3(R_d.dot(RT))
            if order == 2:
                np.dot(S[sel], state.v, out=rate)
        if order == 2 and ends is None:
            jdq[...] = pin.getFrameClassicalAcceleration(model, data, fid, LWA).vector[sel]
    return gather


class TaskProgram:
    """One task's rows (no rotation error) written by the compiled rows kernel into ``J``, ``b``: ``write(t,
    extra=None)``, the bits of its ``jacobian`` and ``command(state, t, order, extra)``."""

    __slots__ = ("task", "state", "order", "J", "b", "program", "gather", "kernel", "buf", "rows", "extra")

    @classmethod
    def of(cls, task: Task, state: State, order: int, J: np.ndarray, b: np.ndarray) -> TaskProgram | None:
        """``task``'s program writing into ``J`` (``dim x n``), ``b``, or None (no row source without a rotation
        error, or no compiled kernel)."""
        source = source_of(task)
        if source is None or type(source) is FrameRows and source.R_d is not None \
                or (kernel := _compiled_step.rows_writer()) is None:
            return None
        self = cls.__new__(cls)
        dim, n = J.shape
        program = _compiled_step.Program(dim, n, (dim,), order, 0.0, 0.0, False, solve=_compiled_step.ROWS)
        self.buf = np.zeros(program.buffer_size(dim, n, _compiled_step.ROWS))
        self.rows = self.buf[: dim * n].reshape(dim, n), self.buf[dim * n: dim * n + dim]
        gather = program_rows(task, state, order, program, 0, self.rows[0], place=False, rate=False)
        if gather is None:
            return None
        self.extra = program.switches[1:] if type(source) is not SelectionRows else None
        self.task, self.state, self.order, self.J, self.b = task, state, order, J, b
        self.program, self.gather, self.kernel = program.build(), gather, kernel
        return self

    def __call__(self, t: float, extra: np.ndarray | None = None) -> None:
        ints, where = self.program.ints, self.extra
        if not _compiled_step._compiled.ENABLED or extra is not None and (
                where is None or type(extra) is not np.ndarray or extra.shape != self.b.shape or extra.dtype != float):
            # the kernels switched off, or an extra command to convert or refuse as Task.command does
            write_own_rows(self.task, self.state, t, self.order, self.J, self.b, extra)
            return
        if extra is not None:
            self.program.vecs[where[1]][...] = extra
            ints[where[0]] = where[1]
        elif where is not None:
            ints[where[0]] = -1
        self.gather(t)
        st = self.state
        self.kernel(self.buf, ints, self.program.floats, st.q, st.v)  # (rows not finite: the step's check finds them)
        self.J[...], self.b[...] = self.rows

"""The task rows the compiled steps write (private): a task's :meth:`~hqp_tpm.tasks.base.Task.row_source`
registered with a :class:`~hqp_tpm.control._compiled_step.Program`, the fused step's of a fixed stack
(:mod:`hqp_tpm.control._lean`) or, as a :class:`TaskProgram`, one task's in the planned step of a policy
(:mod:`hqp_tpm.control._planned_step`).

One registration for every task that describes its rows (frame position, orientation and pose, the centre of mass at
velocity level, the posture of revolute and prismatic joints): the kernel reads pinocchio's frame placements and
Jacobians in place (or the step gathers them here), the task's target arrays, and its reference and gains as copied
here when they change; it then writes ``J`` and ``b`` with :func:`~hqp_tpm.tasks.base.tracking_command`, the numbers
of the task's :meth:`~hqp_tpm.tasks.base.Task.jacobian` and :meth:`~hqp_tpm.tasks.base.Task.command`."""

from __future__ import annotations

from collections.abc import Callable
from functools import cache

import numpy as np
import pinocchio as pin

from hqp_tpm.control import _compiled_step
from hqp_tpm.references.trajectories import Harmonic
from hqp_tpm.robot.state import LWA, State
from hqp_tpm.tasks.base import CenterOfMassRows, FrameRows, SelectionRows, Task, row_selector

#: The methods whose numbers a row source stands for (:func:`described`).
_DESCRIBED = ("value", "jacobian", "jdot_qdot", "error", "reference", "command", "level")


@cache
def described(kind: type[Task]) -> bool:
    """Whether task class ``kind``'s :meth:`~Task.row_source` stands for its rows: no class below the one that defines
    it overrides a method whose numbers it stands for (a subclass that changes ``jacobian`` only, say, is written by
    its ``jacobian`` and ``command``)."""
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
    """Copies a task's reference ``(x_d, xd_d, xdd_d)`` (the parts named by ``parts``) and gains into a program's
    floats when they are not the ones copied last (compared by identity, part by part): a constant reference is one
    read-only tuple between starts and assignments (copied once; an assigned constant changes ``x_d`` only,
    :meth:`~hqp_tpm.references.trajectories.Constant.assign`); any other is copied every step, but a
    :class:`~hqp_tpm.references.trajectories.Harmonic` one of a frame entry (``harmonic``): its terms are copied
    when they change, the kernel computes the reference (:data:`~hqp_tpm.control._compiled_step.HARMONIC`)."""

    __slots__ = ("program", "parts", "last", "gains", "gains_at", "task", "views", "harmonic", "terms")

    def __init__(self, task: Task, program, gains_at: int, at: int, parts: tuple[tuple[int, int], ...],
                 harmonic: int | None = None):
        """``kp, kd`` at ``program.floats[gains_at:]``, the reference parts ``(index, entries)`` from ``at`` on;
        ``harmonic``: the frame entry's ``ixd`` in ``program.ints`` (its floats: ``x_d, xd, xdd, omega, phase``)."""
        self.task, self.program, self.gains_at, self.parts = task, program, gains_at, []
        self.harmonic, self.terms = harmonic, None
        for i, size in parts:  # (index into the reference, its slice of the floats), laid out one after the other
            self.parts.append((i, slice(at, at + size)))
            at += size
        self.last, self.gains, self.views = (None, None, None), task.gains, None

    def _harmonic(self, t: float) -> None:
        """The Harmonic reference's terms into the floats of ``x_d, xd, xdd`` (base, a, b per row) and after them
        ``omega, phase``; the step's time into ``floats[TIME]``."""
        floats = self.program.floats
        floats[_compiled_step.TIME] = t
        terms = self.task.trajectory.terms()
        if terms is not self.terms:
            w, phase, fields = terms
            k, at = len(fields), self.parts[0][1].start
            for i, (base, a, b) in enumerate(fields):
                floats[at + i], floats[at + k + i], floats[at + 2 * k + i] = base, a, b
            floats[at + 3 * k], floats[at + 3 * k + 1] = w, phase
            self.program.ints[self.harmonic] = _compiled_step.HARMONIC
            self.terms, self.last = terms, (None, None, None)

    def refresh(self, t: float) -> None:
        task = self.task
        if self.harmonic is not None:
            if type(task.trajectory) is Harmonic:
                self._harmonic(t)
                if task.gains is not self.gains:
                    self.gains = g = task.gains
                    self.program.floats[self.gains_at: self.gains_at + 2] = g.kp, g.kd
                return
            if self.terms is not None:  # (no longer a Harmonic: the reference copied again)
                self.program.ints[self.harmonic], self.terms = -1, None
        ref = task.trajectory.reference(t)
        last = self.last
        if ref is not last:
            if self.views is None:  # (the program's floats exist once it is built)
                self.views = [self.program.floats[s] for _, s in self.parts]
            for (i, _), view in zip(self.parts, self.views, strict=True):
                if ref[i] is not last[i]:
                    view[...] = ref[i]
            frozen = not (ref[0].flags.writeable or ref[1].flags.writeable or ref[2].flags.writeable)
            self.last = ref if frozen else (None, None, None)
        if task.gains is not self.gains:
            self.gains = g = task.gains
            self.program.floats[self.gains_at: self.gains_at + 2] = g.kp, g.kd


def program_rows(task: Task, state: State, order: int, program, row: int, J: np.ndarray,
                 place: bool = True, rate: bool = True) -> Callable[[float], None] | None:
    """Register ``task``'s rows (from stacked row ``row`` on; ``J`` their view of the stacked Jacobian) with
    ``program`` and return ``gather(t)``, which copies what changed into the program before each kernel call; None:
    the task has no row source the kernel can read (the step calls its ``jacobian`` and ``command``). ``place``: the
    kernel places the frames it reads where it can (else the state update places them); ``rate``: at order 2 the kernel
    computes a frame's Jacobian and ``J qd`` where it can (else pinocchio's Jacobian and numpy's ``J qd``, the bits of
    ``command``)."""
    source = source_of(task)
    if type(source) is SelectionRows:
        J[...] = task.jacobian(state)  # (constant: written once, the kernel writes b only)
        g, d = task.gains, len(source.qidx)
        at = program.add_selection(row, source.qidx, source.vidx, g.kp, g.kd)
        return ReferenceSlots(task, program, at - 2, at, ((0, d), (1, d), (2, d))).refresh
    if type(source) is CenterOfMassRows:
        return _center_of_mass(task, source, state, order, program, row)
    if type(source) is FrameRows:
        return _frame(task, source, state, order, program, row, place, rate or order == 1)
    return None


def _center_of_mass(task: Task, source: CenterOfMassRows, state: State, order: int, program, row: int):
    """At velocity level: pinocchio's CoM and CoM Jacobian (transposed) as views in the kernel's slots, filled by
    ``jacobianCenterOfMass`` every step (in the lean step's state update, :meth:`State.update_positions` with
    ``com``, else :meth:`State.com_kinematics`). At acceleration level: None."""
    views = state.com_views()
    if views is None or order != 1:
        return None
    com, Jcom, _ = views
    d, g = len(source.rows), task.gains
    at, _, _, _ = program.add_frame(row, source.rows, source.rows, g.kp, g.kd, x_d_vec=False, x=com,
                                    transposed=Jcom.T)  # (pinocchio updates both in place)
    refresh = ReferenceSlots(task, program, at - 2, at, ((0, d), (1, d), (2, d)), program.switches[0]).refresh
    program.com_in_update = True  # (the lean step's state update computes them: com_kinematics then returns)

    def gather(t: float) -> None:
        refresh(t)
        state.com_kinematics(1)  # (nothing when the lean step's state update computed them: com_in_update)
    return gather


def _frame(task: Task, source: FrameRows, state: State, order: int, program, row: int, place: bool, inside: bool):
    """A frame task's rows: where the state gives views of pinocchio's joint Jacobians and placements
    (:meth:`State.frame_jacobian_source`, :meth:`State.frame_placement_source`) the kernel places the frame, computes
    its Jacobian, ``log3(R_d R^T)`` and (order 2) ``J qd`` and, where the state offers it
    (:meth:`State.frame_jdot_source`), ``Jdot qd`` itself; else they are gathered here."""
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
    placement = None
    if place and inside and (placed := state.frame_placement_source(fid)) is not None:
        placement = (fid, *placed)
    ends = state.frame_jdot_source(fid) if inside and order == 2 else None  # (then Jdot qd in the kernel too)
    at, mat, vec, _ = program.add_frame(
        row, rows, position, g.kp, g.kd, x_d_vec=source.p_d is not None, x=p if k else None,
        jacobian=(*jsource, p) if inside else None,
        rotation=(RT, source.R_d.T) if inside and angular else None,  # (R_d: Fortran-ordered, R_d.T row-major)
        placement=placement, jdot=ends)
    if source.p_d is not None:  # x_d: the task's array (bound once: the task writes it in place)
        program.vecs[vec + (1 if k else 0) + (1 if angular else 0) + (2 if order == 2 else 0)] = source.p_d
        parts = ((1, d), (2, d))
    else:
        parts = ((0, k), (1, d), (2, d)) if k else ((1, d), (2, d))
    refresh = ReferenceSlots(task, program, at - 2, at + (k if source.p_d is not None else 0), parts,
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
    """One task's rows written by the compiled rows kernel into ``J``, ``b`` (the planned step's,
    :mod:`hqp_tpm.control._planned_step`): ``write(t, extra=None)`` gives the numbers of the task's ``jacobian`` and
    ``command(state, t, order, extra)`` to the last bit, the extra command added in the kernel as ``command`` adds
    it. For the tasks without a rotation error (frame positions, the CoM at velocity level, a posture without an
    extra command; the planned step's state update places every frame, the kernel does not; at order 2 ``J qd`` is
    numpy's dot of pinocchio's Jacobian, as in ``command``: the same bits)."""

    __slots__ = ("task", "state", "order", "J", "b", "program", "gather", "kernel", "buf", "rows", "extra")

    @classmethod
    def of(cls, task: Task, state: State, order: int, J: np.ndarray, b: np.ndarray) -> TaskProgram | None:
        """``task``'s program writing into ``J`` (``dim x n``), ``b``, or None (no row source without a rotation
        error, or no compiled kernel)."""
        source = source_of(task)
        if source is None or (type(source) is FrameRows and source.R_d is not None):
            return None
        kernel = _compiled_step.kernel(_compiled_step.ROWS)
        if kernel is None:
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

"""The fused step's rows, box and solve in one compiled call (private; :mod:`hqp_tpm.control._planned_step`).

:func:`kernel` gives one kernel per thing solved (:data:`ROWS`, :data:`TPM`, :data:`SNS`), each compiling only what
it calls; :class:`Program` packs its arguments. A status other than :data:`SOLVED` hands the step back to the caller
(the statuses below). Details: docs/architecture.md, "How ctrl.step() runs compiled"."""

from __future__ import annotations

import math

import numpy as np

from hqp_tpm import _jit
from hqp_tpm.references.trajectories import harmonic_point
from hqp_tpm.robot import _compiled as _robot_compiled
from hqp_tpm.solvers import _compiled, _compiled_sns
from hqp_tpm.solvers._fullrank import COND, MARGIN
from hqp_tpm.solvers.levels import MAX_SUMSQ
from hqp_tpm.tasks.base import tracking_command

SOLVED, DECLINED, UNDECIDED = _compiled.SOLVED, _compiled.DECLINED, _compiled.UNDECIDED
#: the TPM kernel met a pivot block only its SVD decides: ``tpm_stacked(kernel_status=PIVOT_SVD)`` finishes.
PIVOT_SVD = _compiled.PIVOT_SVD
#: ``J`` or ``b`` holds a non-finite value, or their sum of squares exceeds ``levels.MAX_SUMSQ`` (nothing solved).
NONFINITE_ROWS = 3
#: the solution holds a non-finite value.
NONFINITE_X = 4
#: the rows are written and finite, nothing solved (a program built with ``solve=ROWS``: another solver's turn).
WRITTEN = 5
#: the SNS-TPM loop handed back (its status codes ``BAD_BOX``, ``DECLINED``, ``SHIFT``): the numpy path solves.
SNS_HANDED_BACK = 6
#: the joint box's kernel declined (an empty position box: the recovery rules); nothing solved.
BOX_HANDED_BACK = 7
#: Where the SNS box comes from (:meth:`Program.set_box`): the caller, the velocity box, the acceleration box.
BOX_GIVEN, BOX_VELOCITY, BOX_ACCELERATION = 0, 1, 2
#: What a program solves (:class:`Program`): nothing (the rows only), TPM, SNS-TPM in the box ``lo, up``.
ROWS, TPM, SNS = 0, 1, 2
#: The kinds of task rows the kernel writes (:class:`Program`).
SELECTION, FRAME = 0, 1
#: ``jsrc`` of a frame entry whose Jacobian slot holds the Jacobian transposed (:meth:`Program.add_frame`).
TRANSPOSED = -2
#: ``ixd`` of a frame entry whose reference is a Harmonic's terms, computed at ``floats[TIME]`` (``Program.switches``).
HARMONIC = -2
#: ``floats[TIME]``: the time of the step (a Harmonic reference's).
TIME = 5
#: ``ints[:HEAD]``: m, n, use_x0, the level count, order, the task count, solve, the address tables' offsets.
HEAD = 9

#: the compiled kernels by what they solve (:func:`kernel`), compiled or loaded on first use
_KERNELS: dict = {}
# the kernels the steps call, set by _build (globals: numba resolves them when it compiles a step)
_write_rows = _past_rank = _general = _general_svd = _sns_loop = _velocity_box = _acceleration_box = None
_frame_jacobian = _rotation_error = _frame_placement = _frame_jdot_qdot = _mat = _vec = None
_command, _harmonic = tracking_command, harmonic_point  # (Task.command's, Harmonic.reference's; compiled by _build)


def _rows(buf, ints, floats, q, v):  # pragma: no cover - compiled
    """The program's rows of ``J``, ``b``: ``(WRITTEN or NONFINITE_ROWS, pi, pf)``, ``pi``, ``pf`` the ends of the
    tasks' entries in ``ints``, ``floats`` (where the SNS entries start). Plain Python until :func:`_build`."""
    m, n, nlev, order, count = ints[0], ints[1], ints[3], ints[4], ints[5]
    mn = m * n
    J = buf[:mn].reshape((m, n))
    b = buf[mn: mn + m]
    pi, pf = HEAD + nlev, TIME + 1
    for _ in range(count):  # the program's tasks: their rows of J and b
        kind, r0, dim = ints[pi], ints[pi + 1], ints[pi + 2]
        kp, kd = floats[pf], floats[pf + 1]
        if kind == SELECTION:  # the posture rows (Task.command: tracking_command, Jdot qd = 0)
            x_s = _vec(ints, ints[pi + 3])
            for i in range(dim):
                e = x_s[i] - q[ints[pi + 4 + i]]
                b[r0 + i] = _command(order, e, floats[pf + 2 + i], floats[pf + 2 + dim + i],
                                     v[ints[pi + 4 + dim + i]], 0.0, kp, kd)
            pi += 4 + 2 * dim
            pf += 2 + 2 * dim
        else:  # FRAME: the frame's rows, b by tracking_command
            k, jm, iv, ixd = ints[pi + 3], ints[pi + 4], ints[pi + 5], ints[pi + 6]
            jsrc, ip, rot, nc = ints[pi + 7], ints[pi + 8], ints[pi + 9], ints[pi + 10]
            place, acc = ints[pi + 11], ints[pi + 12]  # the frame's placement from its joint's (else the caller's)
            at = pi + 13                               # the rows, xrows, the Jacobian's columns, (acc) their ends
            if place >= 0:                             # mats: R_i^T, P, R_f^T from slot place; vecs: p_i, p
                _frame_placement(_mat(ints, place), _vec(ints, ints[at + dim + k + nc + (nc if acc else 0)]),
                                 _mat(ints, place + 1), _mat(ints, place + 2), _vec(ints, ip))
            S = _mat(ints, jm)
            if jsrc >= 0:  # the frame Jacobian from the joint Jacobians (else the caller put it in mats[jm])
                _frame_jacobian(_mat(ints, jsrc), ints[at + dim + k: at + dim + k + nc], _vec(ints, ip), S)
            ws = iv + (1 if k else 0)                  # w's slot, then at order 2 J qd's and Jdot qd's
            rs = ws + (1 if k < dim else 0)
            if rot >= 0:  # w = log3(R_d R^T) (else the caller put it in vecs[ws])
                _rotation_error(_mat(ints, rot + 1), _mat(ints, rot), _vec(ints, ws))
            if order == 2:
                rate, jdq = _vec(ints, rs), _vec(ints, rs + 1)
            if jsrc >= 0 and order == 2:  # J qd of the task's rows
                for i in range(dim):
                    src = ints[at + i]
                    r = 0.0
                    for c in range(n):
                        r += S[src, c] * v[c]
                    rate[i] = r
                if acc:  # Jdot qd of the task's rows from the joint Jacobians (else the caller put it in its slot)
                    full = np.empty(6)
                    _frame_jdot_qdot(_mat(ints, jsrc), ints[at + dim + k: at + dim + k + nc],
                                     ints[at + dim + k + nc: at + dim + k + 2 * nc], v, _vec(ints, ip), full)
                    for i in range(dim):
                        jdq[i] = full[ints[at + i]]
            fx, fxd = pf + 2, pf + 2 + k
            harmonic = ixd == HARMONIC
            if harmonic:  # Harmonic.reference's terms: base, a, b per row in place of x_d, xd, xdd; omega, phase
                hw = floats[fxd + 2 * dim]
                arg = hw * floats[TIME] + floats[fxd + 2 * dim + 1]
                hc, hs = math.cos(arg), math.sin(arg)
            tail = pi + 13 + dim + k + nc + (nc if acc else 0) + (1 if place >= 0 else 0)
            iex = ints[tail]  # the extra command's slot (-1: none)
            if iex >= 0:
                ex = _vec(ints, iex)
            if k:
                x = _vec(ints, iv)
                if not harmonic:
                    x_dv = _vec(ints, ixd)
            if k < dim:
                w = _vec(ints, ws)
            for i in range(dim):
                src = ints[at + i]
                if jsrc == TRANSPOSED:  # S given as S^T (n x rows: pinocchio's CoM Jacobian transposed)
                    for c in range(n):
                        J[r0 + i, c] = S[c, src]
                else:
                    for c in range(n):
                        J[r0 + i, c] = S[src, c]
                xd, xdd = floats[fxd + i], floats[fxd + dim + i]
                if i < k:
                    if harmonic:
                        x_d, xd, xdd = _harmonic(floats[fx + i], xd, xdd, hw, hc, hs)
                    else:
                        x_d = x_dv[i]
                    e = x_d - x[ints[at + dim + i]]
                else:
                    e = w[i - k]
                if order == 1:  # (Task.command: the extra command added to b at order 1, to xdd at order 2)
                    bb = _command(1, e, xd, 0.0, 0.0, 0.0, kp, kd)
                    b[r0 + i] = bb + ex[i] if iex >= 0 else bb
                else:
                    if iex >= 0:
                        xdd = xdd + ex[i]
                    b[r0 + i] = _command(2, e, xd, xdd, rate[i], jdq[i], kp, kd)
            pi = tail + 1
            pf += 4 + k + 2 * dim
    s = 0.0                                            # NaN, inf and too large rows all fail one sum of squares
    for i in range(mn + m):
        s += buf[i] * buf[i]
    if not s <= MAX_SUMSQ:
        return NONFINITE_ROWS, pi, pf
    return WRITTEN, pi, pf


def _x_status(status, out):  # pragma: no cover - compiled (inlined)
    """The solve's ``status``, or :data:`NONFINITE_X` if it solved and ``out`` holds a non-finite value."""
    if status != SOLVED:
        return status
    for i in range(out.shape[0]):
        if not math.isfinite(out[i]):
            return NONFINITE_X
    return SOLVED


def _step_arrays(buf, ints):  # pragma: no cover - compiled (inlined)
    """``(J, b, x0, out, sizes)``: the views of a program's buffer and integers a solve reads and writes."""
    m, n, nlev = ints[0], ints[1], ints[3]
    mn = m * n
    return (buf[:mn].reshape((m, n)), buf[mn: mn + m], buf[mn + m: mn + m + n], buf[mn + m + n: mn + m + 2 * n],
            ints[HEAD: HEAD + nlev])


def _rows_step(buf, ints, floats, q, v):  # pragma: no cover - compiled
    """:data:`ROWS`: the rows and their finiteness only."""
    return _write_rows(buf, ints, floats, q, v)[0]


def _tpm_step(buf, ints, floats, q, v):  # pragma: no cover - compiled
    """:data:`TPM`, ``m <= n``: the rows, the TPM kernel (``_general``), ``x``'s finiteness."""
    status, pi, pf = _write_rows(buf, ints, floats, q, v)
    if status != WRITTEN:
        return status
    J, b, x0, out, sizes = _step_arrays(buf, ints)
    return _x_status(_general(J, b, sizes, x0, ints[2] != 0, floats[0], floats[1], floats[2], out), out)


def _tpm_step_tall(buf, ints, floats, q, v):  # pragma: no cover - compiled
    """:data:`TPM`, ``m > n``: the rows, the TPM kernel (``_past_rank``), ``x``'s finiteness."""
    status, pi, pf = _write_rows(buf, ints, floats, q, v)
    if status != WRITTEN:
        return status
    J, b, x0, out, sizes = _step_arrays(buf, ints)
    return _x_status(_past_rank(J, b, sizes, ints[1], floats[0], floats[1], floats[2], floats[3], floats[4], out), out)


def _sns_step(buf, ints, floats, q, v):  # pragma: no cover - compiled
    """:data:`SNS`: the rows, the box (:meth:`Program.set_box`), the SNS-TPM loop, ``x``'s finiteness; the end of
    ``buf`` gets the solve's info (:meth:`Program.sns_info`)."""
    status, pi, pf = _write_rows(buf, ints, floats, q, v)
    if status != WRITTEN:
        return status
    J, b, _, out, sizes = _step_arrays(buf, ints)
    n = ints[1]
    o = ints[0] * (n + 1) + 2 * n  # the box lo, up, the loop's scratch (3 x n), then the solve's info
    lo, up, state = buf[o: o + n], buf[o + n: o + 2 * n], buf[o + 2 * n: o + 5 * n].reshape((3, n))
    bi = pi + n  # (the loop's scratch,) the box: where from, the slot of its limits in mats, its joint count, indices
    box = ints[bi]
    if box != BOX_GIVEN:
        nc = ints[bi + 2]
        idx = ints[bi + 3: bi + 3 + 2 * nc].reshape((2, nc))
        if box == BOX_VELOCITY:
            ok = _velocity_box(q, _mat(ints, ints[bi + 1]), idx, floats[pf], lo, up)
        else:
            ok = _acceleration_box(q, v, _mat(ints, ints[bi + 1]), idx, floats[pf], lo, up)
        if not ok:
            return BOX_HANDED_BACK
    status, scale, nsat, iterations, feasible, _ = _sns_loop(
        J, b, sizes, lo, up, floats[0], floats[1], floats[2], floats[3], floats[4], out, ints[pi: bi], state)
    if status != _compiled_sns.DONE:
        return SNS_HANDED_BACK
    if _x_status(SOLVED, out) != SOLVED:
        return NONFINITE_X
    o += 5 * n
    buf[o], buf[o + 1], buf[o + 2] = scale, nsat, iterations
    buf[o + 3] = 1.0 if feasible else 0.0
    for i in range(nsat):  # the saturated joints, from the loop's scratch
        buf[o + 4 + i] = ints[pi + i]
    return SOLVED


def _stacked_rows(J, b, v, damping, x0):  # pragma: no cover - compiled
    """The finiteness of the planned step's stacked ``J``, ``b`` and ``x0 = -damping v`` when ``damping`` (eq. (15)
    of papers/000): -1 a non-finite or too large value (nothing written), 1 ``x0`` written, 0 no ``x0``."""
    m, n = J.shape
    s = 0.0                                            # NaN, inf and too large rows all fail one sum of squares
    for i in range(m):
        s += b[i] * b[i]
        for j in range(n):
            s += J[i, j] * J[i, j]
    if not s <= MAX_SUMSQ:
        return -1
    if damping == 0.0:
        return 0
    for i in range(n):
        x0[i] = -damping * v[i]
    return 1


def stacked_tpm(J, b, sizes, v, damping, lambda_max, eps, unit, margin, cond, x0, out):
    """The planned step's TPM solve of its stacked ``J`` (``m x n``), ``b``: :func:`_stacked_rows`, the kernel
    ``tpm_stacked`` would call (``_compiled._general``, read at each call: it may become the SVD one; ``m > n``:
    ``_past_rank``), ``x``'s finiteness; the statuses of :func:`kernel`. Compiled calls, not one kernel: a kernel
    calling ``_general`` would compile its code once more (~2 s of a first run)."""
    use_x0 = _stacked_rows(J, b, v, damping, x0)
    if use_x0 < 0:
        return NONFINITE_ROWS
    m, n = J.shape
    if m > n:
        return _x_status(_past_rank(J, b, sizes, n, lambda_max, eps, unit, margin, cond, out), out)
    return _x_status(_compiled._general(J, b, sizes, x0, use_x0 == 1, lambda_max, eps, unit, out), out)


def _solves() -> bool:
    """Make the dispatchers of the solvers' kernels (numba compiles or loads each on the first call of a kernel that
    calls it) and of this module's pieces; False if numba cannot be imported after all."""
    global _past_rank, _general, _general_svd, _x_status, _step_arrays, _stacked_rows
    if _compiled._sizes(()) is None:  # prepares (or loads) hqp_tpm.solvers._compiled's kernels first
        return False
    if _KERNELS.get("solves") is None:
        # (_general_first: the kernel that hands back PIVOT_SVD, even after the process rebound _compiled._general)
        _past_rank, _general, _general_svd = _compiled._past_rank, _compiled._general_first, _compiled._general_svd
        _x_status, _step_arrays = (_jit.dispatcher(f, inline=True) for f in (_x_status_py, _step_arrays_py))
        _stacked_rows = _jit.dispatcher(_stacked_rows_py)
        _KERNELS["solves"] = True
    return True


_x_status_py, _step_arrays_py, _stacked_rows_py = _x_status, _step_arrays, _stacked_rows  # (the Python sources)


def stacked_kernel():
    """:func:`stacked_tpm` (``sizes`` an int64 array; its kernels compiled or loaded on first use), or None if numba
    cannot be imported after all."""
    return stacked_tpm if _solves() else None


def _rows_writer():
    """:func:`_rows` compiled, ``(buf, ints, floats, q, v) -> (status, pi, pf)``, after binding its callees (the
    fused kernels call it); None if numba cannot be imported."""
    global _write_rows, _frame_placement, _frame_jacobian, _rotation_error, _frame_jdot_qdot, _mat, _vec, _command
    global _harmonic
    if not _solves():
        return None
    if not _jit.compile_module(vars(_robot_compiled)):  # (dispatchers already, unless the switch was off at import)
        return None
    if _write_rows is None:
        _frame_jacobian, _rotation_error = _robot_compiled.frame_jacobian, _robot_compiled.rotation_error
        _frame_placement, _frame_jdot_qdot = _robot_compiled.frame_placement, _robot_compiled.frame_jdot_qdot
        readers = _jit.address_readers()
        if readers is None:
            return None
        _mat, _vec = readers
        _command = _jit.dispatcher(tracking_command, inline=True)
        _harmonic = _jit.dispatcher(harmonic_point, inline=True)
        _write_rows = _jit.dispatcher(_rows)
    return _write_rows


def rows_writer():
    """The rows kernel of a :class:`~hqp_tpm.control._task_rows.TaskProgram`: :func:`_rows` without the rotation error,
    the frame placement and ``Jdot qd`` (:func:`hqp_tpm._jit.variant`; ~1.2 s of a first run); None without numba."""
    if _rows_writer() is None:
        return None
    if "task rows" not in _KERNELS:
        _KERNELS["task rows"] = _jit.dispatcher(_jit.variant(
            _rows, "_of_task", "_rotation_error", "_frame_placement", "_frame_jdot_qdot"))
    return _KERNELS["task rows"]


def _build(solve: int, tall: bool, svd: bool = False):
    """Compile the kernel of ``solve`` after the kernels it calls (its own only: a ``tpm`` user does not compile the
    SNS loop); None if numba cannot be imported."""
    global _sns_loop, _velocity_box, _acceleration_box
    if _rows_writer() is None:
        return None
    if solve == SNS and not _compiled_sns._READY:
        try:
            _compiled_sns._compile()
        except ImportError:  # pragma: no cover - numba not importable after all
            return None
    _sns_loop = _compiled_sns._sns_loop
    _velocity_box, _acceleration_box = _robot_compiled.velocity_box, _robot_compiled.acceleration_box
    step = {ROWS: _rows_step, TPM: _tpm_step_tall if tall else _tpm_step, SNS: _sns_step}[solve]
    if svd:  # a stack that met a pivot block only its SVD decides: _tpm_step with _general_svd (no hand-back)
        step = _jit.variant(_tpm_step, "_svd", _general=_general_svd)
    _KERNELS[(solve, tall, svd)] = _jit.dispatcher(step)
    return _KERNELS[(solve, tall, svd)]


def _checked(a: np.ndarray, ndim: int) -> np.ndarray:
    """``a`` if the kernel can read it by address: float64, ``ndim`` dimensions, C-contiguous."""
    if a.dtype != np.float64 or a.ndim != ndim or not a.flags.c_contiguous:
        raise ValueError(f"a program slot takes a C-contiguous float64 array of {ndim} dimensions, not {a.dtype} "
                         f"{a.shape} (C-contiguous: {a.flags.c_contiguous})")
    return a


class Program:
    """The packed arguments ``ints``, ``floats`` of :func:`kernel` for a stack of ``m`` rows in levels of ``sizes`` at
    ``order``, and the tasks whose rows the kernel writes (:meth:`add_selection`, :meth:`add_frame`); the other arrays
    it reads are slots of :attr:`mats`, :attr:`vecs` (layout: docs/internals.md#compiled-step)."""

    def __init__(self, m: int, n: int, sizes, order: int, lambda_max: float, eps: float, use_x0: bool,
                 solve: int = TPM):
        if solve not in (ROWS, TPM, SNS) or (solve == SNS and use_x0):
            raise ValueError(f"solve={solve!r}: ROWS, TPM or SNS (SNS without x0)")
        self.order, self.solve = order, solve
        self._box: list = [BOX_GIVEN, 0, 0]
        self._dt = 0.0
        self._ints = [m, n, int(use_x0), len(sizes), order, 0, int(solve), 0, 0, *sizes]
        self._floats = [lambda_max, eps, _compiled._UNIT, MARGIN, COND, 0.0]  # (then the step's time)
        #: the arrays the kernel reads (2-D, 1-D; float64, C-contiguous) by slot; a task owns its slots
        self.mats: list[np.ndarray] = []
        self.vecs: list[np.ndarray] = []
        self.ints = self.floats = None
        #: the frames the kernel places itself (:meth:`add_frame`'s ``placement``)
        self.placed: set[int] = set()
        #: a task's rows read pinocchio's CoM and its Jacobian: the fused step's state update computes them (order 1)
        self.com_in_update = False
        #: a task's rows read pinocchio's velocity pass (order 2, :meth:`add_frame` without ``jdot``)
        self.velocity_pass = False

    def _gains(self, kp: float, kd: float, values: int) -> int:
        self._ints[5] += 1
        self._floats += [kp, kd]
        at = len(self._floats)
        self._floats += [0.0] * values
        return at

    def add_selection(self, row: int, qidx, vidx, kp: float, kd: float) -> tuple[int, int]:
        """Rows ``row...`` with ``b = xd_d + kp (x_d - q[qidx])`` (order 1) or ``xdd_d + kd (xd_d - v[vidx]) + kp (x_d -
        q[qidx]) - 0`` (order 2), ``J`` constant (not written); returns ``(at, vec)``: the offset of ``xd_d, xdd_d`` in
        :attr:`floats` and the slot of ``x_d`` in :attr:`vecs` (its owner keeps them current)."""
        dim = len(qidx)
        self._ints += [SELECTION, row, dim, len(self.vecs), *qidx, *vidx]
        self.vecs.append(np.zeros(dim))
        return self._gains(kp, kd, 2 * dim), len(self.vecs) - 1

    def add_frame(self, row: int, rows, xrows, kp: float, kd: float, x: np.ndarray | None = None,
                  jacobian=None, rotation=None, transposed: np.ndarray | None = None,
                  placement=None, jdot: np.ndarray | None = None) -> tuple[int, int, int, int, int]:
        """Rows ``row...`` of a frame task: ``J[i] = S[rows[i]]`` (``S = mats[mat]``), ``e = [x_d - x[xrows], w]``,
        ``b`` as :meth:`hqp_tpm.tasks.base.Task.command`; the sources the kernel computes from, else the caller writes
        them (docs/internals.md#compiled-step). Returns ``(at, mat, vec, rot, xslot)``: the offset of ``[x_d], xd_d,
        xdd_d`` in :attr:`floats`, the slots of ``S``, of the first vector, of ``RT`` and of ``x_d`` (-1: none)."""
        if transposed is not None and (self.order != 1 or jacobian is not None):
            raise ValueError("add_frame: a transposed Jacobian: order 1, and no joint-Jacobian source")
        if jdot is not None and (self.order != 2 or jacobian is None or len(jdot) != len(jacobian[1])):
            raise ValueError("add_frame: jdot: order 2, with the joint-Jacobian source, one entry per column")
        if placement is not None and jacobian is None:
            raise ValueError("add_frame: a frame placed in the kernel: with its joint-Jacobian source")
        dim, k = len(rows), len(xrows)
        mat, vec = len(self.mats), len(self.vecs)
        used = (1 if k else 0) + (1 if k < dim else 0) + (2 if self.order == 2 else 0)
        self.mats.append(np.zeros((6, self._ints[1])))
        self.vecs += [np.zeros(6) for _ in range(used)] + ([np.zeros(k)] if k else [])
        if x is not None:
            self.vecs[vec] = x
        jsrc = ip = rot = place = -1
        cols: list[int] = []
        tail: list[int] = []
        if transposed is not None:
            jsrc, self.mats[mat] = TRANSPOSED, transposed
        if jacobian is not None:
            JT, cols, p = jacobian
            jsrc = self._slot(self.mats, JT)
            ip = self._slot(self.vecs, p)
            cols = [int(c) for c in cols]
        if rotation is not None:
            rot = len(self.mats)
            self.mats += [rotation[0], rotation[1]]
        self.velocity_pass |= self.order == 2 and jdot is None
        ends = [] if jdot is None else [int(e) for e in jdot]
        if placement is not None:
            fid, RiT, pi, P, RfT = placement
            place = len(self.mats)
            self.mats += [RiT, np.ascontiguousarray(P, dtype=float), RfT]
            tail = [self._slot(self.vecs, pi)]
            self.placed.add(int(fid))
        ixd = len(self._ints) + 6
        xslot = vec + used if k else -1
        self._ints += [FRAME, row, dim, k, mat, vec, xslot, jsrc, ip, rot, len(cols), place,
                       int(jdot is not None), *rows, *xrows, *cols, *ends, *tail, -1]
        self.vecs.append(np.zeros(dim))  # (the extra command's, bound to the entry while it has one)
        #: where the last frame entry's ``ixd`` (or :data:`HARMONIC`) and extra command slot (or -1) are in
        #: :attr:`ints`, and the extra command's vecs slot
        self.switches = (ixd, len(self._ints) - 1, len(self.vecs) - 1)
        return self._gains(kp, kd, k + 2 * dim + 2), mat, vec, rot, xslot

    @staticmethod
    def _slot(arrays: list, a: np.ndarray) -> int:
        """The slot of ``a`` in ``arrays`` (added once: tasks share pinocchio's joint Jacobians, a frame task's position
        is its ``x``)."""
        for i, b in enumerate(arrays):
            if b is a:
                return i
        arrays.append(a)
        return len(arrays) - 1

    def set_box(self, kind: int, limits: np.ndarray, idx: np.ndarray, dt: float) -> None:
        """With :data:`SNS`: the kernel computes the box (``kind``) from ``limits`` (rows ``q_min, q_max, v_max, a_max,
        2 a_max, a_max dt``) and ``idx`` (``q`` and ``v`` indices, 2 x joints), as :meth:`JointLimits.kernel_box`."""
        if self.solve != SNS or kind not in (BOX_VELOCITY, BOX_ACCELERATION) or limits.shape != (6, idx.shape[1]):
            raise ValueError("set_box: an SNS program, BOX_VELOCITY or BOX_ACCELERATION, 6 x k limits, 2 x k indices")
        self.mats.append(np.ascontiguousarray(limits, dtype=float))
        self._box = [kind, len(self.mats) - 1, idx.shape[1], *np.asarray(idx, dtype=np.int64).ravel()]
        self._dt = float(dt)

    @staticmethod
    def buffer_size(m: int, n: int, solve: int) -> int:
        """Length of the kernel's ``buf``: ``J``, ``b``, ``x0``, ``x``, and with :data:`SNS` the box ``lo``, ``up``,
        the loop's scratch (``3 x n``) and the solve's info (:meth:`sns_info`, ``n + 4``)."""
        return m * n + m + (8 * n + 4 if solve == SNS else 2 * n)

    def build(self) -> Program:
        """Pack the entries and the address table (then slots change only by :meth:`bind_mat`, :meth:`bind_vec`)."""
        if self.solve == SNS:  # the loop's scratch (n joints), the box: source, slot, joints, indices; its dt
            self._ints += [0] * self._ints[1] + self._box
            self._floats += [self._dt]
        self._ints[7] = len(self._ints)
        self._ints += [0] * (3 * len(self.mats))
        self._ints[8] = len(self._ints)
        self._ints += [0] * (2 * len(self.vecs))
        self.ints = np.array(self._ints, dtype=np.int64)
        for i, a in enumerate(self.mats):
            self.bind_mat(i, a)
        for i, a in enumerate(self.vecs):
            self.bind_vec(i, a)
        self.floats = np.array(self._floats, dtype=float)
        #: the caller writes the SNS box into the buffer before each call (no :meth:`set_box`)
        self.box_given = self._box[0] == BOX_GIVEN
        return self

    def __reduce_ex__(self, protocol):  # (copy.deepcopy asks it too)
        raise TypeError("a fused-step program holds the addresses of its arrays: it cannot be copied nor pickled (a "
                        "controller copies and pickles without its compiled step)")

    def bind_mat(self, slot: int, a: np.ndarray) -> None:
        """Point slot ``slot`` of :attr:`mats` at ``a`` (a float64, C-contiguous matrix; the program keeps it alive)."""
        self.mats[slot] = _checked(a, 2)
        at = self.ints[7] + 3 * slot
        self.ints[at: at + 3] = a.__array_interface__["data"][0], a.shape[0], a.shape[1]

    def bind_vec(self, slot: int, a: np.ndarray) -> None:
        """Point slot ``slot`` of :attr:`vecs` at ``a`` (a float64, C-contiguous vector; kept alive)."""
        self.vecs[slot] = _checked(a, 1)
        at = self.ints[8] + 2 * slot
        self.ints[at: at + 2] = a.__array_interface__["data"][0], a.shape[0]

    def sns_info(self, buf: np.ndarray) -> dict:
        """The SNS solver's info from (a copy of) the kernel's ``buf`` after a solve, as the readable step's."""
        m, n = self._ints[0], self._ints[1]
        scale, nsat, iterations, _, *joints = buf[m * n + m + 7 * n:].tolist()
        return {"scale": scale, "saturated": [int(j) for j in joints[: int(nsat)]], "iterations": int(iterations)}


def kernel(solve: int = TPM, tall: bool = False, svd: bool = False):
    """The kernel ``(buf, ints, floats, q, v) -> status`` of a :class:`Program` built with ``solve`` (``tall``: ``m >
    n``; ``svd``: after :data:`PIVOT_SVD`), compiled or loaded on first use (None: no numba): the rows, their
    finiteness, then the solve and ``x``'s finiteness (``buf = [J, b, x0, x, (lo, up, ...)]``)."""
    tall = bool(tall) and solve == TPM
    svd = bool(svd) and solve == TPM and not tall
    return _KERNELS.get((solve, tall, svd)) or _build(solve, tall, svd)

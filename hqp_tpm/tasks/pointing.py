"""Relaxed pointing task of papers/000: equality (16)-(19) or cone inequality (21), in the stack while ``e > 0``.

``p_rp = z_d^T z_e`` (``z_e`` the frame's z axis), ``J_rp = z_d^T S(z_e)^T J_O`` (19), ``Jdot_rp qd = z_d^T (alpha x
z_e + omega x (omega x z_e))``, ``e = cos(alpha_d) - p_rp``. ``drift_limit``: docs/pointing_drift.md."""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from hqp_tpm.errors import ParameterError, ShapeError, shown
from hqp_tpm.references.trajectories import Constant
from hqp_tpm.robot import _compiled
from hqp_tpm.robot.model import Robot
from hqp_tpm.robot.spatial import cross, cross3
from hqp_tpm.robot.state import LWA, State
from hqp_tpm.solvers.levels import Level
from hqp_tpm.tasks import _compiled_rows
from hqp_tpm.tasks.base import Gains, Task

#: The cone (21) as a one-row inequality level: no upper bound, active while the axis is outside.
_NO_UPPER = np.array([np.inf])
_ACTIVE, _INACTIVE = np.array([True]), np.array([False])
for _a in (_NO_UPPER, _ACTIVE, _INACTIVE):
    _a.flags.writeable = False
#: What the attributes :class:`Pointing` checks on assignment take (:meth:`Pointing.__setattr__`).
_TAKES = {"alpha_d": "a number in [0, pi) radians", "drift_limit": "a finite number > 0 (rad/s^2), or None (no limit)",
          "axis": "no value (a method): build a new Pointing (or assign z_d)",
          "target": "no value (cos(alpha_d)): assign alpha_d"}


class Pointing(Task):
    """Point the frame's z axis at ``axis`` within the cone half-angle ``alpha_d`` (radians, in ``[0, pi)``): the cone
    (21) by default, the equality (16) with ``inequality=False``."""

    dim = 1

    def __init__(self, robot: Robot, frame: str, axis, alpha_d: float, gains: Gains | None = None, *,
                 inequality: bool = True, name: str | None = None, drift_limit: float | None = None):
        self.frame = frame
        self.fid = robot.frame_id(frame)
        object.__setattr__(self, "z_d", unit_axis(axis, name or frame + "_pointing"))  # (later: __setattr__)
        self._column = None  # (state, view of its frame rotation's z column), see pointing_error
        self.inequality = inequality
        super().__init__(name or f"{frame}_pointing", [1.0], gains)
        self.alpha_d, self.drift_limit = alpha_d, drift_limit  # (checked by __setattr__; alpha_d sets the reference)

    def __setattr__(self, name: str, value) -> None:
        """The attributes of :data:`_TAKES` checked, used from the next step on (``alpha_d``: and the reference)."""
        if name == "z_d":
            value = unit_axis(value, self.name)
        elif name in _TAKES and (value is not None or name != "drift_limit"):
            real = isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)
            x = float(value) if real else np.nan
            if name in ("axis", "target") or not (0.0 <= x < np.pi if name == "alpha_d" else 0.0 < x < np.inf):
                raise ParameterError(f"task {self.name!r}: {name} = {shown(value)} refused: it takes {_TAKES[name]}")
            value = x
            if name == "alpha_d":  # (pointing_error's cos(alpha_d), and the reference's)
                object.__setattr__(self, "_cos", float(np.cos(x)))
                object.__setattr__(self, "trajectory", Constant(value=[np.cos(x)]))
        object.__setattr__(self, name, value)

    def __getstate__(self) -> dict:
        """Copied and pickled without its kept view of a state's rotation."""
        return {**self.__dict__, "_column": None}

    def axis(self, state: State) -> np.ndarray:
        return state.rotation(self.fid)[:, 2]

    def value(self, state: State) -> np.ndarray:
        """``p_rp = z_d^T z_e`` (16)."""
        return np.array([dot3(self.z_d, self.axis(state))])

    def jacobian(self, state: State) -> np.ndarray:
        z_e = self.axis(state)
        # z_d^T S(z_e)^T J_O = (z_e x z_d)^T J_O, since S(z_e)^T w = w x z_e                  eq. (19)
        c, J_O = cross(z_e, self.z_d), state.jacobian(self.fid)[3:]
        # summed left to right, as the compiled row does (a BLAS kernel may fuse them, FMA)
        return (c[0] * J_O[0] + c[1] * J_O[1] + c[2] * J_O[2]).reshape(1, -1)

    def jdot_qdot(self, state: State) -> np.ndarray:
        z_e = self.axis(state).tolist()
        omega = state.velocity(self.fid)[3:].tolist()
        alpha = state.jdot_qdot(self.fid)[3:].tolist()
        a, w = cross3(alpha, z_e), cross3(omega, cross3(omega, z_e))  # z_d^T (alpha x z_e + omega x (omega x z_e))
        return np.array([self.z_d.dot(np.array([a[0] + w[0], a[1] + w[1], a[2] + w[2]]))])

    def command(self, state: State, t: float, order: int, extra=None, J: np.ndarray | None = None) -> np.ndarray:
        """:meth:`Task.command`; with a ``drift_limit`` at acceleration level, the drift is not cancelled (added back)
        while ``|Jdot_rp qd| > drift_limit ||J_rp||``."""
        J = self.jacobian(state) if J is None else J
        b = super().command(state, t, order, extra, J)
        if order == 2 and self.drift_limit is not None:
            jdq = self.jdot_qdot(state)
            if drift_left_out(jdq[0], J[0], self.drift_limit):
                b = b + jdq
        return b

    def pointing_error(self, state: State) -> float:
        """``e = cos(alpha_d) - p_rp``: positive while the axis is outside the cone."""
        # cos(alpha_d) - value(state)[0] without the array (asked every step), z_e read through a view of the
        # rotation pinocchio updates in place once the state is complete
        c = self._column
        if c is not None and c[0] is state and not state._partial:
            return self._cos - dot3(self.z_d, c[1])
        z_e = state.rotation(self.fid)[:, 2]
        views = state.frame_views(self.fid)
        self._column = None if views is None else (state, views[1][:, 2])
        return self._cos - dot3(self.z_d, z_e)

    def is_active(self, state: State) -> bool:
        """Equality: always; inequality (21): while ``e > 0``."""
        return (not self.inequality) or self.pointing_error(state) > 0.0

    def level(self, state: State, t: float, order: int, extra=None) -> Level:
        if not self.inequality:
            return super().level(state, t, order, extra)
        J = self.jacobian(state)
        return self.cone_level(J, self.command(state, t, order, extra, J), self.pointing_error(state) > 0.0)

    def cone_level(self, J: np.ndarray, b: np.ndarray, active: bool) -> Level:
        """The inequality (21) as a level: ``J x >= b``, active while the pointing error is positive."""
        return Level(J, lower=b, upper=_NO_UPPER, active=_ACTIVE if active else _INACTIVE, name=self.name,
                     defer_finite=True)

    def row_writer(self, state: State, order: int, J: np.ndarray, b: np.ndarray):
        """The planned step's ``write(t) -> pointing_error``: :meth:`jacobian`, :meth:`command` into ``J``, ``b``."""
        model, data, fid, none = state.model, state.data, self.fid, np.zeros(6)
        views = state.frame_views(fid)
        R = None if views is None else views[1]

        def write(t: float) -> float:
            if R is None or not _compiled.ENABLED:  # (this pinocchio returns copies, or the kernels are off)
                Jt = self.jacobian(state)
                J[...] = Jt
                b[...] = self.command(state, t, order, None, Jt)
                return self.pointing_error(state)
            ref, g, limit = self.trajectory.reference(t), self.gains, self.drift_limit
            Jf = pin.getFrameJacobian(model, data, fid, LWA)
            if order == 1:
                vel = acc = none
            else:
                vel = pin.getFrameVelocity(model, data, fid, LWA).vector
                acc = pin.getFrameClassicalAcceleration(model, data, fid, LWA).vector
            _compiled_rows.pointing_row(J, b, R, self.z_d, Jf, state.v, vel, acc, ref[0], ref[1], ref[2], g.kp, g.kd,
                                        order, np.inf if limit is None else limit)
            return self.pointing_error(state)  # (the cone's activity, as level decides it: from alpha_d)
        return write


def dot3(a: np.ndarray, b: np.ndarray) -> float:
    """``a . b`` of two 3-vectors summed left to right, as the compiled row does."""
    x, y = a.tolist(), b.tolist()
    return x[0] * y[0] + x[1] * y[1] + x[2] * y[2]


def drift_left_out(jdq: float, row: np.ndarray, limit: float) -> bool:
    """Whether the drift ``jdq`` of a pointing row ``row`` is left out of its command: ``jdq^2 > limit^2 ||row||^2``."""
    s = 0.0
    for x in row.tolist():
        s += x * x
    return jdq * jdq > limit * limit * s


def unit_axis(axis, task: str) -> np.ndarray:
    """``axis`` (the cone's axis ``z_d`` in the world frame) as a unit 3-vector, else the error naming ``task``."""
    try:
        z = np.asarray(axis, dtype=float)
    except (TypeError, ValueError):
        z = np.empty(0)
    if z.shape != (3,):
        raise ShapeError(f"Pointing {task!r}: axis {shown(axis)} has shape {z.shape}, expected a 3-vector (x, y, z) "
                         "in the world frame")
    norm = np.linalg.norm(z)
    if not np.isfinite(z).all() or norm < 1e-12:
        raise ParameterError(f"Pointing {task!r}: axis {shown(axis)} must be finite and non-zero")
    return z / norm

"""One state update per control step: kinematics, Jacobians and J-dot q-dot computed once, frame and CoM quantities
read lazily and cached until the next update. Details: docs/internals.md#state."""

from __future__ import annotations

import math

import numpy as np
import pinocchio as pin
from scipy.linalg.blas import ddot as _ddot

from hqp_tpm.errors import NonFiniteError, ShapeError
from hqp_tpm.robot import _compiled
from hqp_tpm.robot.model import Robot
from hqp_tpm.solvers.levels import all_finite

LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
_ARRAY, _FLOAT64 = np.ndarray, np.dtype(np.float64)
#: joint models whose configuration is a vector their velocity is added to (pinocchio's VectorSpace Lie group:
#: bounded revolute and prismatic joints); continuous joints (SO(2)), free flyers, spherical joints are not
_EUCLIDEAN = frozenset(f"JointModel{k}" for k in ("RX", "RY", "RZ", "PX", "PY", "PZ", "RevoluteUnaligned",
                                                  "PrismaticUnaligned"))


def _copy_finite(x: np.ndarray, out: np.ndarray) -> bool:
    """:func:`~hqp_tpm.robot._compiled.copy_finite` typed at its first call (:func:`~hqp_tpm.robot._compiled.typed`)."""
    global _copy_finite
    if not _compiled.ENABLED:  # (the caller's numpy path checks and copies)
        return False
    _copy_finite = kernel = _compiled.typed(_compiled.copy_finite, x, out)
    return kernel(x, out)


class State:
    """Robot state ``(q, v)`` at time ``t`` with its cached kinematic quantities."""

    def __init__(self, robot: Robot):
        self.robot = robot
        self.model = robot.model
        self.data = robot.model.createData()
        self.q = robot.neutral()
        self.v = np.zeros(robot.nv)
        self._shapes = ((self.model.nq,), (self.model.nv,))
        self.t = 0.0
        self._zero = np.zeros(robot.nv)
        self._cache: dict = {}
        self._partial = False
        self._joint_jacobians_T = None  # data.J.T (frame_jacobian_source)
        self._verified: dict = {}  # (what, frame) -> verify_source's answer
        self.updates = 0
        self._com_update = -1  # the update whose positions gave pinocchio's CoM and CoM Jacobian (update_positions)
        #: every joint adds its velocity to its configuration (``pin.integrate`` is ``q + dq``): see :meth:`integrate`
        self.euclidean = self.model.nq == self.model.nv and all(j.shortname() in _EUCLIDEAN
                                                                for j in self.model.joints[1:])

    def __repr__(self) -> str:
        return (f"State({self.robot.name!r}, t={self.t:.4f}, q={_short(self.q)}, v={_short(self.v)}, "
                f"updates={self.updates})")

    def check(self, q, v=None) -> tuple[np.ndarray, np.ndarray]:
        """Validated copies of ``q`` and ``v`` (shape and finiteness; ``v`` None: zeros), without touching the state."""
        qs, vs = self._shapes
        if type(q) is _ARRAY and type(v) is _ARRAY and q.dtype is _FLOAT64 and v.dtype is _FLOAT64 \
                and q.strides == v.strides == (8,):  # contiguous float64 vectors: checked and copied by the kernel
            q_new, v_new = np.empty(qs), np.empty(vs)
            if _copy_finite(q, q_new) and _copy_finite(v, v_new):
                return q_new, v_new
        q, v = np.array(q, dtype=float), np.zeros(vs) if v is None else np.array(v, dtype=float)
        if q.shape == qs and v.shape == vs and math.isfinite(_ddot(q, q) + _ddot(v, v)):
            return q, v  # (the common case: one sum of squares says both are finite)
        for arr, what, (size,) in ((q, "q", qs), (v, "v", vs)):
            if arr.size != size:
                raise ShapeError(f"{what} has {arr.size} entries, the robot {self.robot.name!r} has n{what} = {size}")
        for arr, what in ((q, "q"), (v, "v")):
            if not all_finite(arr):
                raise NonFiniteError(f"{what} holds non-finite values at {np.flatnonzero(~np.isfinite(arr)).tolist()}")
        return q.reshape(-1), v.reshape(-1)

    def update(self, q, v, t: float = 0.0, *, validate: bool = True, frames=None, velocities: bool = True) -> State:
        """Forward kinematics (positions, velocities, J-dot q-dot) and joint Jacobians, once. ``validate=False`` skips
        :meth:`check`; ``frames`` (ids) places only those frames, ``velocities=False`` runs the position pass only (the
        first method that needs the rest computes it)."""
        if validate:
            q, v = self.check(q, v)
        self.q, self.v, self.t = q, v, float(t)
        model, data = self.model, self.data
        if velocities:
            pin.forwardKinematics(model, data, q, v, self._zero)
            pin.computeJointJacobians(model, data)  # from the placements computed just above
        else:  # the placements and the joint Jacobians in one pass (the same operations)
            pin.computeJointJacobians(model, data, q)
        if frames is None:
            pin.updateFramePlacements(model, data)
        else:
            for fid in frames:
                pin.updateFramePlacement(model, data, fid)
        self._partial = frames is not None or not velocities
        self._cache.clear()
        self.updates += 1
        return self

    def update_positions(self, q, v, t: float, frames, com: bool = False) -> State:
        """``update(q, v, t, validate=False, frames=frames, velocities=False)`` in fewer Python operations; ``com``:
        also the CoM and its Jacobian (:meth:`com_views`) in the same pass."""
        self.q, self.v, self.t = q, v, t
        if com:
            pin.jacobianCenterOfMass(self.model, self.data, q, False)
            self._com_update = self.updates + 1
        else:
            pin.computeJointJacobians(self.model, self.data, q)
        for fid in frames:
            pin.updateFramePlacement(self.model, self.data, fid)
        self._partial = True
        self._cache.clear()
        self.updates += 1
        return self

    def _complete(self) -> None:
        """The kinematics a partial :meth:`update` left out (velocities, J-dot q-dot, every frame), if it did."""
        if self._partial:
            pin.forwardKinematics(self.model, self.data, self.q, self.v, self._zero)
            pin.updateFramePlacements(self.model, self.data)
            self._partial = False

    # -- frames --------------------------------------------------------------------------------
    def placement(self, fid: int) -> pin.SE3:
        self._complete()
        return self.data.oMf[fid]

    def position(self, fid: int) -> np.ndarray:
        return self.placement(fid).translation

    def rotation(self, fid: int) -> np.ndarray:
        return self.placement(fid).rotation

    def jacobian(self, fid: int) -> np.ndarray:
        """6 x nv frame Jacobian, world-aligned at the frame origin (linear rows first)."""
        key = ("J", fid)
        if key not in self._cache:
            self._cache[key] = pin.getFrameJacobian(self.model, self.data, fid, LWA)
        return self._cache[key]

    def jdot_qdot(self, fid: int) -> np.ndarray:
        """6-vector J-dot q-dot of the frame: classical linear and angular acceleration at zero q-ddot."""
        key = ("Jdqd", fid)
        if key not in self._cache:
            self._complete()
            self._cache[key] = pin.getFrameClassicalAcceleration(self.model, self.data, fid, LWA).vector.copy()
        return self._cache[key]

    def velocity(self, fid: int) -> np.ndarray:
        """6-vector frame velocity (linear, angular), world-aligned."""
        self._complete()
        return pin.getFrameVelocity(self.model, self.data, fid, LWA).vector

    def frame_views(self, fid: int) -> tuple[np.ndarray, np.ndarray] | None:
        """Position and rotation of frame ``fid`` as views of pinocchio's data (updated in place by every
        :meth:`update`); None if this pinocchio returns copies."""
        M = self.data.oMf[fid]
        views = M.translation, M.rotation
        again = self.data.oMf[fid]
        return views if _same_memory(views, (again.translation, again.rotation)) else None

    def frame_placement_source(self, fid: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
        """``(RiT, pi, P, RfT)`` for ``_compiled.frame_placement`` (views of pinocchio's data, ``P`` the frame's
        placement in its joint); None if this pinocchio returns copies or :func:`verify_source` fails."""
        model, data = self.model, self.data
        frame = model.frames[fid]
        Mi, Mf = data.oMi[frame.parentJoint], data.oMf[fid]
        RiT, pi, RfT = Mi.rotation.T, Mi.translation, Mf.rotation.T
        again, f_again = data.oMi[frame.parentJoint], data.oMf[fid]
        if not (_same_memory((RiT, pi, RfT, Mf.translation),
                             (again.rotation.T, again.translation, f_again.rotation.T, f_again.translation))
                and RiT.flags.c_contiguous and RfT.flags.c_contiguous and RfT.flags.writeable
                and Mf.translation.flags.writeable and self._verified_source("placement", fid)):
            return None
        P = np.vstack((frame.placement.rotation, frame.placement.translation))
        return RiT, pi, P, RfT

    def frame_jacobian_source(self, fid: int) -> tuple[np.ndarray, np.ndarray] | None:
        """``(JT, cols)`` for ``_compiled.frame_jacobian`` (a view of ``data.J.T``, the frame's columns); None if this
        pinocchio returns a copy, the model has mimic joints or :func:`verify_source` fails."""
        model, data = self.model, self.data
        if getattr(model, "nvExtended", model.nv) != model.nv or not self._verified_source("jacobian", fid):
            return None  # (mimic joints: pinocchio's two-pass rule)
        JT = self._joint_jacobians_T  # (one array object for every task; a copied state's is a copy: made again)
        if JT is None or not _same_memory((JT,), (data.J.T,)):
            JT = data.J.T
            if not (JT.flags.c_contiguous and JT.flags.writeable and _same_memory((JT,), (data.J.T,))):
                return None
            self._joint_jacobians_T = JT
        return JT, _columns(model, fid)[0]

    def frame_jdot_source(self, fid: int) -> np.ndarray | None:
        """``ends`` for ``_compiled.frame_jdot_qdot`` (:func:`_columns`); None where :meth:`frame_jacobian_source` is
        None or :func:`verify_source` fails."""
        if self.frame_jacobian_source(fid) is None or not self._verified_source("jdot", fid):
            return None
        return _columns(self.model, fid)[1]

    def _verified_source(self, what: str, fid: int) -> bool:
        """:func:`verify_source`, once per state and frame."""
        if (what, fid) not in self._verified:
            self._verified[what, fid] = verify_source(self.model, what, fid)
        return self._verified[what, fid]

    # -- centre of mass --------------------------------------------------------------------------
    def com_views(self) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """CoM, CoM Jacobian and CoM J-dot q-dot as views of pinocchio's data, filled by :meth:`com_kinematics`; None
        if this pinocchio returns copies."""
        d = self.data
        views = d.com[0], d.Jcom, d.acom[0]
        return views if _same_memory(views, (d.com[0], d.Jcom, d.acom[0])) else None

    def com_kinematics(self, order: int) -> None:
        """Fill :meth:`com_views` from this update's kinematics (at ``order`` 2 also the CoM J-dot q-dot), with the
        calls of :meth:`com`; at order 1 nothing if :meth:`update_positions` computed them."""
        if order == 1 and self._com_update == self.updates:
            return
        if order == 2:
            self._complete()
            pin.centerOfMass(self.model, self.data, pin.KinematicLevel.ACCELERATION, False)
        pin.jacobianCenterOfMass(self.model, self.data, False)

    def _com_all(self):
        if "com" not in self._cache:  # from the kinematics of update() (no second forward pass)
            self.com_kinematics(2)
            d = self.data
            self._cache["com"] = (d.com[0].copy(), d.Jcom.copy(), d.acom[0].copy())
        return self._cache["com"]

    def com(self) -> np.ndarray:
        return self._com_all()[0]

    def com_jacobian(self) -> np.ndarray:
        return self._com_all()[1]

    def com_jdot_qdot(self) -> np.ndarray:
        return self._com_all()[2]

    # -- integration ---------------------------------------------------------------------------
    def integrate(self, q, v, a, dt: float, order: int) -> tuple[np.ndarray, np.ndarray]:
        """Next ``(q, v)``: velocity level ``q + v dt``; acceleration level ``q + v dt + a dt^2 / 2`` and ``v + a dt``
        (docs/setups.md, 'Initial state and run')."""
        if self.euclidean:  # pin.integrate is q + dq here: one kernel call, the same operations
            q_next, v_next = np.empty(q.shape[0]), np.empty(q.shape[0])
            _compiled.euclidean_step(q, v, a, dt, order, q_next, v_next)
            return q_next, v_next
        if order == 1:
            return pin.integrate(self.model, q, a * dt), a.copy()
        return pin.integrate(self.model, q, v * dt + 0.5 * a * dt * dt), v + a * dt


def _columns(model, fid: int) -> tuple[np.ndarray, np.ndarray]:
    """The velocity columns of the joints that support frame ``fid`` (its Jacobian's nonzero columns) and per column 1
    where it is its joint's last, else 0."""
    spans = [(model.idx_vs[j], model.nvs[j]) for j in model.supports[model.frames[fid].parentJoint]]
    cols = np.array([c for a, k in spans for c in range(a, a + k)], dtype=np.int64)
    return cols, np.array([int(c == a + k - 1) for a, k in spans for c in range(a, a + k)], dtype=np.int64)


#: How far the kernel's ``J-dot q-dot`` (:meth:`State.frame_jdot_source`) may be from pinocchio's on the probe state,
#: relative to ``max(1, |Jdot qd|)``: its sums round otherwise (~1e-15); a wrong formula is off by O(1).
JDOT_TOLERANCE = 1e-12


def verify_source(model, what: str, fid: int) -> bool:
    """Whether the compiled step may read and write pinocchio's memory by address for frame ``fid``: the kernel
    ``what`` (``"jacobian"``, ``"placement"``, ``"jdot"``) gives pinocchio's numbers through views on a probe state
    (docs/internals.md#state)."""
    data = model.createData()
    frame = model.frames[fid]
    try:
        JT, Mi, Mf = data.J.T, data.oMi[frame.parentJoint], data.oMf[fid]
        RiT, pi, RfT, pf = Mi.rotation.T, Mi.translation, Mf.rotation.T, Mf.translation
        v = 0.7 * np.sin(1.0 + np.arange(model.nv))  # a probe configuration: every joint moved
        q = pin.integrate(model, pin.neutral(model), v)
        pin.forwardKinematics(model, data, q, v, np.zeros(model.nv))
        pin.computeJointJacobians(model, data)
        M = pin.updateFramePlacement(model, data, fid)
        if what == "jdot":
            out = np.zeros(6)
            _compiled.frame_jdot_qdot(JT, *_columns(model, fid), v, np.array(M.translation), out)
            want = pin.getFrameClassicalAcceleration(model, data, fid, LWA).vector
            return bool(np.abs(out - want).max() <= JDOT_TOLERANCE * max(1.0, np.abs(want).max()))
        if what == "jacobian":
            S = np.zeros((6, model.nv))
            _compiled.frame_jacobian(JT, _columns(model, fid)[0], np.array(M.translation), S)
            return bool(np.array_equal(S, pin.getFrameJacobian(model, data, fid, LWA)))
        P = np.vstack((frame.placement.rotation, frame.placement.translation))
        R, p = np.empty((3, 3)), np.empty(3)
        _compiled.frame_placement(RiT, pi, P, R, p)
        if not (np.array_equal(R, M.rotation.T) and np.array_equal(p, M.translation)):
            return False
        RfT[...], pf[...] = 2.0 * R, 2.0 * p  # written through the views: pinocchio reads them back
        return bool(np.array_equal(data.oMf[fid].rotation, 2.0 * R.T) and np.array_equal(data.oMf[fid].translation,
                                                                                        2.0 * p))
    except (ValueError, TypeError):  # read-only or mismatched views of another pinocchio: its API every step
        return False


def _same_memory(a, b) -> bool:
    """Do the arrays ``a`` and ``b`` (pairwise) start at the same address (two reads of one stored value)?"""
    return all(x.__array_interface__["data"][0] == y.__array_interface__["data"][0] for x, y in zip(a, b, strict=True))


def _short(x: np.ndarray) -> str:
    """A vector as short text: its values (3 digits) when it is short, else its size and norm."""
    x = np.asarray(x, dtype=float)
    if x.size <= 8:
        return np.array2string(x, precision=3, suppress_small=True, separator=", ")
    return f"<{x.size} values, norm {np.linalg.norm(x):.3g}>"

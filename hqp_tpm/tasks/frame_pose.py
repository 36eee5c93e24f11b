"""Full pose of a frame (6 rows: position then orientation), e.g. a sole held on the ground."""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from hqp_tpm.errors import ParameterError, ShapeError, shown
from hqp_tpm.references.trajectories import Hold
from hqp_tpm.robot import _compiled
from hqp_tpm.robot.model import Robot
from hqp_tpm.robot.state import LWA, State
from hqp_tpm.tasks.base import Gains, ReferenceSlots, Task, kernel_placement

#: the target forms :class:`FramePose` accepts (named by its errors)
TARGET_FORMS = ("a pinocchio.SE3, a 4x4 homogeneous matrix [[R, p], [0, 0, 0, 1]], a pair (position 3-vector, "
                "3x3 rotation matrix), or None / 'hold' (the start pose)")


def placement_target(target, task: str) -> pin.SE3 | None:
    """The target placement of the pose task ``task`` from one of :data:`TARGET_FORMS` (None: the start pose)."""
    if target is None or (isinstance(target, str) and target == "hold"):
        return None
    if isinstance(target, pin.SE3):
        if not np.isfinite(target.homogeneous).all():
            raise ParameterError(f"FramePose {task!r}: target {target.homogeneous.tolist()} is not finite")
        rotation_matrix(target.rotation, f"FramePose {task!r}")  # (a pin.SE3 may hold any 3x3 matrix)
        return target.copy()
    what = f"an array of shape {target.shape}" if isinstance(target, np.ndarray) else shown(target)
    bad = ShapeError(f"FramePose {task!r}: target {what} is not a pose; expected {TARGET_FORMS}")
    if isinstance(target, str):
        raise bad
    try:
        if isinstance(target, (tuple, list)) and len(target) == 2:
            p, R = np.asarray(target[0], dtype=float), np.asarray(target[1], dtype=float)
        else:
            H = np.asarray(target, dtype=float)
            if H.shape != (4, 4):
                raise bad
            if not np.allclose(H[3], [0.0, 0.0, 0.0, 1.0]):
                raise ParameterError(f"FramePose {task!r}: the last row of the 4x4 target is {H[3].tolist()}, "
                                     f"expected [0, 0, 0, 1] (a homogeneous matrix)")
            p, R = H[:3, 3], H[:3, :3]
    except (TypeError, ValueError) as exc:
        if isinstance(exc, (ShapeError, ParameterError)):
            raise
        raise bad from exc
    if p.shape != (3,) or R.shape != (3, 3):
        raise bad
    if not np.isfinite(p).all():
        raise ParameterError(f"FramePose {task!r}: target position {p.tolist()} is not finite")
    return pin.SE3(rotation_matrix(R, f"FramePose {task!r}"), p.copy())


def rotation_matrix(R: np.ndarray, what: str) -> np.ndarray:
    """A copy of the 3x3 matrix ``R`` if it is a finite rotation matrix, else :class:`ParameterError` (``what``: the
    task, for the message)."""
    if not (np.isfinite(R).all() and np.allclose(R.T @ R, np.eye(3), atol=1e-6) and np.linalg.det(R) > 0):
        raise ParameterError(f"{what}: the target rotation {R.tolist()} is not a rotation matrix (finite, "
                             "orthonormal, determinant +1)")
    return R.copy()


_PROBE = pin.SE3.Identity()
_VIEW, _PROBE.translation = _PROBE.translation, np.ones(3)
#: assigning an ``SE3``'s translation (rotation) writes into the memory its earlier views read: a task keeps one target
#: placement (whose memory the fused kernel reads) and its ``target`` setter writes into it
IN_PLACE = bool(_VIEW[0] == 1.0)


class FramePose(Task):
    """``e = [p_d - p; log3(R_d R^T)]`` (world), ``J`` = 6-row world-aligned frame Jacobian.

    The target is a ``pin.SE3``, a 4x4 homogeneous matrix, a pair ``(position, rotation)`` (3-vector, 3x3 rotation
    matrix) or ``None``/``"hold"`` for the start pose; anything else raises :class:`ShapeError`."""

    dim = 6

    def __init__(self, robot: Robot, frame: str, target=None, gains: Gains | None = None, *, name: str | None = None):
        self.frame = frame
        self.fid = robot.frame_id(frame)
        self._M_target = placement_target(target, name or f"{frame}_pose")
        self._views = None  # (M, views of its translation and rotation transposed): the target setter writes there
        super().__init__(name or f"{frame}_pose", None, gains)
        self.trajectory = Hold()

    @property
    def target(self) -> pin.SE3 | None:
        """The target placement (a copy; None: the start pose, until the first step). Assigning one of
        :data:`TARGET_FORMS` but None/"hold" sets it, validated (:class:`ShapeError`, :class:`ParameterError` naming the
        value; a ``pin.SE3``'s rotation must be a rotation matrix); a valid ``pin.SE3`` is copied into the task's own
        placement (the one the compiled step reads)."""
        return None if self._M_target is None else self._M_target.copy()

    @target.setter
    def target(self, value) -> None:
        M = self._M_target
        if type(value) is pin.SE3 and M is not None and IN_PLACE:  # the common case: checked and copied in one call
            views = self._views
            if views is None or views[0] is not M:
                views = self._views = (M, M.translation, M.rotation.T)
            if _compiled.pose_into(value.homogeneous, views[1], views[2]):
                return
        if (M := placement_target(value, self.name)) is None:
            raise ParameterError(f"FramePose {self.name!r}: target {shown(value)} (the start pose) is a "
                                 f"constructor's target only; assign {TARGET_FORMS.split(', or None')[0]}")
        self._M_target = M

    def __getstate__(self) -> dict:
        return {**self.__dict__, "_views": None}  # (a copy's views are made again, of its own placement)

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
        slots; the kernel computes the frame Jacobian from the joint Jacobians and ``w = log3(R_d R^T)`` where the state
        gives views of them (:meth:`State.frame_jacobian_source`), else they are gathered here."""
        views = state.frame_views(self.fid)
        if views is None:
            return None
        model, data, fid = state.model, state.data, self.fid
        p, R = views
        g = self.gains
        RT = R.T  # a view, as R
        source = state.frame_jacobian_source(fid)
        inside = source is not None  # the frame Jacobian and the rotation error computed in the kernel
        ends = state.frame_jdot_source(fid) if inside and order == 2 else None  # (then Jdot qd too)
        at, mat, vec, rot = program.add_frame(row, range(6), range(3), g.kp, g.kd, x_d_vec=True, x=p,
                                              jacobian=(*source, p) if inside else None,
                                              rotation=(RT, np.eye(3)) if inside else None,  # (the target's: below)
                                              placement=kernel_placement(state, fid, inside), jdot=ends)
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
            if order == 2 and ends is None:
                jdq[...] = pin.getFrameClassicalAcceleration(model, data, fid, LWA).vector
        return gather

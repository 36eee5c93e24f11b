"""Full pose of a frame (6 rows: position then orientation), e.g. a sole held on the ground."""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from hqp_tpm.errors import ParameterError, ShapeError, shown
from hqp_tpm.robot import _compiled
from hqp_tpm.robot.model import Robot
from hqp_tpm.robot.state import State
from hqp_tpm.tasks.base import FrameRows, FrameTask, Gains

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
    """A copy of ``R`` if it is a finite 3x3 rotation matrix, else :class:`ParameterError` naming ``what``."""
    if not (np.isfinite(R).all() and np.allclose(R.T @ R, np.eye(3), atol=1e-6) and np.linalg.det(R) > 0):
        raise ParameterError(f"{what}: the target rotation {R.tolist()} is not a rotation matrix (finite, "
                             "orthonormal, determinant +1)")
    return R.copy()


def _pose_into(H: np.ndarray, pose: np.ndarray) -> bool:
    """:func:`~hqp_tpm.robot._compiled.pose_into`, typed at its first call (:func:`~hqp_tpm.robot._compiled.typed`)"""
    global _pose_into
    if not _compiled.ENABLED:
        return _compiled.pose_into(H, pose)
    _pose_into = kernel = _compiled.typed(_compiled.pose_into, H, pose)
    return kernel(H, pose)


class FramePose(FrameTask):
    """``e = [p_d - p; log3(R_d R^T)]`` (world), ``J`` = 6-row world-aligned frame Jacobian. The target is a
    ``pin.SE3``, a 4x4 homogeneous matrix, a pair ``(position, rotation)`` (3-vector, 3x3 rotation matrix) or
    ``None``/``"hold"`` for the start pose; anything else raises :class:`ShapeError`."""

    dim = 6

    def __init__(self, robot: Robot, frame: str, target=None, gains: Gains | None = None, *, name: str | None = None):
        self.frame = frame
        self.fid = robot.frame_id(frame)
        M = placement_target(target, name or f"{frame}_pose")
        # the target placement, written in place (the compiled step reads it): p_d, then R_d^T row by row
        self._pose = np.array([0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0])
        self._held = M is None
        if M is not None:
            self._p_d[:], self._R_d[:] = M.translation, M.rotation
        super().__init__(name or f"{frame}_pose", None, gains)  # (a Hold: the error is the placement's)

    @property
    def target(self) -> pin.SE3 | None:
        """The target placement (a copy; None: the start pose, until the first step). Assigning one of
        :data:`TARGET_FORMS` but None/"hold" sets it, validated (a refused target changes nothing)."""
        return None if self._held else pin.SE3(self._R_d.copy(), self._p_d.copy())

    @target.setter
    def target(self, value) -> None:
        if type(value) is pin.SE3 and _pose_into(value.homogeneous, self._pose):
            self._held = False  # (the common case: checked and copied in one call)
            return
        if (M := placement_target(value, self.name)) is None:
            raise ParameterError(f"FramePose {self.name!r}: target {shown(value)} (the start pose) is a "
                                 f"constructor's target only; assign {TARGET_FORMS.split(', or None')[0]}")
        self._p_d[:], self._R_d[:] = M.translation, M.rotation
        self._held = False

    _p_d = property(lambda self: self._pose[:3])  # (views of the placement: R_d Fortran-ordered)
    _R_d = property(lambda self: self._pose[3:].reshape(3, 3).T)

    def start(self, state: State) -> None:
        if self._held:
            M = state.placement(self.fid)
            self._p_d[:], self._R_d[:] = M.translation, M.rotation
            self._held = False
        self.trajectory.start(np.zeros(6))

    def value(self, state: State) -> np.ndarray:
        M = state.placement(self.fid)
        return np.concatenate([M.translation, pin.log3(M.rotation)])

    def error(self, state: State, x_d) -> np.ndarray:
        M = state.placement(self.fid)
        return np.concatenate([self._p_d - M.translation, pin.log3(self._R_d.dot(M.rotation.T))])

    def row_source(self) -> FrameRows:
        return FrameRows(self.fid, (0, 1, 2, 3, 4, 5), (0, 1, 2), self._p_d, self._R_d)

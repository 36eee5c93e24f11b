"""Joint limits of a robot as a per-step box on the command (joint velocity or acceleration); details:
docs/internals.md#joint-limits."""

from __future__ import annotations

import numpy as np

from hqp_tpm.errors import ParameterError
from hqp_tpm.robot.joint_boxes import BoxLimits
from hqp_tpm.robot.model import Robot
from hqp_tpm.robot.state import State


class JointLimits:
    """``box(state, t) -> (lower, upper)`` on ``qd`` (``order`` 1) or ``qdd`` (2), one entry per velocity column
    (free-flyer columns unbounded). ``command_rate`` (order 1 only): the box also bounds the change from the previous
    command, ``v +- a_max dt`` (:func:`~hqp_tpm.robot.joint_boxes.command_rate_box`); off: papers/002's box."""

    def __init__(self, robot: Robot, *, order: int, dt: float, position: bool = True, velocity: bool = True,
                 acceleration_limit: float = 50.0, velocity_scale: float = 1.0, command_rate: bool = False):
        if order not in (1, 2):
            raise ParameterError(f"JointLimits: order must be 1 (a box on the joint velocity) or 2 (on the joint "
                                 f"acceleration), got {order!r}")
        if command_rate and order != 1:
            raise ParameterError(f"command_rate = {command_rate!r} needs order 1 (velocity level), got order "
                                 f"{order!r}: at acceleration level the box bounds the command itself (|qdd| <= a_max)")
        self.robot, self.order, self.dt = robot, order, float(dt)
        #: the box also bounds the command's change from the previous step (``a_max dt``)
        self.command_rate = bool(command_rate)
        m = robot.model
        self.cols = np.array([m.joints[j].idx_v for j in range(1, m.njoints) if m.joints[j].nv == 1], dtype=int)
        self.qidx = np.array([m.joints[j].idx_q for j in range(1, m.njoints) if m.joints[j].nv == 1], dtype=int)
        lo, up = robot.position_limits()
        self.q_min = lo[self.cols] if position else np.full(self.cols.size, -np.inf)
        self.q_max = up[self.cols] if position else np.full(self.cols.size, np.inf)
        v = robot.velocity_limits()[self.cols] * float(velocity_scale)
        self.v_max = v if velocity else np.full(self.cols.size, 1e6)
        self.a_max = np.full(self.cols.size, float(acceleration_limit))
        self.limits = BoxLimits(self.q_min, self.q_max, self.v_max, self.a_max, self.dt)  # validated once
        self.velocity_limits = np.full(robot.nv, np.inf)
        self.velocity_limits[self.cols] = self.v_max
        #: the joints' q and v indices (the kernels' ``idx``)
        self.kernel_indices = np.ascontiguousarray(np.vstack([self.qidx, self.cols]).astype(np.int64))
        #: the limits' rows (:attr:`BoxLimits.rows`) for a kernel that computes the box inside another (the compiled
        #: SNS step); None when a position limit is infinite or an ``a_max`` not positive (the caller gives the box)
        self.kernel_limits = (self.limits.rows if self.cols.size and np.isfinite(self.limits.rows[:2]).all()
                              and (self.a_max > 0).all() else None)

    def __call__(self, state: State, t: float) -> tuple[np.ndarray, np.ndarray]:
        """The box at ``state`` (new arrays, one entry per velocity column)."""
        lo, up = np.full(self.robot.nv, -np.inf), np.full(self.robot.nv, np.inf)
        self.kernel_box(state.q, state.v, lo, up)
        return lo, up

    def kernel_box(self, q: np.ndarray, v: np.ndarray, lo: np.ndarray, up: np.ndarray) -> None:
        """The box at ``(q, v)`` into ``lo``, ``up`` (their limited columns; the others are not written)."""
        self.limits.box_into(q, v, lo, up, self.order, self.command_rate, self.kernel_indices)

"""Position of a frame origin (possibly only some axes), world frame."""

from __future__ import annotations

import numpy as np

from hqp_tpm.robot.model import Robot
from hqp_tpm.robot.state import State
from hqp_tpm.tasks.base import FrameRows, FrameTask, Gains, row_selector, select_axes, trajectory_target


class FramePosition(FrameTask):
    """``x = p_frame[axes]``, ``J = J_v[axes]``, ``Jdot qd`` = classical linear acceleration at zero q-ddot."""

    target = trajectory_target

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

    def row_source(self) -> FrameRows:
        rows = tuple(int(r) for r in self.rows)
        return FrameRows(self.fid, rows, rows)

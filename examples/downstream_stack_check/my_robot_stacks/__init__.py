"""A stack of our own: the tip of the planar 5-link arm at a height, the third link's tip at a y, a posture."""

from __future__ import annotations

import numpy as np

from hqp_tpm import FramePosition, Gains, Posture, Robot, Stack, State, Task


class TipHeight(Task):
    """Height (y) of the tip above a sloped floor ``y = slope * x``: ``h = y - slope * x``."""

    dim = 1

    def __init__(self, robot: Robot, frame: str = "planar5_ee", target=0.5, slope: float = 0.2,
                 gains: Gains | None = None):
        self.fid = robot.frame_id(frame)
        self.normal = np.array([-slope, 1.0, 0.0])
        super().__init__("tip_height", [target], gains or Gains(kp=2.0))

    def value(self, state: State) -> np.ndarray:
        return np.array([self.normal @ state.position(self.fid)])

    def jacobian(self, state: State) -> np.ndarray:
        return (self.normal @ state.jacobian(self.fid)[:3]).reshape(1, -1)

    def jdot_qdot(self, state: State) -> np.ndarray:
        return np.array([self.normal @ state.jdot_qdot(self.fid)[:3]])


def robot() -> Robot:
    return Robot.load("planar5")


def tasks(r: Robot) -> list[Task]:
    return [TipHeight(r), FramePosition(r, "planar5_tip_3", [0.4], Gains(kp=1.0), axes="y"),
            Posture(r, np.zeros(r.nv), Gains(kp=0.5))]


def levels_at(r: Robot, tasks_: list[Task], q, v, t: float = 0.0, order: int = 1):
    """The solver levels of our stack at ``(q, v)``."""
    state = State(r).update(q, v, t)
    for task in tasks_:
        task.start(state)
    return Stack.of(*tasks_).to_levels(state, t, order)

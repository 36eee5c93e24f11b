"""Interaction-force task of papers/003, Sec. 4.3: ``sigma_f = R_s f^s``, desired 0, Jacobian ``J_p``."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from hqp_tpm.errors import NonFiniteError, ShapeError
from hqp_tpm.robot.model import Robot
from hqp_tpm.robot.state import State
from hqp_tpm.tasks.base import FrameTask, Gains

ForceSource = Callable[[State, float], np.ndarray]


def no_force(state: State, t: float) -> np.ndarray:
    """The default source: nobody touches the sensor."""
    return np.zeros(3)


class Force(FrameTask):
    """Zero-force task: the EE moves along the force ``f^s = source(state, t)`` the operator applies on the sensor (in
    its frame ``frame``, the flange; the sensor-tip offset neglected, as in the paper). The error ``sigma_f = R_s f^s``
    makes the command ``J_p qd = Lambda_f sigma_f`` an admittance with damping ``1/Lambda_f``."""

    dim = 3
    _sel = slice(None, 3)

    def __init__(self, robot: Robot, frame: str, source: ForceSource | None = None, gains: Gains | None = None,
                 *, target=(0.0, 0.0, 0.0), name: str = "force"):
        self.frame = frame
        self.fid = robot.frame_id(frame)
        self.source: ForceSource = source or no_force
        super().__init__(name, target, gains)

    def sensor_force(self, state: State) -> np.ndarray:
        """``f^s`` from the source, validated."""
        f = np.asarray(self.source(state, state.t), dtype=float)
        if f.shape != (3,):
            raise ShapeError(f"task {self.name!r}: force source returned shape {f.shape}, expected (3,)")
        if not np.isfinite(f).all():
            raise NonFiniteError(f"task {self.name!r}: force source returned non-finite values {f}")
        return f

    def value(self, state: State) -> np.ndarray:
        return state.rotation(self.fid) @ self.sensor_force(state)  # sigma_f = R_s f^s

    def error(self, state: State, x_d: np.ndarray) -> np.ndarray:
        """``sigma_f - f_d``: the EE moves along the applied force until it vanishes."""
        return self.value(state) - x_d

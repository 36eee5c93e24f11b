"""The admittance-control baseline of papers/003 (Sec. 6, after Siciliano et al. 2009).

The operator force ``f`` (world frame) drives a reference ``x_r`` for the flange position through
``M xdd_r + D xd_r + K (x_r - x_0) = f`` (``M = I``, ``D = 100 I``, ``K = 0.001 I``; ``x_0`` the start
position), integrated once per step (semi-implicit Euler, period T). The joints follow with the
(damped, as the scenario's ``lambda_max`` says) pseudo-inverse of one level, no null-space use:

    [J_p; Sigma J_o] qd = [xd_r + k_p (x_r - p); Lambda_o sigma_o]

The 2-D orientation rows (10) keep the flange facing down as in the hierarchical runs (the
operator of the paper holds it that way too), so both schemes control the same five DOF and
differ only in what the remaining two do: nothing here, the performance tasks there.
``k_p`` (default 5.5, the position gain of the paper) closes the loop on the reference; with
``k_p = 0`` the reference velocity is mapped open loop. ``probe`` records what the switching policy
records (``sigma_m``, ``sigma_l``, joint margins, the operator force) plus ``admittance_lag``
(``||x_r - p||``, m).
"""

from __future__ import annotations

import numpy as np

from hqp_tpm.control.policy import SceneItems, StackPolicy
from hqp_tpm.control.stack import Stack
from hqp_tpm.errors import ParameterError, ScenarioError
from hqp_tpm.policies.switching import ComanipulationIndices
from hqp_tpm.references.operator import Operator
from hqp_tpm.robot.model import Robot
from hqp_tpm.robot.state import State
from hqp_tpm.solvers.levels import Level
from hqp_tpm.tasks import JointLimit, Manipulability
from hqp_tpm.tasks.base import Gains, Task


class AdmittancePosition(Task):
    """Flange position following the admittance reference ``x_r``: ``b = xd_r + k_p (x_r - p)``."""

    dim = 3

    def __init__(self, robot: Robot, frame: str, operator: Operator | None, *, dt: float, mass: float = 1.0,
                 damping: float = 100.0, stiffness: float = 0.001, kp: float = 5.5, name: str = "admittance"):
        for what, v in (("mass", mass), ("damping", damping), ("stiffness", stiffness), ("kp", kp), ("dt", dt)):
            if not (np.isfinite(v) and v >= 0) or (what in ("mass", "dt") and v == 0):
                raise ParameterError(f"admittance {what} = {v!r} must be finite and > 0 (>= 0 for damping, "
                                 "stiffness, kp)")
        self.frame, self.fid, self.operator = frame, robot.frame_id(frame), operator
        self.dt, self.mass, self.damping, self.stiffness = float(dt), float(mass), float(damping), float(stiffness)
        super().__init__(name, "hold", Gains(kp=kp))
        self.x0 = self.x_r = self.xd_r = np.zeros(3)

    def start(self, state: State) -> None:
        super().start(state)
        self.x0 = self.value(state).copy()
        self.x_r, self.xd_r = self.x0.copy(), np.zeros(3)

    def advance(self, state: State, t: float) -> None:
        """One period of ``M xdd_r + D xd_r + K (x_r - x_0) = f`` (after the operator's update)."""
        f = self.operator.force if self.operator is not None else np.zeros(3)
        xdd = (f - self.damping * self.xd_r - self.stiffness * (self.x_r - self.x0)) / self.mass
        self.xd_r = self.xd_r + self.dt * xdd
        self.x_r = self.x_r + self.dt * self.xd_r

    def value(self, state: State) -> np.ndarray:
        return state.position(self.fid)

    def error(self, state: State, x_d: np.ndarray) -> np.ndarray:
        return self.x_r - self.value(state)

    def reference(self, t: float):
        return self.x_r, self.xd_r, np.zeros(3)

    def jacobian(self, state: State) -> np.ndarray:
        return state.jacobian(self.fid)[:3]

    def jdot_qdot(self, state: State) -> np.ndarray:
        return state.jdot_qdot(self.fid)[:3]

    def level(self, state: State, t: float, order: int, extra=None) -> Level:
        if order != 1:
            raise ScenarioError("the admittance baseline works at velocity level only")
        return super().level(state, t, order, extra)


class Admittance(StackPolicy):
    """One level ``[admittance position; orientation]``, solved by the pseudo-inverse (no null space)."""

    channels = (*ComanipulationIndices.channels, "admittance_lag")

    def __init__(self, robot: Robot, admittance: AdmittancePosition, orientation: Task | None,
                 manipulability: Manipulability, joint_limit: JointLimit, operator: Operator | None,
                 sigma_m_bar: float = 1.5):
        self.admittance, self.orientation, self.operator = admittance, orientation, operator
        self.manipulability, self.joint_limit = manipulability, joint_limit
        self.sigma_m_bar = sigma_m_bar
        self.stack = Stack([tuple(t for t in (admittance, orientation) if t is not None)])
        self.indices = ComanipulationIndices(manipulability, joint_limit, operator)
        self.thresholds = {"sigma_m": {"sigma_bar_m": sigma_m_bar}}

    def tasks(self) -> list[Task]:
        return [t for t in (self.admittance, self.orientation, self.manipulability, self.joint_limit) if t]

    def scene(self) -> SceneItems:
        return SceneItems(operator=self.operator)

    def update(self, state: State, t: float) -> None:
        """The operator's force, then one period of the admittance reference."""
        if self.operator is not None:
            self.operator.update(state, t)
        self.admittance.advance(state, t)

    def snapshot(self):
        """The admittance reference ``x_r``, ``xd_r`` and the operator."""
        a = self.admittance
        return a.x_r, a.xd_r, self.operator.snapshot() if self.operator is not None else None

    def restore(self, snapshot) -> None:
        self.admittance.x_r, self.admittance.xd_r, op = snapshot
        if self.operator is not None:
            self.operator.restore(op)

    def __call__(self, state: State, t: float) -> Stack:
        return self.stack

    def probe(self, ctrl, res) -> dict:
        lag = float(np.linalg.norm(self.admittance.x_r - self.admittance.value(ctrl.state)))
        return {**self.indices.probe(ctrl, res), "admittance_lag": lag}

    def summary(self, arrays: dict) -> dict:
        return {**self.indices.summary(arrays, self.sigma_m_bar),
                "admittance_lag_max": float(arrays["admittance_lag"].max())}

"""Torques from the controller's command, computed from the measured state with the controller's own model.

Acceleration level: :class:`InverseDynamics`, ``tau = rnea(q, v, qdd_cmd)`` (pinocchio's recursive
Newton-Euler: ``M(q) qdd + C(q, v) v + g(q)``). Velocity level: :class:`JointImpedance`, a computed-torque PD
on the integrated command: ``q_ref <- q_ref + qd_cmd T`` and ``tau = rnea(q, v, kp (q_ref - q) + kd (qd_cmd -
v))`` (``kp`` in 1/s², ``kd`` in 1/s: the joint error obeys ``e'' + kd e' + kp e = 0`` when the model is right).
Both see only what a real controller sees: the measured ``(q, v)`` and the controller's model, not the plant's
armature, damping or friction.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin


class InverseDynamics:
    """``tau = rnea(q, v, a)`` of the controller's model (an acceleration-level command ``a``)."""

    def __init__(self, model: pin.Model) -> None:
        self.model, self.data = model, model.createData()

    def reset(self, q: np.ndarray, v: np.ndarray) -> None:
        """Nothing to reset (no internal state)."""

    def __call__(self, q: np.ndarray, v: np.ndarray, a: np.ndarray) -> np.ndarray:
        return pin.rnea(self.model, self.data, q, v, a).copy()


class JointImpedance:
    """Computed-torque PD around the integrated velocity command (a velocity-level command ``qd``)."""

    def __init__(self, model: pin.Model, dt: float, kp: float = 400.0, kd: float = 40.0) -> None:
        self.model, self.data, self.dt, self.kp, self.kd = model, model.createData(), float(dt), kp, kd
        self.q_ref = pin.neutral(model)

    def reset(self, q: np.ndarray, v: np.ndarray) -> None:
        """Start the reference at the measured position."""
        self.q_ref = np.array(q, dtype=float)

    def __call__(self, q: np.ndarray, v: np.ndarray, qd: np.ndarray) -> np.ndarray:
        a = self.kp * pin.difference(self.model, q, self.q_ref) + self.kd * (qd - v)
        self.q_ref = pin.integrate(self.model, self.q_ref, qd * self.dt)
        return pin.rnea(self.model, self.data, q, v, a).copy()

"""Random robot states within the robot's limits (shared by the derivative checks and the strategies).

A state is sampled in velocity coordinates: the position of every bounded one-DOF joint (revolute or
prismatic with finite limits) uniformly within its limits, shrunk by ``margin`` of its range at both
ends; every other velocity column (free-flyer, continuous, spherical, planar joints, unbounded joints) as
a tangent component -- translations in [-1, 1] m, rotations in [-pi, pi] -- applied to the neutral
configuration with ``pin.integrate``, so quaternions and (cos, sin) pairs stay normalized.
Velocities are uniform within the robot's velocity limits (scaled by ``velocity``), standard normal
times ``velocity`` where the model gives none.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin


def sampling_box(robot, margin: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(lower, upper, bounded)`` per velocity column of the sampling space (module doc)."""
    model = robot.model
    lo, up = np.full(robot.nv, -np.pi), np.full(robot.nv, np.pi)
    bounded = np.zeros(robot.nv, dtype=bool)
    for jid in range(1, model.njoints):
        j = model.joints[jid]
        if j.nq == 1 and j.nv == 1:
            a, b = float(model.lowerPositionLimit[j.idx_q]), float(model.upperPositionLimit[j.idx_q])
            if np.isfinite(a) and np.isfinite(b) and b > a and b - a < 1e6:
                w = margin * (b - a)
                lo[j.idx_v], up[j.idx_v], bounded[j.idx_v] = a + w, b - w, True
        elif j.nv == 6:  # free flyer: translation first
            lo[j.idx_v:j.idx_v + 3], up[j.idx_v:j.idx_v + 3] = -1.0, 1.0
    return lo, up, bounded


def configuration(robot, u: np.ndarray) -> np.ndarray:
    """The configuration of sampling coordinates ``u`` (one per velocity column, module doc)."""
    model = robot.model
    _, _, bounded = sampling_box(robot)
    q = pin.neutral(model)
    dv = np.where(bounded, 0.0, u)
    for jid in range(1, model.njoints):
        j = model.joints[jid]
        if j.nq == 1 and j.nv == 1 and bounded[j.idx_v]:
            q[j.idx_q] = u[j.idx_v]
    return pin.integrate(model, q, dv)


def velocity_box(robot, velocity: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Per column: the velocity limit times ``velocity`` (``inf`` where the model gives none)."""
    vmax = robot.velocity_limits() * velocity
    return -vmax, vmax


def random_state(robot, rng, *, margin: float = 0.0, velocity: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """A random ``(q, v)`` of ``robot`` within its limits (module doc), from numpy generator ``rng``."""
    lo, up, _ = sampling_box(robot, margin)
    q = configuration(robot, rng.uniform(lo, up))
    vlo, vup = velocity_box(robot, velocity)
    finite = np.isfinite(vup)
    v = np.where(finite, rng.uniform(np.where(finite, vlo, -1.0), np.where(finite, vup, 1.0)),
                 velocity * rng.standard_normal(robot.nv))
    return q, v

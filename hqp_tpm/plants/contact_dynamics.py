"""Joint torques for a floating-base robot standing on rigid contacts: one small QP per step.

The motion stack (any hierarchy, solved by the project's solvers) gives a desired acceleration ``a*``. A
floating base cannot be given ``a*`` through ``rnea`` alone: the six base rows of ``M a + h`` must be
produced by contact forces. This QP finds the acceleration closest to ``a*`` and the contact forces that
produce it: task-space inverse dynamics with contacts as TSID formulates it (its
``InverseDynamicsFormulationAccForce``, ``src/formulations/inverse-dynamics-formulation-acc-force.cpp``: the base
rows ``M_u a - J_u^T f = -h_u`` and the contacts' motion as equalities, the friction cones on the forces of a flat
contact's four corners as inequalities, a force regularisation, ``tau = M_a a + h_a - J_a^T f``; read, not copied;
here the motion tasks are solved before, by the project's hierarchy, and enter through ``a*``). Variables
``y = (a, f)`` with ``f`` the 3-D world-frame forces at the corners of each sole:

    min  |a - a*|^2 + w_f |f - f_0|^2
    s.t. M_u a + h_u = J_u^T f                           (the base rows of M a + h = S^T tau + J^T f)
         J_k a = b_k               for each contact task  (the foot task's own acceleration command)
         |f_x|, |f_y| <= mu / sqrt(2) f_z,  f_z >= f_min  (the friction pyramid inscribed in the cone)
         -tau_max <= M_a a + h_a - J_a^T f <= tau_max   (the URDF's effort limits)

``f_0`` shares the weight evenly between the corners (it keeps the centre of pressure centred when the
motion leaves freedom). Then ``tau = M_a a + h_a - J_a^T f`` (the actuated rows).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from hqp_tpm.errors import ParameterError, SolverFailedError
from hqp_tpm.robot.model import Robot
from hqp_tpm.robot.state import State
from hqp_tpm.tasks.frame_pose import FramePose


def sole_corners(center, half_extents) -> np.ndarray:
    """The 4 corners (4 x 3, in the sole frame, on its plane z = 0) of a rectangle ``center`` +- ``half_extents``."""
    cx, cy = float(center[0]), float(center[1])
    hx, hy = float(half_extents[0]), float(half_extents[1])
    return np.array([[cx + sx * hx, cy + sy * hy, 0.0] for sx in (1, -1) for sy in (1, -1)])


@dataclass(frozen=True)
class SoleContact:
    """A flat foot on the ground: its 6-D pose task (held) and its corners in the sole frame."""

    task: FramePose
    corners: np.ndarray  # (k, 3), sole frame


@dataclass
class ContactSolution:
    """One solve: acceleration, contact forces (``(points, 3)``, world frame), torques, cone margins."""

    a: np.ndarray
    forces: np.ndarray
    tau: np.ndarray
    margins: np.ndarray  # mu f_z - |f_t| per point (>= 0: inside the true cone)
    deviation: float  # |a - a*|


def cone_margins(forces: np.ndarray, mu: float) -> np.ndarray:
    """``mu f_z - |(f_x, f_y)|`` per row of ``forces`` (world frame, flat ground): >= 0 inside the friction cone."""
    forces = np.asarray(forces, dtype=float).reshape(-1, 3)
    return mu * forces[:, 2] - np.hypot(forces[:, 0], forces[:, 1])


class ContactInverseDynamics:
    """``solve(state, t, a_star) -> ContactSolution`` for a floating-base robot on its sole contacts.

    ``mu``: friction coefficient the controller assumes (lower than the real one: a margin); ``f_min``: the
    smallest normal force per corner (N); ``weight_force``: ``w_f``; ``solver``: a qpsolvers backend.
    """

    def __init__(self, robot: Robot, contacts: list[SoleContact], *, mu: float = 0.7, f_min: float = 1.0,
                 weight_force: float = 1e-5, solver: str = "daqp"):
        if not robot.has_free_flyer:
            raise ParameterError(f"robot {robot.name!r} has no free-flyer base: use rnea for a fixed base")
        if not contacts:
            raise ParameterError("a floating base needs at least one contact")
        if not (np.isfinite(mu) and mu > 0):
            raise ParameterError(f"friction coefficient mu = {mu!r} must be finite and > 0")
        if not (np.isfinite(f_min) and f_min >= 0):
            raise ParameterError(f"f_min = {f_min!r} must be finite and >= 0")
        import qpsolvers

        if solver not in qpsolvers.available_solvers:
            from hqp_tpm.errors import unknown_name

            raise unknown_name("QP solver", solver, qpsolvers.available_solvers)
        self.robot, self.contacts = robot, list(contacts)
        self.mu, self.f_min, self.weight_force, self.solver = float(mu), float(f_min), float(weight_force), solver
        self.model = robot.model
        self.data = self.model.createData()
        self.nv = robot.nv
        self.points = sum(len(c.corners) for c in self.contacts)
        self.tau_max = np.array(self.model.effortLimit[6:], dtype=float)
        self.tau_max[~np.isfinite(self.tau_max) | (self.tau_max <= 0)] = np.inf
        # friction pyramid and minimum normal force, per point: rows on (fx, fy, fz)
        m = self.mu / np.sqrt(2.0)
        self._cone = np.array([[1.0, 0.0, -m], [-1.0, 0.0, -m], [0.0, 1.0, -m], [0.0, -1.0, -m], [0.0, 0.0, -1.0]])
        #: proxqp's default tolerance (1e-5 on the equalities) is loose for the floating-base rows: 1e-9
        self._tolerances = {"eps_abs": 1e-9, "eps_rel": 0.0} if solver == "proxqp" else {}
        weight = sum(i.mass for i in self.model.inertias) * np.linalg.norm(self.model.gravity.linear)
        self.f0 = np.tile([0.0, 0.0, weight / self.points], self.points)

    def contact_jacobian(self, state: State) -> np.ndarray:
        """``(3 points) x nv``: the world-aligned linear Jacobians of the sole corners (forces map by its transpose)."""
        rows = []
        for c in self.contacts:
            J = state.jacobian(c.task.fid)
            M = state.placement(c.task.fid)
            for p in c.corners:
                r = M.rotation @ p  # corner relative to the sole origin, world frame
                rows.append(J[:3] - pin.skew(r) @ J[3:])
        return np.vstack(rows)

    def solve(self, state: State, t: float, a_star: np.ndarray) -> ContactSolution:
        """The QP of the module docstring at ``state`` (updated at ``(q, v)``; its kinematics are reused)."""
        import qpsolvers

        nv, npt = self.nv, 3 * self.points
        q, v = state.q, state.v
        M = pin.crba(self.model, self.data, q)
        M = np.triu(M) + np.triu(M, 1).T
        h = pin.nonLinearEffects(self.model, self.data, q, v)
        Jc = self.contact_jacobian(state)
        # equalities: base dynamics, then the contact tasks' own acceleration rows
        A = [np.hstack([M[:6], -Jc[:, :6].T])]
        b = [-h[:6]]
        for c in self.contacts:
            A.append(np.hstack([c.task.jacobian(state), np.zeros((6, npt))]))
            b.append(c.task.command(state, t, 2))
        A, b = np.vstack(A), np.concatenate(b)
        # inequalities: cones, then torque limits
        cone = np.kron(np.eye(self.points), self._cone)
        G = [np.hstack([np.zeros((cone.shape[0], nv)), cone])]
        hv = [np.tile([0.0, 0.0, 0.0, 0.0, -self.f_min], self.points)]
        lim = np.isfinite(self.tau_max)
        if lim.any():
            T = np.hstack([M[6:], -Jc[:, 6:].T])[lim]
            ha = h[6:][lim]
            G += [T, -T]
            hv += [self.tau_max[lim] - ha, self.tau_max[lim] + ha]
        G, hv = np.vstack(G), np.concatenate(hv)
        w = self.weight_force
        P = np.diag(np.concatenate([np.ones(nv), np.full(npt, w)]))
        c_ = -np.concatenate([a_star, w * self.f0])
        y = qpsolvers.solve_qp(P, c_, G, hv, A, b, solver=self.solver, **self._tolerances)
        if y is None or not np.isfinite(y).all():
            raise SolverFailedError(f"contact QP ({self.solver}) found no solution at t = {t:.4f}: no contact forces "
                                    f"inside the friction cones and torques inside their limits give this motion")
        a, f = y[:nv], y[nv:]
        tau = M[6:] @ a + h[6:] - Jc[:, 6:].T @ f
        forces = f.reshape(-1, 3)
        return ContactSolution(a, forces, tau, cone_margins(forces, self.mu), float(np.linalg.norm(a - a_star)))

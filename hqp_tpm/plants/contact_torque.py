"""Torques for a floating base standing on its soles: the contact QP as the plant's torque law.

:class:`ContactTorque` is a torque law of :class:`~hqp_tpm.plants.mujoco_plant.MujocoPlant` (``law(q, v, a*) ->
tau``): at the measured state it solves :class:`~hqp_tpm.plants.contact_dynamics.ContactInverseDynamics` for the
acceleration closest to the stack's ``a*`` that contact forces inside the friction cones and torques inside the
limits can produce, and returns those torques (zero on the base's six columns, which no motor drives).
:meth:`ContactTorque.record` gives a run's per-step channels: the torques' ratio to their limits, the QP's forces
and cone margins, MuJoCo's own contact forces in the controller's cone, the base height and the soles' slip.
"""

from __future__ import annotations

import numpy as np

from hqp_tpm.plants.contact_dynamics import ContactInverseDynamics, ContactSolution, cone_margins
from hqp_tpm.plants.humanoid import contact_forces
from hqp_tpm.robot.state import State


class ContactTorque:
    """``tau = ContactTorque(...)(q, v, a_star)``: the contact QP's torques at the measured state."""

    def __init__(self, contacts: ContactInverseDynamics, feet_bodies=()):
        self.contacts = contacts
        self.robot = contacts.robot
        self.state = State(self.robot)
        self.feet_bodies = list(feet_bodies)
        self.last: ContactSolution | None = None
        self._start = None  # (base height, sole positions) at the first step

    def reset(self, q: np.ndarray, v: np.ndarray) -> None:
        self.last, self._start = None, None

    def __call__(self, q: np.ndarray, v: np.ndarray, a_star: np.ndarray) -> np.ndarray:
        """The torques (``nv``; zero on the base) at ``(q, v)``. The soles' tasks hold a fixed placement, so their
        rows do not depend on time (the QP is solved at t = 0)."""
        st = self.state.update(q, v, 0.0)
        sol = self.contacts.solve(st, 0.0, a_star)
        self.last = sol
        tau = np.zeros(self.robot.nv)
        tau[6:] = sol.tau
        return tau

    def record(self, plant) -> dict:
        """The standing channels after a plant step (``plant``: the :class:`MujocoPlant` this law drives)."""
        sol = self.last
        model, data = plant.model, plant.data
        feet = np.array([data.xpos[model.body(b).id] for b in self.feet_bodies]).reshape(-1, 3)
        base = float(data.qpos[2])
        if self._start is None:
            self._start = (self.state.q[2], feet.copy())
        sim = contact_forces(model, data)
        mu = self.contacts.mu
        return {"tau_ratio": float(np.max(np.abs(sol.tau) / self.contacts.tau_max)),
                "contact_forces": sol.forces.reshape(-1), "cone_margin": float(sol.margins.min()),
                "normal_force_min": float(sol.forces[:, 2].min()),
                "sim_cone_margin": float(cone_margins(sim, mu).min()) if len(sim) else float("-inf"),
                "sim_contacts": float(len(sim)), "base_height_change": base - float(self._start[0]),
                "foot_slip": float(np.hypot(*(feet - self._start[1])[:, :2].T).max()) if len(feet) else 0.0,
                "qp_deviation": sol.deviation}

    @staticmethod
    def summary(arrays: dict) -> dict:
        """The standing run's numbers (the criteria of issue 30, item 4)."""
        def peak(key, fn=np.max):
            return float(fn(np.asarray(arrays[key]))) if key in arrays and len(arrays[key]) else float("nan")

        return {"base_height_max_change_m": peak("base_height_change", lambda a: np.abs(a).max()),
                "foot_slip_max_m": peak("foot_slip"), "cone_margin_min_N": peak("cone_margin", np.min),
                "normal_force_min_N": peak("normal_force_min", np.min),
                "sim_cone_margin_min_N": peak("sim_cone_margin", np.min),
                "tau_ratio_max": peak("tau_ratio"), "qp_deviation_max": peak("qp_deviation")}

"""A floating-base robot simulated by MuJoCo under the project's controller, torques from a contact QP.

:class:`FloatingBasePlant` holds the MuJoCo model and data of a robot standing on the ground
(:func:`hqp_tpm.plants.humanoid.floating_spec`) and converts its state to pinocchio's conventions in one place:
MuJoCo stores the free joint as ``(x, y, z, qw, qx, qy, qz)`` with the linear velocity in the world frame,
pinocchio as ``(x, y, z, qx, qy, qz, qw)`` with both velocities in the body frame; the 1-DOF joints are mapped
by name.

:class:`ContactController` is a :class:`~hqp_tpm.control.controller.Controller` whose step is committed on the
plant instead of by integration: the motion stack (the project's solver) gives ``a*``, the contact QP
(:class:`~hqp_tpm.control.contact_dynamics.ContactInverseDynamics`) the torques, MuJoCo one step, and the
controller then reads the measured ``(q, v)`` and nothing else.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from hqp_tpm.control.contact_dynamics import ContactInverseDynamics, ContactSolution, cone_margins
from hqp_tpm.control.controller import Controller
from hqp_tpm.errors import NonFiniteError, RobotFileError
from hqp_tpm.plants.humanoid import mujoco_module
from hqp_tpm.robot.model import Robot
from hqp_tpm.robot.state import State


class FloatingBasePlant:
    """MuJoCo model and data of ``robot`` (free-flyer) from a ``mujoco.MjSpec``; state in pinocchio's terms."""

    def __init__(self, robot: Robot, spec):
        mujoco = mujoco_module()
        self.robot = robot
        self.spec = spec
        self.model = spec.compile()
        self.data = mujoco.MjData(self.model)
        m = self.model
        names = robot.joint_names[6:]
        if m.nq != robot.nq or m.nv != robot.nv or m.jnt_type[0] != mujoco.mjtJoint.mjJNT_FREE:
            raise RobotFileError(f"the MuJoCo model (nq {m.nq}, nv {m.nv}) does not match robot {robot.name!r} "
                                 f"(nq {robot.nq}, nv {robot.nv}, free-flyer first)")
        # 1-DOF joints by name: pinocchio column -> MuJoCo qpos / qvel address
        self.qadr = np.array([m.jnt_qposadr[m.joint(n).id] for n in names], dtype=int)
        self.vadr = np.array([m.jnt_dofadr[m.joint(n).id] for n in names], dtype=int)
        self.actuators = np.array([m.actuator(n).id for n in names], dtype=int)
        self.tau_limit = np.where(m.actuator_ctrllimited[self.actuators] > 0, m.actuator_ctrlrange[self.actuators, 1],
                                  np.inf)
        self._mj = mujoco

    @property
    def dt(self) -> float:
        return float(self.model.opt.timestep)

    def set_state(self, q: np.ndarray, v: np.ndarray) -> None:
        """Write pinocchio's ``(q, v)`` into MuJoCo's state (and recompute its derived quantities)."""
        d = self.data
        R = pin.Quaternion(q[6], q[3], q[4], q[5]).normalized().toRotationMatrix()
        d.qpos[:3] = q[:3]
        d.qpos[3] = q[6]
        d.qpos[4:7] = q[3:6]
        d.qpos[self.qadr] = q[7:]
        d.qvel[:3] = R @ v[:3]
        d.qvel[3:6] = v[3:6]
        d.qvel[self.vadr] = v[6:]
        self._mj.mj_forward(self.model, d)

    def measure(self) -> tuple[np.ndarray, np.ndarray]:
        """The state in pinocchio's terms: ``q`` (base quaternion x, y, z, w), ``v`` (base velocities local)."""
        d = self.data
        q = np.empty(self.robot.nq)
        v = np.empty(self.robot.nv)
        q[:3] = d.qpos[:3]
        q[3:6] = d.qpos[4:7]
        q[6] = d.qpos[3]
        q[7:] = d.qpos[self.qadr]
        R = pin.Quaternion(q[6], q[3], q[4], q[5]).toRotationMatrix()
        v[:3] = R.T @ d.qvel[:3]
        v[3:6] = d.qvel[3:6]
        v[6:] = d.qvel[self.vadr]
        return q, v

    def snapshot(self) -> tuple:
        """What the next ``mj_step`` reads of the data (state, controls, the constraint solver's warm start)."""
        d = self.data
        return d.time, d.qpos.copy(), d.qvel.copy(), d.act.copy(), d.ctrl.copy(), d.qacc_warmstart.copy()

    def restore(self, snapshot: tuple) -> None:
        """Put back a :meth:`snapshot` (a rejected step leaves the plant as it was, to the bit)."""
        d = self.data
        d.time = snapshot[0]
        d.qpos[:], d.qvel[:], d.act[:], d.ctrl[:] = snapshot[1:5]
        self._mj.mj_forward(self.model, d)  # (it overwrites the warm start with its own solution)
        d.qacc_warmstart[:] = snapshot[5]

    def step(self, tau: np.ndarray) -> None:
        """Apply joint torques ``tau`` (pinocchio's joint order) for one MuJoCo step."""
        self.data.ctrl[self.actuators] = tau
        self._mj.mj_step(self.model, self.data)

    def body_position(self, name: str) -> np.ndarray:
        return self.data.xpos[self.model.body(name).id].copy()

    def contact_forces(self) -> np.ndarray:
        """``(contacts, 3)``: each active contact's force on the robot in the world frame (flat ground:
        column 2 is the normal force)."""
        mj, m, d = self._mj, self.model, self.data
        out = np.zeros((d.ncon, 3))
        f6 = np.zeros(6)
        for i in range(d.ncon):
            mj.mj_contactForce(m, d, i, f6)
            c = d.contact[i]
            frame = c.frame.reshape(3, 3)  # rows: normal, tangents (world)
            f = frame.T @ f6[:3]  # force on geom2 from geom1, world frame
            out[i] = f if m.geom_bodyid[c.geom2] != 0 else -f
        return out

    def write(self, folder, q0, v0=None) -> list[str]:
        """Write the model MuJoCo simulates into ``folder`` with the run's initial state as keyframe ``initial``
        (``mj_resetDataKeyframe(m, d, 0)``): ``plant.xml`` (MJCF, readable, 6 significant digits: MuJoCo's
        writer) and ``plant.mjb`` (MuJoCo's binary model: the same bits, for an exact torque replay)."""
        from pathlib import Path

        saved = self.data.qpos.copy(), self.data.qvel.copy()
        self.set_state(q0, np.zeros(self.robot.nv) if v0 is None else v0)
        qpos, qvel = self.data.qpos.copy(), self.data.qvel.copy()
        self.data.qpos[:], self.data.qvel[:] = saved
        self._mj.mj_forward(self.model, self.data)
        for key in list(self.spec.keys):
            self.spec.delete(key)
        self.spec.add_key(name="initial", qpos=qpos.tolist(), qvel=qvel.tolist(), ctrl=[0.0] * self.model.nu)
        model = self.spec.compile()  # the same model with its keyframe (this plant keeps its own)
        folder = Path(folder)
        (folder / "plant.xml").write_text(self.spec.to_xml())
        self._mj.mj_saveModel(model, str(folder / "plant.mjb"), None)
        return ["plant.xml", "plant.mjb"]


class ContactController(Controller):
    """A controller whose steps run on a :class:`FloatingBasePlant` (torques from ``contacts``, a contact QP).

    The motion stack is solved as usual (acceleration level); :meth:`advance` sends the command through the
    contact QP, applies its torques for one plant step and reads the measured state. ``last`` is the QP's
    latest :class:`ContactSolution`; :meth:`probe` records it with the plant's own contact forces.
    """

    def __init__(self, robot: Robot, policy, plant: FloatingBasePlant, contacts: ContactInverseDynamics,
                 *, feet_bodies=(), **kwargs):
        super().__init__(robot, policy, order=2, **kwargs)
        self.plant = plant
        self.contacts = contacts
        self.last: ContactSolution | None = None
        self.feet_bodies = list(feet_bodies)
        self._contact_state = State(robot)
        plant.set_state(self.q, self.v)
        self.q0, self.v0 = self.q.copy(), self.v.copy()
        self._feet0 = np.array([plant.body_position(b) for b in self.feet_bodies]).reshape(-1, 3)
        self._base0 = self.q[2]

    def advance(self, command) -> np.ndarray:
        """``command()`` -> ``a*``; the contact QP's torques for one plant step; the measured state (transactional:
        a failure leaves the controller, its policy and the plant as they were)."""
        started, saved = self._started, self.policy.snapshot()
        plant_saved = self.plant.snapshot()
        try:
            x = command()
            st = self._contact_state.update(self._q, self._v, self.t, validate=False)
            sol = self.contacts.solve(st, self.t, x)
            self.plant.step(sol.tau)
            q, v = self.plant.measure()
            if not (np.isfinite(q).all() and np.isfinite(v).all()):
                raise NonFiniteError(f"the plant's state became non-finite{self._where()}")
        except BaseException:
            self.policy.restore(saved)
            self._started = started
            self.plant.restore(plant_saved)
            raise
        self._q, self._v = q, v
        self.a = sol.a.copy()
        self.last = sol
        self.t += self.dt
        self.steps += 1
        return x

    # -- what a run records -------------------------------------------------------------------
    def plant_files(self, folder) -> list[str]:
        """The plant's model with the run's initial state (:meth:`FloatingBasePlant.write`): replaying the recorded
        ``tau`` on ``plant.mjb`` with MuJoCo alone gives the recorded run."""
        return self.plant.write(folder, self.q0, self.v0)

    def probe(self, ctrl, res) -> dict:
        """Per step: torques and their ratio to the limits, the QP's forces and cone margins, the plant's contact
        forces and their margins in the controller's cone, base height change, largest horizontal foot slip."""
        sol = self.last
        sim = self.plant.contact_forces()
        mu = self.contacts.mu
        sim_margin = float(cone_margins(sim, mu).min()) if len(sim) else float("nan")
        feet = np.array([self.plant.body_position(b) for b in self.feet_bodies]).reshape(-1, 3)
        slip = float(np.hypot(*(feet - self._feet0)[:, :2].T).max()) if len(feet) else 0.0
        tau_max = self.contacts.tau_max
        return {"tau": sol.tau, "tau_ratio": float(np.max(np.abs(sol.tau) / tau_max)),
                "contact_forces": sol.forces.reshape(-1), "cone_margin": float(sol.margins.min()),
                "normal_force_min": float(sol.forces[:, 2].min()),
                "sim_cone_margin": sim_margin, "sim_contacts": float(len(sim)),
                "base_height_change": float(self._q[2] - self._base0), "foot_slip": slip,
                "qp_deviation": sol.deviation}

    @staticmethod
    def summary(arrays: dict) -> dict:
        """The standing run's numbers (the issue's criteria): base height, slip, cones, torques."""
        def peak(key, fn=np.max):
            return float(fn(np.asarray(arrays[key]))) if key in arrays and len(arrays[key]) else float("nan")

        return {"base_height_max_change_m": peak("base_height_change", lambda a: np.abs(a).max()),
                "foot_slip_max_m": peak("foot_slip"), "cone_margin_min_N": peak("cone_margin", np.min),
                "normal_force_min_N": peak("normal_force_min", np.min),
                "sim_cone_margin_min_N": peak("sim_cone_margin", np.nanmin),
                "tau_ratio_max": peak("tau_ratio"), "qp_deviation_max": peak("qp_deviation")}

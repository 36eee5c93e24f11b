"""A MuJoCo plant: the robot as a body with mass, torques and what the controller does not model.

The loop a run closes through it, once per control period ``T``::

    q, v = plant.measure()          # what the controller reads (sensor noise, k-step delay)
    command = controller(q, v)      # qd (velocity level) or qdd (acceleration level)
    tau = plant.step(command)       # torques from the command (hqp_tpm.plants.torque), then MuJoCo for T

The controller's state is set to the measurement and nothing else: the plant writes nothing into the
controller. Torques go to one motor per actuated joint (``data.ctrl``, in pinocchio's velocity order of the
actuated joints), clipped to the URDF's limits when ``torque_limits``; :attr:`tau` holds the applied
torques as an ``nv`` vector (zero on a floating base's six columns, which no motor drives).
"""

from __future__ import annotations

from collections import deque

import numpy as np
import pinocchio as pin

from hqp_tpm.errors import ParameterError, PlantError, ShapeError
from hqp_tpm.plants.frames import body_of_frame
from hqp_tpm.plants.joint_map import JointMap
from hqp_tpm.plants.mjcf import compile_xml, mujoco_module, plant_xml
from hqp_tpm.plants.options import PlantOptions
from hqp_tpm.plants.torque import InverseDynamics, JointImpedance
from hqp_tpm.robot.model import Robot


class MujocoPlant:
    """The robot simulated by MuJoCo, stepped every ``period`` seconds with a command of level ``order``."""

    kind = "mujoco"

    def __init__(self, robot: Robot, period: float, order: int = 2, options: PlantOptions | None = None,
                 xml: str | None = None, geoms=(), law=None) -> None:
        """``xml``: the MJCF to simulate (default: :func:`~hqp_tpm.plants.mjcf.plant_xml` of the robot, with the
        contact-free ``geoms`` added). ``law``: what turns a command into torques, ``law(q, v, command) -> tau``
        (``nv``) with ``law.reset(q, v)`` (default: :class:`InverseDynamics` at acceleration level,
        :class:`JointImpedance` at velocity level; a floating base on contacts:
        :class:`~hqp_tpm.plants.contact_torque.ContactTorque`)."""
        if order not in (1, 2):
            raise ParameterError(f"order must be 1 (velocity level) or 2 (acceleration level), got {order!r}")
        if not (np.isfinite(period) and period > 0):
            raise ParameterError(f"period = {period!r} must be finite and > 0")
        self.mujoco = mujoco_module()
        self.robot, self.period, self.order = robot, float(period), order
        self.options = PlantOptions() if options is None else options
        self.substeps = self.options.substeps(self.period)
        self.xml = plant_xml(robot, self.period, self.options, geoms) if xml is None else xml
        self.model = compile_xml(self.xml)
        self.data = self.mujoco.MjData(self.model)
        self.map = JointMap(robot.model, self.model)
        self.law = law if law is not None else (
            InverseDynamics(robot.model) if order == 2 else
            JointImpedance(robot.model, self.period, self.options.kp, self.options.kd))
        lo, up = self.model.actuator_ctrlrange.T
        limited = self.model.actuator_ctrllimited.astype(bool)
        self.tau_min = np.where(limited, lo, -np.inf)
        self.tau_max = np.where(limited, up, np.inf)
        self.tau = np.zeros(robot.nv)
        self.rng = np.random.default_rng(self.options.seed)
        self._history: deque = deque(maxlen=self.options.delay + 1)
        self.reset(robot.neutral(), np.zeros(robot.nv))

    def __repr__(self) -> str:
        o = self.options
        return (f"MujocoPlant({self.robot.name!r}, {'velocity' if self.order == 1 else 'acceleration'} level, "
                f"T={self.period:g} s in {self.substeps} step(s) of {o.integrator}, unmodelled: "
                f"{'yes' if o.unmodelled else 'none'})")

    # -- state -----------------------------------------------------------------------------------
    def reset(self, q, v=None) -> None:
        """Put the plant at ``(q, v)`` (pinocchio's conventions), clear the delay line and the torque law."""
        q = np.asarray(q, dtype=float)
        v = np.zeros(self.robot.nv) if v is None else np.asarray(v, dtype=float)
        if q.shape != (self.robot.nq,) or v.shape != (self.robot.nv,):
            raise ShapeError(f"plant state: q must have {self.robot.nq} entries and v {self.robot.nv}, got "
                             f"{q.shape} and {v.shape}")
        self.mujoco.mj_resetData(self.model, self.data)
        self.data.qpos[:] = self.map.q_to_mujoco(q)
        self.data.qvel[:] = self.map.v_to_mujoco(q, v)
        self.mujoco.mj_forward(self.model, self.data)
        self._history.clear()
        self._sample()
        self.law.reset(*self.measure())

    @property
    def time(self) -> float:
        return float(self.data.time)

    def state(self) -> tuple[np.ndarray, np.ndarray]:
        """The true ``(q, v)`` now, in pinocchio's conventions."""
        q = self.map.q_from_mujoco(self.data.qpos)
        return q, self.map.v_from_mujoco(q, self.data.qvel)

    def _sample(self) -> None:
        """Read the sensors now (noise added here) into the delay line."""
        q, v = self.state()
        o = self.options
        if o.noise_q:
            q = pin.integrate(self.robot.model, q, o.noise_q * self.rng.standard_normal(self.robot.nv))
        if o.noise_v:
            v = v + o.noise_v * self.rng.standard_normal(self.robot.nv)
        self._history.append((q, v))

    def measure(self) -> tuple[np.ndarray, np.ndarray]:
        """What the controller reads: the sensors ``delay`` periods ago (the oldest sample until then)."""
        q, v = self._history[0]
        return q.copy(), v.copy()

    # -- stepping --------------------------------------------------------------------------------
    def torque(self, command: np.ndarray) -> np.ndarray:
        """The motor torques (``nv``, clipped to the limits) the command asks for at the measured state."""
        command = np.asarray(command, dtype=float)
        if command.shape != (self.robot.nv,):
            raise ShapeError(f"plant command: expected {self.robot.nv} values, got shape {command.shape}")
        q, v = self.measure()
        tau = self.law(q, v, command)
        out = np.zeros(self.robot.nv)
        out[self.map.actuated] = np.clip(tau[self.map.actuated], self.tau_min, self.tau_max)
        return out

    def apply(self, tau: np.ndarray) -> np.ndarray:
        """Apply motor torques ``tau`` (``nv``, pinocchio's order; clipped to the limits) for one period."""
        tau = np.asarray(tau, dtype=float)
        act = np.clip(tau[self.map.actuated], self.tau_min, self.tau_max)
        self.data.ctrl[:] = act
        for _ in range(self.substeps):
            self.mujoco.mj_step(self.model, self.data)
        if self.data.warning[self.mujoco.mjtWarning.mjWARN_BADQACC].number:
            raise PlantError(f"the MuJoCo simulation diverged (bad accelerations) at t = {self.data.time:.6f} s: "
                             "torques or contacts too large for the timestep")
        self.tau = np.zeros(self.robot.nv)
        self.tau[self.map.actuated] = act
        self._sample()
        return self.tau

    def step(self, command: np.ndarray) -> np.ndarray:
        """Torques for ``command`` from the measured state, applied for one period; returns them."""
        return self.apply(self.torque(command))

    # -- external forces -------------------------------------------------------------------------
    def push(self, frame: str | int, force, torque=None) -> None:
        """An external wrench (world frame: N, N m) on the body that carries ``frame``, acting at the frame's origin,
        until changed (``push(frame, 0)`` removes it). Written to MuJoCo's ``xfrc_applied``, which acts at the
        body's centre of mass: the moment of the force about it is added."""
        fid = self.robot.frame_id(frame) if isinstance(frame, str) else int(frame)
        body, offset = self.frame_body(fid)
        f = np.broadcast_to(np.asarray(force, dtype=float), (3,))
        n = np.zeros(3) if torque is None else np.asarray(torque, dtype=float)
        point = self.data.xpos[body] + self.data.xmat[body].reshape(3, 3) @ offset.translation
        self.data.xfrc_applied[body, :3] = f
        self.data.xfrc_applied[body, 3:] = n + np.cross(point - self.data.xipos[body], f)

    def frame_body(self, fid: int) -> tuple[int, pin.SE3]:
        """MuJoCo body id carrying pinocchio frame ``fid`` and the frame's placement in it
        (:func:`hqp_tpm.plants.frames.body_of_frame`)."""
        names = {self.model.body(b).name for b in range(self.model.nbody)}
        name, offset = body_of_frame(self.robot.model, names, fid)
        return int(self.model.body(name).id), offset

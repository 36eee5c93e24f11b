"""What the plant simulates beyond the controller's model, and how it integrates (:class:`PlantOptions`).

Every option defaults to "nothing the controller does not know": with the defaults the plant's mass matrix
is the controller's (pinocchio's) to rounding. Unmodelled effects: ``armature`` (rotor inertia added to the
diagonal of the mass matrix), ``damping`` (viscous joint damping, N m s/rad), ``friction`` (dry joint friction,
N m), ``noise_q``/``noise_v`` (standard deviations of Gaussian sensor noise on the measured position and
velocity, from a generator seeded with ``seed``), ``delay`` (the controller reads the state measured
``delay`` steps before), ``torque_limits`` (motor torques clipped to the URDF's ``effort``). Integration:
``timestep`` (s; None: the control period; it must divide the period) and ``integrator`` (MuJoCo's).
``kp``, ``kd``: the joint impedance that turns a velocity-level command into torques
(:class:`~hqp_tpm.plants.torque.JointImpedance`). ``floor``: a ground plane at z = 0 that the robot's
collision geometry touches; ``self_collision``: contacts between the robot's own links; ``collision``: keep the
URDF's collision geometry (false: bodies and joints alone, e.g. for a robot whose meshes MuJoCo cannot read).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

from hqp_tpm.errors import ParameterError

#: Plant kinds (a scenario's ``[plant] kind``): the controller's own perfect integration, or MuJoCo.
KINDS = ("kinematic", "mujoco")

#: MuJoCo's integrators by their MJCF names.
INTEGRATORS = ("euler", "rk4", "implicit", "implicitfast")


@dataclass(frozen=True)
class PlantOptions:
    """Options of a :class:`~hqp_tpm.plants.mujoco_plant.MujocoPlant` (checked on construction)."""

    timestep: float | None = None
    integrator: str = "euler"
    armature: float = 0.0
    damping: float = 0.0
    friction: float = 0.0
    noise_q: float = 0.0
    noise_v: float = 0.0
    seed: int = 0
    delay: int = 0
    torque_limits: bool = True
    kp: float = 400.0
    kd: float = 40.0
    floor: bool = False
    self_collision: bool = False
    collision: bool = True

    def unmodelled_effects(self) -> dict:
        """The effects the controller does not model that are set (nonzero), by name."""
        effects = {"armature": self.armature, "damping": self.damping, "friction": self.friction,
                   "noise_q": self.noise_q, "noise_v": self.noise_v, "delay": self.delay}
        return {k: v for k, v in effects.items() if v}

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if f.type == "bool":
                if not isinstance(value, bool):
                    raise ParameterError(f"plant option {f.name}: expected true or false, got {value!r}")
            elif f.name in ("seed", "delay"):
                if isinstance(value, bool) or not isinstance(value, int) or value < 0:
                    raise ParameterError(f"plant option {f.name}: expected a whole number >= 0, got {value!r}")
            elif f.name == "integrator":
                if value not in INTEGRATORS:
                    raise ParameterError(f"plant option integrator: {value!r} is not one of "
                                         f"{', '.join(map(repr, INTEGRATORS))}")
            elif f.name == "timestep" and value is None:
                continue
            else:
                if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                    raise ParameterError(f"plant option {f.name}: expected a finite number, got {value!r}")
                if value < 0 or (f.name == "timestep" and value == 0):
                    raise ParameterError(f"plant option {f.name}: must be {'> 0' if f.name == 'timestep' else '>= 0'}"
                                         f", got {value!r}")

    @property
    def unmodelled(self) -> bool:
        """Does the plant simulate something the controller's model does not have?"""
        return bool(self.unmodelled_effects())

    def substeps(self, period: float) -> int:
        """MuJoCo steps per control period (the timestep must divide the period)."""
        if self.timestep is None:
            return 1
        n = round(period / self.timestep)
        if n < 1 or abs(n * self.timestep - period) > 1e-9 * period:
            raise ParameterError(f"plant option timestep: {self.timestep!r} s does not divide the control period "
                                 f"{period!r} s")
        return n

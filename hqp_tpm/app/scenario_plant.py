"""A scenario's ``[plant]`` section: what the controller's command drives (docs/plant.md).

``kind = "kinematic"`` (the default, also without the section): the controller integrates its own command.
``kind = "mujoco"``: a :class:`~hqp_tpm.plants.MujocoPlant` with the other fields as its
:class:`~hqp_tpm.plants.PlantOptions`. Every bad field is a :class:`~hqp_tpm.errors.ScenarioError` naming the file
and the field.
"""

from __future__ import annotations

from dataclasses import dataclass

from hqp_tpm.app.scenario_values import Section
from hqp_tpm.errors import ParameterError, ScenarioError
from hqp_tpm.plants.options import INTEGRATORS, KINDS, PlantOptions

#: The options' defaults (what a field left out means).
_DEFAULT = PlantOptions()


@dataclass(frozen=True)
class ContactConfig:
    """``[plant] contacts``: a floating base standing on its soles, torques from the contact QP
    (:class:`~hqp_tpm.plants.contact_dynamics.ContactInverseDynamics`)."""

    tasks: tuple[str, ...]  # the scenario's frame_pose tasks that hold the soles
    mu: float = 0.7  # the controller's friction coefficient (the linearised cones)
    f_min: float = 1.0  # smallest normal force per sole corner (N)
    qp_solver: str = "daqp"
    ground_friction: float = 1.0  # MuJoCo's friction coefficient between the soles and the ground


@dataclass(frozen=True)
class PlantConfig:
    """The parsed ``[plant]`` section: its kind and, for ``"mujoco"``, the plant's options (and its contacts)."""

    kind: str = "kinematic"
    options: PlantOptions | None = None
    contacts: ContactConfig | None = None


def plant_config(sec: Section | None, period: float) -> PlantConfig:
    """Read and check ``[plant]`` (None: no section, a kinematic run) for a run stepped every ``period`` s."""
    if sec is None:
        return PlantConfig()
    kind = sec.string("kind", "kinematic", choices=KINDS)
    if kind == "kinematic":
        extra = sorted(set(sec.data) - {"kind"})
        if extra:
            raise ScenarioError(f"{sec.where}.{extra[0]}: an option of kind = 'mujoco'; with kind = 'kinematic' the "
                                "controller integrates its own command and the section takes no other field")
        return PlantConfig()
    values = {
        "timestep": sec.number("timestep", _DEFAULT.timestep),
        "integrator": sec.string("integrator", _DEFAULT.integrator, choices=INTEGRATORS),
        "armature": sec.number("armature", _DEFAULT.armature),
        "damping": sec.number("damping", _DEFAULT.damping),
        "friction": sec.number("friction", _DEFAULT.friction),
        "noise_q": sec.number("noise_q", _DEFAULT.noise_q),
        "noise_v": sec.number("noise_v", _DEFAULT.noise_v),
        "seed": sec.raw("seed", _DEFAULT.seed),
        "delay": sec.raw("delay", _DEFAULT.delay),
        "torque_limits": sec.boolean("torque_limits", _DEFAULT.torque_limits),
        "kp": sec.number("kp", _DEFAULT.kp),
        "kd": sec.number("kd", _DEFAULT.kd),
        "floor": sec.boolean("floor", _DEFAULT.floor),
        "self_collision": sec.boolean("self_collision", _DEFAULT.self_collision),
        "collision": sec.boolean("collision", _DEFAULT.collision),
    }
    for name, value in values.items():  # one at a time, so that the error names the field
        try:
            PlantOptions(**{name: value})
        except ParameterError as exc:
            raise ScenarioError(f"{sec.where}.{name}: {str(exc).split(': ', 1)[-1]}") from None
    contacts = _contacts(sec)
    sec.check_unused()
    options = PlantOptions(**values)
    try:
        options.substeps(period)
    except ParameterError as exc:
        raise ScenarioError(f"{sec.where}.timestep: {str(exc).split(': ', 1)[-1]}") from None
    return PlantConfig(kind, options, contacts)


def _contacts(sec: Section) -> ContactConfig | None:
    """``contacts`` (a list of frame_pose task names) and the contact QP's fields; None without ``contacts``."""
    names = sec.raw("contacts", None)
    fields = ("mu", "f_min", "qp_solver", "ground_friction")
    if names is None:
        given = [f for f in fields if sec.has(f)]
        if given:
            raise ScenarioError(f"{sec.where}.{given[0]}: a field of the contact QP, which needs `contacts` (the "
                                "frame_pose tasks that hold the soles)")
        return None
    if not isinstance(names, list) or not names or not all(isinstance(n, str) for n in names):
        raise ScenarioError(f"{sec.where}.contacts: expected a list of frame_pose task names (the held soles), "
                            f"got {names!r}")
    out = ContactConfig(tuple(names), mu=sec.number("mu", 0.7), f_min=sec.number("f_min", 1.0),
                        qp_solver=sec.string("qp_solver", "daqp"),
                        ground_friction=sec.number("ground_friction", 1.0))
    for name, value in (("mu", out.mu), ("ground_friction", out.ground_friction)):
        if value <= 0:
            raise ScenarioError(f"{sec.where}.{name}: must be > 0, got {value!r}")
    if out.f_min < 0:
        raise ScenarioError(f"{sec.where}.f_min: must be >= 0, got {out.f_min!r}")
    return out

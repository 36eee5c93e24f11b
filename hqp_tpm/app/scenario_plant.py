"""A scenario's ``[plant]`` section: what the controller's command drives (docs/plant.md).

``kind = "kinematic"`` (the default, also without the section): the controller integrates its own command.
``kind = "mujoco"``: a :class:`~hqp_tpm.plants.MujocoPlant` with the other fields as its
:class:`~hqp_tpm.plants.PlantOptions`. Every bad field is a :class:`~hqp_tpm.errors.ScenarioError` naming the file
and the field.
"""

from __future__ import annotations

from dataclasses import dataclass

from hqp_tpm.app.scenario import Section
from hqp_tpm.errors import ParameterError, ScenarioError
from hqp_tpm.plants.options import INTEGRATORS, KINDS, PlantOptions

#: The options' defaults (what a field left out means).
_DEFAULT = PlantOptions()


@dataclass(frozen=True)
class PlantConfig:
    """The parsed ``[plant]`` section: its kind and, for ``"mujoco"``, the plant's options."""

    kind: str = "kinematic"
    options: PlantOptions | None = None


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
    sec.check_unused()
    options = PlantOptions(**values)
    try:
        options.substeps(period)
    except ParameterError as exc:
        raise ScenarioError(f"{sec.where}.timestep: {str(exc).split(': ', 1)[-1]}") from None
    return PlantConfig(kind, options)

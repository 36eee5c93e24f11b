"""A floating-base robot standing on flat ground: the plant's MJCF with box soles on a ground plane.

:func:`standing_xml` takes the plant's own model of the robot (:func:`~hqp_tpm.plants.mjcf.plant_xml`, built with
``collision = false``: Romeo's meshes are COLLADA, which MuJoCo does not read, and meshes make poor feet) and adds
one box under each sole frame (the only collision geometry: its bottom face is the sole frame's plane) and the
ground plane they stand on, with the ground's friction and contact softness. :func:`standing_base` puts the
robot's base where its soles rest on the ground; :func:`contact_forces` reads MuJoCo's contact forces.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from hqp_tpm.errors import PlantError
from hqp_tpm.plants.mjcf import mujoco_module, plant_xml, precise_xml
from hqp_tpm.plants.options import PlantOptions
from hqp_tpm.robot.model import Robot

#: Romeo's soles: the box under each ``*_sole`` frame (centre and half extents in the sole frame, metres),
#: the bounding box of the foot's collision mesh (coal's convex hull of ``l_ankle_0`` in the sole frame:
#: x in [-0.089, 0.155], y in [-0.056, 0.071] on the left foot, mirrored on the right), slightly trimmed.
ROMEO_SOLES = {"l_sole": ((0.033, 0.0074), (0.12, 0.06)), "r_sole": ((0.033, -0.0074), (0.12, 0.06))}
#: Thickness of a sole box (m).
SOLE_THICKNESS = 0.02


@dataclass(frozen=True)
class Ground:
    """The ground and the soles: MuJoCo's friction coefficient and contact softness (``solref``)."""

    friction: float = 1.0
    solref: tuple[float, float] = (0.02, 1.0)


def standing_xml(robot: Robot, period: float, soles: dict, options: PlantOptions | None = None,
                 ground: Ground = Ground()) -> str:
    """The MJCF text of ``robot`` (free-flyer) standing: the plant's model, a box per sole, a ground plane.

    ``soles``: sole frame (a body of the URDF) -> ``((cx, cy), (hx, hy))``, its box in the sole frame.
    """
    mujoco = mujoco_module()
    if not robot.has_free_flyer:
        raise PlantError(f"robot {robot.name!r} has no free-flyer base: it cannot stand on its soles")
    options = PlantOptions(collision=False) if options is None else options
    spec = mujoco.MjSpec.from_string(plant_xml(robot, period, options))
    friction = [float(ground.friction), 0.005, 0.0001]
    for frame, ((cx, cy), (hx, hy)) in soles.items():
        body = spec.body(frame)
        if body is None:
            raise PlantError(f"robot {robot.name!r}: no link {frame!r} to put a sole box under")
        body.add_geom(name=f"{frame}_box", type=mujoco.mjtGeom.mjGEOM_BOX, size=[hx, hy, SOLE_THICKNESS / 2],
                      pos=[cx, cy, SOLE_THICKNESS / 2], friction=friction, solref=list(ground.solref), mass=0.0,
                      contype=1, conaffinity=0, condim=3)
    floor = spec.geom("floor")
    if floor is None:
        floor = spec.worldbody.add_geom(name="floor", type=mujoco.mjtGeom.mjGEOM_PLANE, size=[0, 0, 1])
    floor.contype, floor.conaffinity, floor.friction = 0, 1, friction
    try:
        spec.compile()
    except (ValueError, RuntimeError) as exc:
        raise PlantError(f"MuJoCo cannot compile the standing model of {robot.name!r}: {exc}") from exc
    return precise_xml(spec.to_xml(), spec)


def standing_base(robot: Robot, q: np.ndarray, soles) -> np.ndarray:
    """``q`` with its base placed so that the lowest sole frame lies on the ground (z = 0), the soles centred
    about the origin, the base orientation upright."""
    q = np.array(q, dtype=float)
    q[:7] = [0, 0, 0, 0, 0, 0, 1]
    data = robot.model.createData()
    pin.framesForwardKinematics(robot.model, data, q)
    feet = np.array([data.oMf[robot.frame_id(f)].translation for f in soles])
    q[:2] = -feet[:, :2].mean(axis=0)
    q[2] = -feet[:, 2].min()
    return q


def contact_forces(model, data) -> np.ndarray:
    """``(contacts, 3)``: each active contact's force on the robot, world frame (flat ground: column 2 normal)."""
    mujoco = mujoco_module()
    out = np.zeros((data.ncon, 3))
    f6 = np.zeros(6)
    for i in range(data.ncon):
        mujoco.mj_contactForce(model, data, i, f6)
        c = data.contact[i]
        f = c.frame.reshape(3, 3).T @ f6[:3]  # rows of frame: normal, tangents; the force geom1 puts on geom2
        out[i] = f if model.geom_bodyid[c.geom2] != 0 else -f
    return out

"""A floating-base robot on flat ground for MuJoCo: the robot's own URDF, its feet as boxes, a ground plane.

For the physics only the URDF's bodies, joints and inertias are kept: visual and collision meshes are dropped
(Romeo's are COLLADA, which MuJoCo does not read, and meshes make poor feet), every 1-DOF joint the reduced
robot locked is removed (its body welded at the URDF's zero, pinocchio's ``buildReducedModel`` at the neutral
configuration: the same), the URDF's mimic equalities go with them, and a free joint carries the root body.
Each sole gets a box (the only collision geometry) whose bottom face is the sole frame's plane, and each
actuated joint a torque motor limited to the URDF's effort.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pinocchio as pin

from hqp_tpm.errors import ParameterError, PlantNotAvailableError, RobotFileError
from hqp_tpm.robot.model import Robot

#: Romeo's soles: the box under each ``*_sole`` frame (centre and half extents in the sole frame, metres),
#: the bounding box of the foot's collision mesh (coal's convex hull of ``l_ankle_0``: x in [-0.089, 0.155],
#: |y| <= 0.071 on the outer side, 0.056 on the inner), slightly trimmed.
ROMEO_SOLES = {"l_sole": ((0.033, 0.0074), (0.12, 0.06)), "r_sole": ((0.033, -0.0074), (0.12, 0.06))}
#: Thickness of a sole box (m).
SOLE_THICKNESS = 0.02


def mujoco_module():
    """The ``mujoco`` package (the ``sim`` extra), or an error saying how to install it."""
    try:
        import mujoco
    except ImportError as exc:
        raise PlantNotAvailableError(f"the MuJoCo plant needs the mujoco package ({exc}): pip install hqp-tpm[sim]"
                                     ) from exc
    return mujoco


@dataclass(frozen=True)
class Ground:
    """The ground and the feet: MuJoCo's friction coefficient and contact softness (``solref``)."""

    friction: float = 1.0
    solref: tuple[float, float] = (0.02, 1.0)


def physics_urdf(path: str | Path) -> str:
    """The URDF's text without ``<visual>`` and ``<collision>`` elements (bodies, joints, inertias only)."""
    path = Path(path)
    if not path.is_file():
        raise RobotFileError(f"robot file not found: {str(path)!r}")
    text = path.read_text()
    text = re.sub(r"<visual\b.*?</visual>", "", text, flags=re.S)
    return re.sub(r"<collision\b.*?</collision>", "", text, flags=re.S)


def example_robot_urdf(name: str) -> Path:
    """The URDF file of an example-robot-data robot (``"romeo"``)."""
    from example_robot_data import robots_loader

    loaders = {"romeo": robots_loader.RomeoLoader}
    if name not in loaders:
        from hqp_tpm.errors import unknown_name

        raise unknown_name("floating-base robot", name, list(loaders))
    loader = loaders[name]
    return Path(robots_loader.getModelPath(f"{loader.path}/{loader.urdf_subpath}/{loader.urdf_filename}")) / (
        f"{loader.path}/{loader.urdf_subpath}/{loader.urdf_filename}")


def floating_spec(robot: Robot, urdf: str | Path, soles: dict, *, ground: Ground = Ground(), timestep: float = 1e-3,
                  integrator: str = "implicitfast"):
    """The ``mujoco.MjSpec`` of ``robot`` (free-flyer, 1-DOF joints by name) standing on a ground plane.

    ``soles``: sole frame (a body of the URDF) -> ``((cx, cy), (hx, hy))``, its box in the sole frame.
    """
    mujoco = mujoco_module()
    if not robot.has_free_flyer:
        raise ParameterError(f"robot {robot.name!r} has no free-flyer base")
    spec = mujoco.MjSpec.from_string(physics_urdf(urdf))
    spec.compiler.fusestatic = False
    spec.compiler.discardvisual = True
    spec.option.timestep = float(timestep)
    integrators = {"euler": mujoco.mjtIntegrator.mjINT_EULER, "implicitfast": mujoco.mjtIntegrator.mjINT_IMPLICITFAST,
                   "rk4": mujoco.mjtIntegrator.mjINT_RK4, "implicit": mujoco.mjtIntegrator.mjINT_IMPLICIT}
    if integrator not in integrators:
        from hqp_tpm.errors import unknown_name

        raise unknown_name("integrator", integrator, list(integrators))
    spec.option.integrator = integrators[integrator]
    actuated = robot.joint_names[6:]
    for eq in list(spec.equalities):  # the URDF's mimic joints (Romeo's fingers), locked below
        spec.delete(eq)
    for joint in list(spec.joints):
        if joint.name not in actuated:
            spec.delete(joint)
    missing = [j for j in actuated if spec.joint(j) is None]
    if missing:
        raise RobotFileError(f"{urdf}: joints {missing} of robot {robot.name!r} are not in the URDF")
    root = spec.worldbody.first_body()
    root.add_freejoint(name=robot.model.names[1])
    for frame, ((cx, cy), (hx, hy)) in soles.items():
        body = spec.body(frame)
        if body is None:
            raise RobotFileError(f"{urdf}: no link {frame!r} for a sole box")
        body.add_geom(name=f"{frame}_box", type=mujoco.mjtGeom.mjGEOM_BOX, size=[hx, hy, SOLE_THICKNESS / 2],
                      pos=[cx, cy, SOLE_THICKNESS / 2], friction=[ground.friction, 0.005, 0.0001],
                      solref=list(ground.solref), mass=0.0, contype=1, conaffinity=1, condim=3)
    spec.worldbody.add_geom(name="ground", type=mujoco.mjtGeom.mjGEOM_PLANE, size=[0, 0, 1],
                            friction=[ground.friction, 0.005, 0.0001], contype=1, conaffinity=1)
    spec.worldbody.add_light(pos=[0, 0, 3], dir=[0, 0, -1])
    for name, effort in zip(actuated, robot.model.effortLimit[6:], strict=True):
        act = spec.add_actuator(name=name, target=name, trntype=mujoco.mjtTrn.mjTRN_JOINT)
        act.gainprm[0] = 1.0
        if np.isfinite(effort) and effort > 0:
            act.ctrllimited = True
            act.ctrlrange = [-float(effort), float(effort)]
    return spec


def standing_base(robot: Robot, q: np.ndarray, soles) -> np.ndarray:
    """``q`` with its base placed so that the lowest sole frame lies on the ground (z = 0), above the origin."""
    q = np.array(q, dtype=float)
    q[:7] = [0, 0, 0, 0, 0, 0, 1]
    data = robot.model.createData()
    pin.framesForwardKinematics(robot.model, data, q)
    feet = np.array([data.oMf[robot.frame_id(f)].translation for f in soles])
    q[:2] = -feet[:, :2].mean(axis=0)
    q[2] = -feet[:, 2].min()
    return q

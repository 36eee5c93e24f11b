"""The MuJoCo model of a robot, built from the robot's own URDF (the file the controller's model came from).

:func:`robot_urdf` finds that file (a project robot, a URDF path, an example-robot-data robot);
:func:`plant_xml` turns it into one MJCF text: visuals dropped, ``package://`` mesh paths made absolute,
no inertia from geometry (the URDF's inertials only, as pinocchio), the URDF's collision cylinders marked
as capsules (``<collision_checking><capsule/>``) made capsules as
pinocchio reads them, a free joint named after pinocchio's root joint for a floating base, joints a reduced
robot locked removed, the plant options' armature, damping, friction, timestep and integrator, one
torque motor per actuated joint (in pinocchio's velocity order, limited to the URDF's ``effort`` when
``torque_limits``), the contacts asked for and pinocchio's gravity. The plant compiles exactly this text,
so the text is the exact model it simulated (``plant.xml`` of a run).
"""

from __future__ import annotations

import os
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pinocchio as pin

from hqp_tpm.errors import PlantError
from hqp_tpm.plants.frames import body_of_frame
from hqp_tpm.plants.options import PlantOptions
from hqp_tpm.robot.model import Robot

#: Mesh formats MuJoCo reads.
MESH_FORMATS = (".stl", ".obj", ".msh")

#: Mass (kg) and inertia (kg m^2) given to a moving link the URDF leaves without mass (MuJoCo rejects them).
MIN_MASS, MIN_INERTIA = 1e-6, 1e-9


def mujoco_module():
    """The ``mujoco`` module, or a :class:`PlantError` saying how to install it."""
    try:
        import mujoco
    except ImportError as exc:
        raise PlantError(f"the MuJoCo plant needs the mujoco package ({exc}); install it with "
                         "`pip install hqp-tpm[sim]` or `pip install mujoco`") from None
    return mujoco


def robot_urdf(robot: Robot) -> tuple[Path, list[Path]]:
    """The URDF the robot was loaded from and the folders its ``package://`` paths are looked up in."""
    source = robot.source or ""
    path = Path(source)
    if source and path.is_file():
        return path, [path.parent, path.parent.parent]
    if source.startswith("example-robot-data:"):
        from example_robot_data import robots_loader

        name = source.split(":", 1)[1].split()[0]
        loaders = getattr(robots_loader, "ROBOTS", {})
        if name not in loaders:
            raise PlantError(f"robot {robot.name!r}: example-robot-data has no loader {name!r} to find its URDF")
        loader = loaders[name]()
        urdf = Path(getattr(loader, "df_path", None) or loader.urdf_path)
        model_path = Path(loader.model_path)  # .../share/example-robot-data/robots
        return urdf, [model_path, model_path.parent.parent, urdf.parent, urdf.parent.parent]
    raise PlantError(f"robot {robot.name!r}: no URDF to build the plant from (source {source!r}); load it from a "
                     "URDF path, a project robot name or an example-robot-data name")


def _mesh_path(filename: str, urdf: Path, dirs: list[Path]) -> str:
    """An absolute path for a URDF mesh reference (``package://pkg/rest``, relative or absolute)."""
    if filename.startswith("package://"):
        pkg, _, rest = filename[len("package://"):].partition("/")
        candidates = [d / pkg / rest for d in dirs] + [d / rest for d in dirs]
    elif filename.startswith("file://"):
        candidates = [Path(filename[len("file://"):])]
    else:
        candidates = [urdf.parent / filename]
    found = next((c for c in candidates if c.is_file()), None)
    if found is None:
        raise PlantError(f"{urdf}: mesh {filename!r} not found (looked in {', '.join(map(str, candidates))})")
    if found.suffix.lower() not in MESH_FORMATS:
        raise PlantError(f"{urdf}: mesh {found.name!r} is {found.suffix!r}, which MuJoCo does not read (it reads "
                         f"{', '.join(MESH_FORMATS)}): convert it, or build the plant with collision = false")
    return str(found.resolve())


def clean_urdf(urdf: Path, dirs: list[Path], collision: bool) -> tuple[str, set[str]]:
    """The URDF text without visuals (and without collisions unless ``collision``), mesh paths absolute; and the
    names of the collision cylinders the file marks as capsules."""
    try:
        root = ET.parse(urdf).getroot()
    except (OSError, ET.ParseError) as exc:
        raise PlantError(f"cannot read robot file {str(urdf)!r}: {exc}") from exc
    capsules = set()
    for link in root.iter("link"):
        for check in list(link.findall("collision_checking")):
            capsules |= {c.get("name") for c in check.findall("capsule")}
            link.remove(check)
        for tag in ("visual",) if collision else ("visual", "collision"):
            for el in list(link.findall(tag)):
                link.remove(el)
    for mesh in root.iter("mesh"):
        mesh.set("filename", _mesh_path(mesh.get("filename", ""), urdf, dirs))
    return ET.tostring(root, encoding="unicode"), capsules


def plant_xml(robot: Robot, period: float, options: PlantOptions | None = None, geoms=()) -> str:
    """The MJCF text of the plant of ``robot`` stepped every ``period`` seconds (see the module docstring);
    ``geoms``: contact-free :class:`~hqp_tpm.plants.distances.ExtraGeom` s to add (distance checks)."""
    mujoco = mujoco_module()
    options = PlantOptions() if options is None else options
    urdf, dirs = robot_urdf(robot)
    text, capsules = clean_urdf(urdf, dirs, options.collision)
    try:
        spec = mujoco.MjSpec.from_string(text)
    except (ValueError, RuntimeError) as exc:
        raise PlantError(f"MuJoCo cannot read {str(urdf)!r}: {exc}") from exc
    spec.compiler.discardvisual = False  # visuals are gone already; contact-free collision geoms must stay
    spec.compiler.inertiafromgeom = mujoco.mjtInertiaFromGeom.mjINERTIAFROMGEOM_FALSE  # the URDF's inertials only
    spec.compiler.fusestatic = False
    spec.strippath = False
    spec.modelname = robot.name
    spec.option.timestep = period / options.substeps(period)
    spec.option.integrator = getattr(mujoco.mjtIntegrator, f"mjINT_{options.integrator.upper()}")
    spec.option.gravity = np.array(robot.model.gravity.linear, dtype=float)
    model = robot.model
    names = set(model.names[1:])
    if robot.has_free_flyer:
        spec.worldbody.first_body().add_freejoint(name=model.names[1])
    for joint in list(spec.joints):
        if joint.type != mujoco.mjtJoint.mjJNT_FREE and joint.name not in names:
            spec.delete(joint)  # locked in a reduced robot (at 0, its neutral value)
    kept = {j.name for j in spec.joints}
    for eq in list(spec.equalities):  # a URDF's mimic joints (Romeo's fingers) tie joints removed just above
        if eq.type == mujoco.mjtEq.mjEQ_JOINT and not {eq.name1, eq.name2} - {""} <= kept:
            spec.delete(eq)
    for joint in spec.joints:
        if joint.type != mujoco.mjtJoint.mjJNT_FREE:
            joint.armature = options.armature + _model_armature(model, joint.name)
            joint.frictionloss = options.friction
            joint.damping = [options.damping, 0.0, 0.0]  # (linear, and MuJoCo 4's higher-order terms)
    for body in spec.bodies:  # a moving body with no mass of its own nor on the bodies welded to it
        if body.name != "world" and len(body.joints) and _welded_mass(body) <= 0:
            body.mass, body.inertia = MIN_MASS, [MIN_INERTIA] * 3
    contype = 1 if (options.floor or options.self_collision) else 0
    for geom in spec.geoms:
        if geom.type == mujoco.mjtGeom.mjGEOM_CYLINDER and geom.name in capsules:
            geom.type = mujoco.mjtGeom.mjGEOM_CAPSULE  # same radius, same half-length of the cylindrical part
        geom.contype, geom.conaffinity = contype, 1 if options.self_collision else 0
    if options.floor:
        spec.worldbody.add_geom(name="floor", type=mujoco.mjtGeom.mjGEOM_PLANE, size=[0, 0, 1], contype=0,
                                conaffinity=1)
    _add_geoms(mujoco, spec, model, geoms)
    for jid in range(1, model.njoints):
        joint = model.joints[jid]
        if joint.nv != 1:
            continue
        act = spec.add_actuator(name=model.names[jid], target=model.names[jid], trntype=mujoco.mjtTrn.mjTRN_JOINT)
        act.set_to_motor()
        effort = float(model.effortLimit[joint.idx_v])
        if options.torque_limits and np.isfinite(effort) and effort > 0:
            act.ctrllimited, act.ctrlrange = True, [-effort, effort]
        else:
            act.ctrllimited = False
    try:
        spec.compile()
    except (ValueError, RuntimeError) as exc:
        raise PlantError(f"MuJoCo cannot compile the plant of {robot.name!r} ({urdf}): {exc}") from exc
    return precise_xml(spec.to_xml(), spec)


def _add_geoms(mujoco, spec, model, geoms) -> None:
    """Geoms at pinocchio frames or in the world (no mass: inertia comes from the URDF); contact-free unless asked."""
    bodies = {b.name for b in spec.bodies}
    types = {"sphere": mujoco.mjtGeom.mjGEOM_SPHERE, "capsule": mujoco.mjtGeom.mjGEOM_CAPSULE,
             "box": mujoco.mjtGeom.mjGEOM_BOX}
    for g in geoms:
        if g.frame is None:
            body, placement = spec.worldbody, g.placement
        else:
            name, offset = body_of_frame(model, bodies, g.frame)
            body, placement = (spec.worldbody if name == "world" else spec.body(name)), offset * g.placement
        quat = pin.Quaternion(placement.rotation)
        body.add_geom(name=g.name, type=types[g.kind], size=[*g.size, *[0.0] * (3 - len(g.size))],
                      pos=placement.translation, quat=[quat.w, quat.x, quat.y, quat.z],
                      contype=1 if g.contact else 0, conaffinity=0, group=3)


#: MJCF attributes (per element) whose numbers :func:`precise_xml` writes from the spec in full precision.
_PRECISE = {
    "body": {"pos": "pos", "quat": "quat"},
    "joint": {"pos": "pos", "axis": "axis", "range": "range", "armature": "armature", "damping": "damping",
              "frictionloss": "frictionloss", "actuatorfrcrange": "actfrcrange"},
    "geom": {"pos": "pos", "quat": "quat", "size": "size"},
    "general": {"ctrlrange": "ctrlrange"},
}


#: MJCF names of MuJoCo's integrators by ``mjtIntegrator`` value.
_INTEGRATOR_NAMES = {0: "Euler", 1: "RK4", 2: "implicit", 3: "implicitfast"}


def precise_xml(xml: str, spec) -> str:
    """``spec.to_xml()`` writes 6 significant digits (an inertia of 0.02419666 becomes 0.0241967, a mass
    matrix entry moves by 3e-8): the numbers of named bodies, inertials, joints, geoms and actuators written
    again from the spec with every digit (``repr``), so the text compiles to the model the spec describes."""
    root = ET.fromstring(xml)
    finders = {"body": spec.body, "joint": spec.joint, "geom": spec.geom, "general": spec.actuator}

    def rewrite(el, obj, attrs):
        for attr, field in attrs.items():
            if attr in el.attrib:
                tokens = len(el.attrib[attr].split())
                values = np.atleast_1d(np.asarray(getattr(obj, field), dtype=float)).ravel()[:tokens]
                el.set(attr, " ".join(repr(float(v)) for v in values))

    for tag, find in finders.items():
        for el in root.iter(tag):
            name = el.get("name")
            obj = find(name) if name else None
            if obj is None:
                continue
            rewrite(el, obj, _PRECISE[tag])
            if tag == "body":
                for inertial in el.findall("inertial"):
                    _precise_inertial(inertial, obj)
    option = root.find("option")
    if option is None:
        option = ET.Element("option")
        root.insert(1, option)
    option.set("timestep", repr(float(spec.option.timestep)))
    option.set("integrator", _INTEGRATOR_NAMES[int(spec.option.integrator)])  # written even when the default
    ET.indent(root, space="  ")
    return ET.tostring(root, encoding="unicode") + "\n"


def _precise_inertial(el, body) -> None:
    """An ``<inertial>`` from the spec's body, every digit: the full inertia matrix (rotated into the body frame
    when the spec holds it in a rotated frame) in place of the principal moments and axes."""
    el.set("pos", " ".join(repr(float(v)) for v in body.ipos))
    el.set("mass", repr(float(body.mass)))
    full = np.asarray(body.fullinertia, dtype=float)
    if np.isnan(full).any():  # principal moments and axes given as such
        el.set("diaginertia", " ".join(repr(float(v)) for v in body.inertia))
        el.set("quat", " ".join(repr(float(v)) for v in body.iquat))
        return
    xx, yy, zz, xy, xz, yz = full
    inertia = np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]])
    w, x, y, z = np.asarray(body.iquat, dtype=float) / np.linalg.norm(body.iquat)
    if not (x == 0 and y == 0 and z == 0):
        R = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                      [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                      [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
        inertia = R @ inertia @ R.T
    for attr in ("diaginertia", "quat"):
        el.attrib.pop(attr, None)
    el.set("fullinertia", " ".join(repr(float(inertia[i, j])) for i, j in ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2),
                                                                            (1, 2))))


def _welded_mass(body) -> float:
    """Mass of ``body`` and of the bodies welded to it (children without joints, recursively): Romeo's
    ``base_link`` has none of its own, but carries the trunk, so the free joint needs no made-up mass."""
    return float(body.mass) + sum(_welded_mass(c) for c in body.bodies if not len(c.joints))


def _model_armature(model, name: str) -> float:
    """The armature the controller's model itself has (pinocchio's ``model.armature``: rotor inertia)."""
    if not model.existJointName(name):
        return 0.0
    joint = model.joints[model.getJointId(name)]
    return float(np.asarray(model.armature)[joint.idx_v]) if joint.nv == 1 else 0.0


def compile_xml(xml: str):
    """``mujoco.MjModel`` of a plant's MJCF text (the plant and a replay compile the same text)."""
    mujoco = mujoco_module()
    try:
        return mujoco.MjModel.from_xml_string(xml)
    except (ValueError, RuntimeError) as exc:
        raise PlantError(f"MuJoCo cannot compile the plant model: {exc}") from exc


def write(path: str | os.PathLike, xml: str) -> Path:
    path = Path(path)
    path.write_text(xml)
    return path

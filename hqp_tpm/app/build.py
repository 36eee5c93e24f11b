"""Turn a parsed :class:`~hqp_tpm.app.scenario.Scenario` into robot, tasks, policy and controller
(:func:`build_run`: all of it in one :class:`~hqp_tpm.app.context.RunContext`)."""

from __future__ import annotations

import numpy as np

from hqp_tpm.app.context import RunContext
from hqp_tpm.app.policy_builders import POLICY_BUILDERS
from hqp_tpm.app.scenario import Scenario
from hqp_tpm.app.scenario_values import Section, number, vector
from hqp_tpm.control.controller import Controller
from hqp_tpm.control.policy import DistancePolicy, FixedStack, Policy
from hqp_tpm.control.stack import Stack
from hqp_tpm.errors import HqpTpmError, ScenarioError, shown
from hqp_tpm.references.trajectories import Constant, Harmonic, Hold
from hqp_tpm.robot.model import Robot
from hqp_tpm.solvers.registry import ANALYTIC, BOXED
from hqp_tpm.tasks import (
    CenterOfMass,
    Force,
    FrameOrientation,
    FramePose,
    FramePosition,
    Gains,
    JointLimit,
    Manipulability,
    Pointing,
    Posture,
    QuaternionOrientation,
)


def trajectory(sec: Section, key: str, dim: int):
    """``target``: a list (constant), ``"hold"``/absent (start value), or a table ``{type = "harmonic", ...}``."""
    raw = sec.raw(key, None)
    if raw is None or raw == "hold":
        return Hold()
    if isinstance(raw, list):
        return Constant(value=sec.vector(key, dim))
    tab = sec.table(key)
    kind = tab.string("type", choices=("harmonic", "constant", "line", "dmp"))
    if kind == "dmp":  # papers/004 Sec. 6: DMP with obstacle coupling, relative to the start value
        from hqp_tpm.references.dmp import Coupling, DmpTrajectory

        obs = tab.raw("obstacles", [])
        if not isinstance(obs, list):
            raise ScenarioError(f"{tab.where}.obstacles: expected a list of [x, y, z] points")
        pts = [vector(o, f"{tab.where}.obstacles[{i}]", 3) for i, o in enumerate(obs)]
        cp = Coupling(tab.number("gamma", 1000.0), tab.number("beta", 20.0 / np.pi), tab.number("eta", 50.0),
                      tab.number("d", 0.15))
        tr = DmpTrajectory(tab.vector("end", dim), tab.number("tau"), pts, cp, horizon=tab.number("horizon", None))
        tab.check_unused()
        return tr
    rel = tab.boolean("relative", False)
    if kind == "line":  # papers/004: straight line, trapezoidal velocity profile
        from hqp_tpm.references.line import Line

        tr = Line(start_point=tab.vector("start", dim), end_point=tab.vector("end", dim), v_max=tab.number("v_max"),
                  a_max=tab.number("a_max"), t_start=tab.number("t_start", 0.0), relative=rel)
    elif kind == "constant":
        tr = Constant(value=tab.vector("value", dim), relative=rel)
    else:
        tr = Harmonic(center=tab.vector("center", dim), cos_amplitude=tab.vector("cos_amplitude", dim),
                      sin_amplitude=tab.vector("sin_amplitude", dim), omega=tab.number("omega"),
                      phase=tab.number("phase", 0.0), relative=rel)
    tab.check_unused()
    return tr


def gains(sec: Section) -> Gains:
    return Gains(kp=sec.number("kp", 1.0), kd=sec.number("kd", 0.0))


def _axes(sec: Section) -> str:
    axes = sec.string("axes", "xyz")
    if not axes or any(a not in "xyz" for a in axes) or len(set(axes)) != len(axes):
        raise ScenarioError(f"{sec.where}.axes: {axes!r} must be distinct letters among 'x', 'y', 'z'")
    return axes


def _frame_position(robot, sec):
    axes = _axes(sec)
    return FramePosition(robot, sec.string("frame"), trajectory(sec, "target", len(axes)), gains(sec),
                         axes=axes, name=sec.string("name"))


def _frame_orientation(robot, sec):
    return FrameOrientation(robot, sec.string("frame"), None, gains(sec), name=sec.string("name"))


def _frame_pose(robot, sec):
    return FramePose(robot, sec.string("frame"), None, gains(sec), name=sec.string("name"))


def _pointing(robot, sec):
    alpha = np.deg2rad(sec.number("alpha_d_deg")) if sec.has("alpha_d_deg") else sec.number("alpha_d")
    # rad/s^2; absent or false: none, papers/000 as written (docs/pointing_drift.md)
    limit = None if sec.raw("drift_limit", False) is False else sec.number("drift_limit", None)
    return Pointing(robot, sec.string("frame"), sec.vector("axis", 3), alpha, gains(sec),
                    inequality=sec.boolean("inequality", True), name=sec.string("name"), drift_limit=limit)


def _com(robot, sec):
    axes = _axes(sec)
    return CenterOfMass(trajectory(sec, "target", len(axes)), gains(sec), axes=axes, name=sec.string("name"))


def _posture(robot, sec):
    joints = sec.raw("joints", None)
    task = Posture(robot, None, gains(sec), joints=joints, name=sec.string("name"))
    task.trajectory = trajectory(sec, "target", task.dim)
    return task


def _joints(sec):
    joints = sec.raw("joints", None)
    if joints is not None and (not isinstance(joints, list) or not all(isinstance(j, str) for j in joints)):
        raise ScenarioError(f"{sec.where}.joints: expected a list of joint names")
    return joints


def _force(robot, sec):
    return Force(robot, sec.string("frame"), None, gains(sec), target=sec.vector("target", 3, [0.0, 0.0, 0.0]),
                 name=sec.string("name"))


def _quaternion_orientation(robot, sec):
    target = sec.raw("target", None)
    if target is not None and target != "hold":
        target = sec.vector("target", 9)
    return QuaternionOrientation(robot, sec.string("frame"), target, gains(sec), axes=sec.string("axes", "xy"),
                                 name=sec.string("name"))


def _manipulability(robot, sec):
    return Manipulability(robot, sec.number("target", 2.0), gains(sec), joints=_joints(sec), name=sec.string("name"))


def _joint_limit(robot, sec):
    return JointLimit(robot, [0.0], gains(sec), joints=_joints(sec), name=sec.string("name"))


TASK_BUILDERS = {
    "frame_position": _frame_position,
    "frame_orientation": _frame_orientation,
    "frame_pose": _frame_pose,
    "pointing": _pointing,
    "com": _com,
    "posture": _posture,
    "force": _force,
    "quaternion_orientation": _quaternion_orientation,
    "manipulability": _manipulability,
    "joint_limit": _joint_limit,
}


def build_task(robot: Robot, sec: Section):
    kind = sec.string("type")
    if kind not in TASK_BUILDERS:
        raise ScenarioError(f"{sec.where}.type: unknown task type {kind!r}; valid types: "
                            f"{', '.join(sorted(TASK_BUILDERS))}")
    try:
        task = TASK_BUILDERS[kind](robot, sec)
    except ScenarioError:
        raise
    except (HqpTpmError, ValueError) as exc:
        raise ScenarioError(f"{sec.where} ({kind}): {exc}") from exc
    sec.check_unused()
    return task


def initial_configuration(robot: Robot, sec: Section) -> np.ndarray:
    """``q`` (radians, full vector), ``q_deg``, or ``joints_deg = {name = value}`` on top of neutral or of the
    robot's reference configuration ``reference = "half_sitting"`` (:meth:`Robot.reference`)."""
    if sec.has("q"):
        q = np.array(sec.vector("q", robot.nq))
    elif sec.has("q_deg"):
        q = np.deg2rad(sec.vector("q_deg", robot.nq))
    else:
        joints = sec.raw("joints_deg", {})
        if not isinstance(joints, dict):
            raise ScenarioError(f"{sec.where}.joints_deg: expected a table of joint = degrees")
        values = {k: np.deg2rad(number(v, f"{sec.where}.joints_deg.{k}")) for k, v in joints.items()}
        where = f"{sec.where}.reference" if sec.has("reference") else f"{sec.where}.joints_deg"
        try:
            q = robot.configuration(values, base=None, reference=sec.string("reference", None))
        except HqpTpmError as exc:
            raise ScenarioError(f"{where}: {exc}") from exc
    _check_within_limits(robot, q, sec.where)
    return q


#: An initial joint value may lie outside its position limits by at most this fraction of the joint's range.
LIMIT_SLACK = 0.1


def _check_within_limits(robot: Robot, q: np.ndarray, where: str) -> None:
    """Reject an initial configuration far outside the joint limits (a typo such as degrees given as radians)."""
    lo, up = robot.position_limits()
    for jid in range(1, robot.model.njoints):
        j = robot.model.joints[jid]
        if j.nq != 1 or j.nv != 1 or not (np.isfinite(lo[j.idx_v]) and np.isfinite(up[j.idx_v])):
            continue
        a, b, v = lo[j.idx_v], up[j.idx_v], q[j.idx_q]
        slack = LIMIT_SLACK * (b - a)
        if not (a - slack <= v <= b + slack):
            raise ScenarioError(f"{where}: joint {robot.model.names[jid]!r} = {v:g} rad ({np.rad2deg(v):g} deg) is "
                                f"outside its limits [{a:g}, {b:g}] rad by more than {LIMIT_SLACK:.0%} of the range")


def obstacles_from(sc: Scenario) -> list:
    """The scenario's ``[[obstacles]]``: spheres (radius 0 = point), boxes, capsules."""
    from hqp_tpm.geometry.obstacles import Obstacle

    out = []
    for sec in sc.obstacles:
        kind = sec.string("type", choices=("sphere", "point", "box", "capsule"))
        name = sec.string("name")
        motion = {}
        if sec.has("velocity"):
            motion["velocity"] = sec.vector("velocity", 3)
        try:
            if kind in ("sphere", "point"):
                out.append(Obstacle.sphere(name, sec.vector("center", 3), sec.number("radius", 0.0), **motion))
            elif kind == "box":
                out.append(Obstacle.box(name, sec.vector("center", 3), sec.vector("half_extents", 3), **motion))
            else:
                out.append(Obstacle.capsule(name, sec.vector("a", 3), sec.vector("b", 3), sec.number("radius"),
                                            **motion))
        except ScenarioError:
            raise
        except (HqpTpmError, ValueError) as exc:  # the geometry's own check (a negative radius, ...)
            field = next((k for k in ("radius", "half_extents") if k in sec.data and k in str(exc)), None)
            raise ScenarioError(f"{sec.where}{'.' + field if field else ''} ({kind}): {exc}") from exc
        sec.check_unused()
    return out


def build_policy(sc: Scenario, robot: Robot, tasks: dict, obstacles: list) -> Policy:
    sec = sc.policy
    kind = sec.string("type", "fixed")
    if kind == "fixed":
        levels = sec.raw("levels", None)
        if levels is None:
            stack = Stack.of(*tasks.values())
        else:
            if not isinstance(levels, list):
                raise ScenarioError(f"{sec.where}.levels: expected a list of task names or lists of names")
            out = []
            first: dict = {}  # task name -> the level it is in
            for i, lv in enumerate(levels):
                names = [lv] if isinstance(lv, str) else lv
                if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
                    raise ScenarioError(f"{sec.where}.levels[{i}]: expected a task name or a list of task names, "
                                        f"got {shown(lv)}")
                for n in names:
                    if n not in tasks:
                        raise ScenarioError(f"{sec.where}.levels[{i}]: unknown task {n!r}; tasks: "
                                            f"{', '.join(tasks)}")
                    if n in first:
                        raise ScenarioError(f"{sec.where}.levels[{i}]: task {n!r} is repeated (already in "
                                            f"levels[{first[n]}]); a task may appear once in a stack")
                    first[n] = i
                out.append(tuple(tasks[n] for n in names))
            stack = Stack(out)
        sec.check_unused()
        return FixedStack(stack)
    if kind not in POLICY_BUILDERS:
        raise ScenarioError(f"{sec.where}.type: unknown policy {kind!r}; valid: "
                            f"{', '.join(['fixed', *sorted(POLICY_BUILDERS)])}")
    return POLICY_BUILDERS[kind](sc, robot, tasks, sec, obstacles)


def check_start_outside_obstacles(sc: Scenario, robot: Robot, policy: Policy, q0: np.ndarray) -> None:
    """Refuse a start with the robot entirely inside an obstacle (every element of the policy's distance field at
    a negative distance from it) or an element deeper inside one than the robot's own size (the diameter of the
    bounding sphere of its elements): a modelling error (an obstacle placed or sized wrongly), not a situation the
    avoidance can answer. Policies without a distance field are not checked."""
    from hqp_tpm.robot.state import State

    if not isinstance(policy, DistancePolicy):  # the contract of a policy that owns a distance field
        return
    field = policy.field
    if not field.n_obstacles or not field.n_elements:
        return
    snap = field.snapshot()
    try:
        field.update(State(robot).update(q0, np.zeros(robot.nv), 0.0).data, None, 0.0)
        D = np.where(field.computed, field.distance, np.inf)
        centers, radii = field.bounding_spheres()
    finally:
        field.restore(snap)
    size = 2.0 * float((np.linalg.norm(centers - centers.mean(axis=0), axis=1) + radii).max())
    where = {sec.data.get("name"): (i, sec) for i, sec in enumerate(sc.obstacles)}
    for j, ob in enumerate(field.obstacles):
        d = D[:, j]
        k = int(np.argmin(d))
        inside = bool((d < 0.0).all())
        if not (inside or d[k] < -size):
            continue
        i, sec = where.get(ob.name, (None, None))
        at = sec.where if sec is not None else f"{sc.path.name}.obstacles"
        what = ("the robot starts entirely inside it (every one of its " f"{field.n_elements} elements)" if inside
                else f"{field.names[k]!r} starts deeper inside it than the robot's own size ({size:.3g} m)")
        raise ScenarioError(f"{at} ({ob.name!r}): {what}: distance {d[k]:.4g} m at {field.names[k]!r}; an "
                            "obstacle that holds the robot is a modelling error (check its center and size, or the "
                            "initial configuration)")


def build_run(sc: Scenario, solver: str | None = None) -> RunContext:
    """Robot, tasks, policy, controller and what the runner, results, figures and viewer need."""
    if sc.limits is not None and solver in ANALYTIC:  # an override (--solver) that would ignore the file's box
        raise ScenarioError(f"solver {solver!r} (given for this run, e.g. --solver) ignores the hard joint box of "
                            f"{sc.limits.where}; valid: a boxed solver ({', '.join(BOXED)}, qp, qp:<backend>), or "
                            "the scenario's own solver")
    try:
        robot = Robot.load(sc.robot)
    except HqpTpmError as exc:
        raise ScenarioError(f"{sc.path.name}.scenario.robot: {exc}") from exc
    tasks = {t.string("name"): build_task(robot, t) for t in sc.tasks}
    q0 = initial_configuration(robot, sc.initial)
    if sc.plant is not None and sc.plant.contacts is not None:  # standing on the ground (hqp_tpm.app.plant_run)
        from hqp_tpm.app.plant_run import contact_soles
        from hqp_tpm.plants.humanoid import standing_base

        q0 = standing_base(robot, q0, contact_soles(sc, tasks))
    v0 = np.zeros(robot.nv)
    obstacles = obstacles_from(sc)
    try:
        policy = build_policy(sc, robot, tasks, obstacles)
    except (HqpTpmError, ValueError) as exc:  # a policy's own check (e.g. thresholds): name the file and section
        if isinstance(exc, ScenarioError) and sc.path.name in str(exc):
            raise
        raise ScenarioError(f"{sc.policy.where}: {exc}") from exc
    limits = None
    if sc.limits is not None:
        from hqp_tpm.robot.limits import JointLimits

        lim = sc.limits
        limits = JointLimits(robot, order=sc.order, dt=sc.period, position=lim.boolean("position", True),
                             velocity=lim.boolean("velocity", True),
                             acceleration_limit=lim.number("acceleration_limit", 50.0),
                             velocity_scale=lim.number("velocity_scale", 1.0),
                             # the command's change per step <= acceleration_limit * period (velocity level; at
                             # acceleration level the box bounds qdd itself); false: papers/002's box
                             command_rate=lim.boolean("command_rate", True) and sc.order == 1)
        lim.check_unused()
    ctrl = Controller(robot, policy, order=sc.order, dt=sc.period, solver=solver or sc.solver,
                      lambda_max=sc.lambda_max, eps=sc.eps, nullspace_damping=sc.nullspace_damping,
                      box=limits, q0=q0, v0=v0)
    sc.initial.check_unused()
    check_start_outside_obstacles(sc, robot, policy, q0)
    scene = policy.scene()
    if not scene.obstacles:
        scene.obstacles = list(obstacles)
    return RunContext(sc, robot, ctrl, tasks, policy, obstacles, limits, scene)


def build(sc: Scenario, solver: str | None = None):
    """``(robot, controller, tasks, policy)`` of a scenario (:func:`build_run` gives the whole context)."""
    ctx = build_run(sc, solver)
    return ctx.robot, ctx.controller, ctx.tasks, ctx.policy

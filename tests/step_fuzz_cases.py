"""Random control set-ups for ``tests/test_step_fuzz.py``: a case is plain data (a :class:`Case`: robot, settings, a
stack or policy of task recipes, events between steps), built into as many identical controllers as asked
(:func:`build`), so that two of them can be stepped in lock-step, one by ``ctrl.step()`` and one by
``ctrl.step(record=True)``, with every event applied to both.

A task recipe is ``(kind, name, params)``; :func:`make_task` turns it into a new task object (each controller gets
its own, so that nothing is shared between the two). :func:`draw_case` draws a case from a numpy generator.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin

from hqp_tpm import (
    CenterOfMass,
    Constant,
    Controller,
    FrameOrientation,
    FramePose,
    FramePosition,
    Gains,
    Harmonic,
    JointLimit,
    JointLimits,
    Manipulability,
    PlanningPolicy,
    Pointing,
    Posture,
    QuaternionOrientation,
    Robot,
    Stack,
    StackPolicy,
    Trajectory,
)
from hqp_tpm.robot.state import State
from hqp_tpm.tasks.avoidance import Avoidance
from hqp_tpm.tasks.base import Task

#: The robots of the cases and the frames their frame tasks use.
FRAMES = {
    "iiwa7": ("iiwa_ee", "iiwa_link_4", "iiwa_link_6"),
    "lwr4": ("lwr_ee", "lwr_link_4", "lwr_link_3"),
    "planar5": ("planar5_ee", "planar5_link_3", "planar5_link_4"),
    "romeo21": ("r_gripper", "l_gripper", "r_sole", "l_sole"),
    "talos": ("arm_left_7_link", "arm_right_7_link", "left_sole_link", "right_sole_link"),
}

_ROBOTS: dict[str, Robot] = {}


def robot(name: str) -> Robot:
    if name not in _ROBOTS:
        _ROBOTS[name] = Robot.load(name)
    return _ROBOTS[name]


# -- user-defined task and trajectory (the public extension points) ------------------------------------------
class JointSum(Task):
    """A user's task: ``x = sum q[cols]`` (1 row); ``bad`` makes its Jacobian non-finite (a faulty user task)."""

    dim = 1

    def __init__(self, robot: Robot, cols, target, gains=None, name="joint_sum"):
        self.cols = np.asarray(cols, dtype=int)
        self.qidx = np.array([robot.model.joints[robot.model.getJointId(robot.joint_names[c])].idx_q
                              for c in self.cols], dtype=int)
        self.nv = robot.nv
        self.bad = False
        super().__init__(name, target, gains)

    def value(self, state):
        return np.array([float(state.q[self.qidx].sum())])

    def jacobian(self, state):
        J = np.zeros((1, self.nv))
        J[0, self.cols] = np.nan if self.bad else 1.0
        return J

    def jdot_qdot(self, state):
        return np.zeros(1)


class Glitch(Trajectory):
    """A user's trajectory: ``base``'s reference with every entry replaced by ``bad`` (NaN, or too large)."""

    def __init__(self, base: Trajectory, bad: float):
        super().__init__()
        object.__setattr__(self, "base", base)
        object.__setattr__(self, "bad", bad)

    def reference(self, t):
        x, xd, xdd = self.base.reference(t)
        return np.full_like(x, self.bad), xd, xdd


class InPlace(Trajectory):
    """A user's trajectory that writes its reference into the same (writable) arrays at every call."""

    def __init__(self, center, amplitude):
        super().__init__()
        for k, value in (("center", np.array(center)), ("amplitude", np.array(amplitude)),
                         ("out", tuple(np.zeros(len(center)) for _ in range(3)))):
            object.__setattr__(self, k, value)

    def reference(self, t):
        x, xd, xdd = self.out
        x[...] = self.center + self.amplitude * math.sin(3.0 * t)
        xd[...] = 3.0 * self.amplitude * math.cos(3.0 * t)
        xdd[...] = -9.0 * self.amplitude * math.sin(3.0 * t)
        return self.out


class ShiftedHarmonic(Harmonic):
    """A user's subclass of Harmonic with its own reference (not the Harmonic's terms)."""

    def reference(self, t):
        x, xd, xdd = super().reference(t)
        return x + 0.01, xd, xdd


class OffsetPosition(FramePosition):
    """A user's subclass of FramePosition that changes its error (its rows are then its own methods')."""

    def error(self, state, x_d):
        return super().error(state, x_d) + 0.001


# -- recipes ---------------------------------------------------------------------------------------------------
def _trajectory(spec):
    kind = spec[0]
    if kind == "hold":
        return None
    if kind == "const":
        return np.array(spec[1])
    if kind == "rel_const":
        return Constant(value=np.array(spec[1]), relative=True)
    if kind == "harmonic":
        _, c, a, b, w, phase, relative = spec
        return Harmonic(center=np.array(c), cos_amplitude=np.array(a), sin_amplitude=np.array(b), omega=w,
                        phase=phase, relative=relative)
    raise ValueError(spec)


def make_task(recipe, rob: Robot) -> Task:
    kind, name, p = recipe
    g = Gains(*p["gains"])
    if kind == "offset_position":
        return OffsetPosition(rob, p["frame"], _trajectory(p["target"]), g, axes=p["axes"], name=name)
    if kind == "position":
        return FramePosition(rob, p["frame"], _trajectory(p["target"]), g, axes=p["axes"], name=name)
    if kind == "com":
        return CenterOfMass(rob, _trajectory(p["target"]), g, axes=p["axes"], name=name)
    if kind == "posture":
        return Posture(rob, _trajectory(p["target"]), g, joints=p["joints"], name=name)
    if kind == "pose":
        target = None if p["target"] is None else pin.SE3(np.array(p["target"][0]), np.array(p["target"][1]))
        return FramePose(rob, p["frame"], target, g, name=name)
    if kind == "orientation":
        return FrameOrientation(rob, p["frame"], None if p["target"] is None else np.array(p["target"]), g, name=name)
    if kind == "quaternion":
        return QuaternionOrientation(rob, p["frame"], None if p["target"] is None else np.array(p["target"]), g,
                                     axes=p["axes"], name=name)
    if kind == "joint_limit":
        return JointLimit(rob, (0.0,), g, joints=p["joints"], name=name)
    if kind == "manipulability":
        return Manipulability(rob, p["target"], g, joints=p["joints"], name=name)
    if kind == "pointing":
        return Pointing(rob, p["frame"], p["axis"], p["alpha"], g, inequality=p["inequality"], name=name)
    if kind == "joint_sum":
        return JointSum(rob, p["cols"], np.array([p["target"]]), g, name=name)
    if kind == "avoid":
        task = Avoidance(name, p["dim"])
        task.spec = p  # (the policy assigns its pair every step)
        return task
    raise ValueError(kind)


# -- policies (the planned step's two kinds) ---------------------------------------------------------------------
def _assign_avoidance(task: Avoidance, rob: Robot, state: State) -> None:
    """A repulsion of ``task.spec['frame']`` from a point obstacle (the policy's update, as Algorithm 1's field)."""
    p = task.spec
    fid = rob.frame_id(p["frame"])
    d = state.position(fid) - np.asarray(p["obstacle"])
    dist = float(np.linalg.norm(d))
    n = d / dist
    magnitude = p["gain"] * max(0.0, p["reach"] - dist)
    task.assign(state.jacobian(fid)[:3].copy(), state.jdot_qdot(fid)[:3].copy(), n, magnitude)


class ScheduledStacks(StackPolicy):
    """A stack policy: ``stacks[k]`` while ``t`` is in the ``k``-th window of ``period`` (round robin); its avoidance
    tasks assigned in :meth:`update`; ``blend > 0``: the command blended with the next stack's solution (eq. (8) of
    papers/003 in spirit: ``(1 - blend) x + blend x_next``)."""

    def __init__(self, rob: Robot, stacks: list[Stack], period: float, blend: float = 0.0):
        self.rob, self.stacks, self.period, self.weight = rob, stacks, period, blend
        self.blends = blend > 0.0
        self._tasks = list({id(t): t for s in stacks for t in s.tasks()}.values())

    def tasks(self):
        return self._tasks

    def _index(self, t: float) -> int:
        return int(math.floor(t / self.period + 1e-9)) % len(self.stacks)

    def update(self, state, t):
        for task in self._tasks:
            if type(task) is Avoidance:
                _assign_avoidance(task, self.rob, state)

    def __call__(self, state, t):
        return self.stacks[self._index(t)]

    def blend(self, state, t, stack, x, resolve):
        other = self.stacks[(self._index(t) + 1) % len(self.stacks)]
        return (1.0 - self.weight) * x + self.weight * resolve(other)


class ScheduledPlan(PlanningPolicy):
    """A planning policy: ``plans[k]`` (one task per level) in the ``k``-th window of ``period``, with extra
    commands (a drift ``amp * sin(t + i)`` per row) for the tasks named in ``extras``."""

    def __init__(self, rob: Robot, plans: list[tuple[Task, ...]], period: float, extras: dict[str, float]):
        self.rob, self.plans, self.period, self.extras = rob, plans, period, extras
        self._tasks = list({id(t): t for p in plans for t in p}.values())

    def tasks(self):
        return self._tasks

    def update(self, state, t):
        for task in self._tasks:
            if type(task) is Avoidance:
                _assign_avoidance(task, self.rob, state)

    def plan(self, state, t):
        tasks = self.plans[int(math.floor(t / self.period + 1e-9)) % len(self.plans)]
        extras = {task.name: self.extras[task.name] * np.sin(t + np.arange(task.dim))
                  for task in tasks if task.name in self.extras}
        return tasks, extras


# -- a case ------------------------------------------------------------------------------------------------------
@dataclass
class Case:
    robot: str
    order: int
    solver: str
    q0: np.ndarray
    v0: np.ndarray
    levels: list                       # of lists of task recipes
    policy: str = "fixed"              # "fixed", "stacks", "plan"
    policy_params: dict = field(default_factory=dict)
    lambda_max: float = 0.0
    eps: float = 0.0
    damping: float = 0.0
    box: dict | None = None            # JointLimits' keyword arguments
    steps: int = 10
    dt: float = 1e-3
    events: dict = field(default_factory=dict)  # step -> list of events (applied before that step)

    def describe(self) -> str:
        lv = " > ".join("+".join(f"{r[0]}:{r[1]}" for r in level) for level in self.levels)
        events = {k: [e[0] for e in v] for k, v in self.events.items()}
        return (f"Case(robot={self.robot}, order={self.order}, solver={self.solver}, policy={self.policy} "
                f"{self.policy_params}, lambda_max={self.lambda_max}, eps={self.eps}, damping={self.damping}, "
                f"box={self.box}, dt={self.dt}, steps={self.steps}, stack={lv}, events={events})")


def build(case: Case) -> tuple[Controller, dict[str, Task]]:
    """A controller of ``case`` with its own task objects, and its tasks by name."""
    rob = robot(case.robot)
    tasks: dict[str, Task] = {}
    levels = []
    for level in case.levels:
        made = []
        for recipe in level:
            task = make_task(recipe, rob)
            tasks[task.name] = task
            made.append(task)
        levels.append(tuple(made))
    if case.policy == "fixed":
        policy = Stack(levels)
    elif case.policy == "stacks":
        k = case.policy_params["split"]
        stacks = [Stack(levels), Stack(levels[k:] + levels[:k])]
        policy = ScheduledStacks(rob, stacks, case.policy_params["period"], case.policy_params["blend"])
    else:
        flat = tuple(t for lv in levels for t in lv)
        k = case.policy_params["split"]
        plans = [flat, flat[k:] + flat[:k] if k < len(flat) else flat[::-1]]
        policy = ScheduledPlan(rob, plans, case.policy_params["period"], case.policy_params["extras"])
    box = None if case.box is None else JointLimits(rob, order=case.order, dt=case.dt, **case.box)
    ctrl = Controller(rob, policy, order=case.order, dt=case.dt, solver=case.solver, lambda_max=case.lambda_max,
                      eps=case.eps, nullspace_damping=case.damping, box=box, q0=case.q0, v0=case.v0)
    return ctrl, tasks


# -- drawing ------------------------------------------------------------------------------------------------------
def _gains(rng, order):
    kp = float(rng.choice([0.5, 5.0, 30.0, 100.0]))
    return (kp, float(2.0 * math.sqrt(kp) * rng.uniform(0.5, 1.5)) if order == 2 else 0.0)


def _vector_target(rng, x0, spread):
    """A target spec for a vector task whose value is ``x0`` now."""
    d = x0.size
    kind = rng.choice(["const", "const", "rel_const", "harmonic", "harmonic_rel", "hold"])
    if kind == "const":
        return ("const", (x0 + rng.normal(0.0, spread, d)).tolist())
    if kind == "rel_const":
        return ("rel_const", rng.normal(0.0, spread, d).tolist())
    if kind == "hold":
        return ("hold",)
    relative = kind == "harmonic_rel"
    center = (rng.normal(0.0, spread, d) if relative else x0 + rng.normal(0.0, spread, d)).tolist()
    return ("harmonic", center, rng.normal(0.0, spread, d).tolist(), rng.normal(0.0, spread, d).tolist(),
            float(rng.uniform(0.5, 6.0)), float(rng.uniform(-3, 3)), relative)


def _subset(rng, items, low=1):
    k = int(rng.integers(low, len(items) + 1))
    return [items[i] for i in sorted(rng.choice(len(items), size=k, replace=False))]


def _axes(rng):
    return "".join(rng.permutation(list("xyz"))[: int(rng.integers(1, 4))])


def _rotation_near(rng, R0, spread=0.3):
    return (pin.exp3(rng.normal(0.0, spread, 3)) @ R0).tolist()


def draw_task(rng, rob: Robot, st: State, order: int, kinds, name: str, absolute: bool = False):
    """A task recipe of one of ``kinds`` near the robot's state ``st`` (``absolute``: no relative or held target:
    a task added after the start)."""
    kind = str(rng.choice(kinds))
    frame = str(rng.choice(FRAMES[rob.name]))
    fid = rob.frame_id(frame)
    g = _gains(rng, order)
    joints = [n for n in rob.joint_names if not rob.has_free_flyer or rob.joint_names.index(n) >= 6]

    def target(x0, spread):
        while True:
            spec = _vector_target(rng, x0, spread)
            if not absolute or spec[0] == "const" or (spec[0] == "harmonic" and not spec[-1]):
                return spec

    if kind in ("position", "offset_position"):
        axes = _axes(rng)
        rows = ["xyz".index(a) for a in axes]
        return (kind, name, {"frame": frame, "axes": axes, "gains": g, "target": target(st.position(fid)[rows], 0.05)})
    if kind == "com":
        axes = _axes(rng)
        rows = ["xyz".index(a) for a in axes]
        return (kind, name, {"axes": axes, "gains": g, "target": target(st.com()[rows], 0.02)})
    if kind == "posture":
        sub = _subset(rng, joints)
        cols = [rob.joint_index(j) for j in sub]
        return (kind, name, {"joints": sub, "gains": g, "target": target(st.q[[_qidx(rob, c) for c in cols]], 0.2)})
    if kind in ("pose", "orientation", "quaternion"):
        M = st.placement(fid)
        held = not absolute and rng.random() < 0.3
        if kind == "pose":
            tgt = None if held else (_rotation_near(rng, M.rotation), (M.translation + rng.normal(0, 0.05, 3)).tolist())
            return (kind, name, {"frame": frame, "gains": g, "target": tgt})
        tgt = None if held else _rotation_near(rng, M.rotation)
        params = {"frame": frame, "gains": g, "target": tgt}
        if kind == "quaternion":
            params["axes"] = _axes(rng)
        return (kind, name, params)
    if kind == "joint_limit":
        return (kind, name, {"joints": _subset(rng, joints), "gains": g})
    if kind == "manipulability":
        sub = _subset(rng, joints)
        return (kind, name, {"joints": sub, "gains": g, "target": float(rng.uniform(0.1, 0.5 * len(sub)))})
    if kind == "pointing":
        z = st.rotation(fid)[:, 2]
        axis = pin.exp3(rng.normal(0.0, 0.4, 3)) @ z
        return (kind, name, {"frame": frame, "axis": axis.tolist(), "alpha": float(rng.uniform(0.05, 0.6)),
                             "inequality": bool(rng.random() < 0.7), "gains": g})
    if kind == "joint_sum":
        cols = [rob.joint_index(j) for j in _subset(rng, joints)]
        x0 = float(sum(st.q[_qidx(rob, c)] for c in cols))
        return (kind, name, {"cols": cols, "gains": g, "target": x0 + float(rng.normal(0.0, 0.2))})
    if kind == "avoid":
        p = st.position(fid)
        return (kind, name, {"frame": frame, "dim": int(rng.choice([1, 3])), "gains": (1.0, 0.0),
                             "obstacle": (p + rng.normal(0.0, 0.15, 3)).tolist(), "reach": 0.3,
                             "gain": float(rng.uniform(0.5, 5.0))})
    raise ValueError(kind)


def _qidx(rob: Robot, col: int) -> int:
    return rob.model.joints[rob.model.getJointId(rob.joint_names[col])].idx_q


#: The task kinds by where they go: a fixed stack's (equality rows the compiled step writes, rows of the tasks'
#: own methods, inequality rows), a policy's (avoidance: assigned by its update).
FIXED_KINDS = ("position", "position", "pose", "orientation", "com", "posture", "posture", "joint_limit",
               "manipulability", "quaternion", "joint_sum", "pointing", "offset_position")
POLICY_KINDS = (*FIXED_KINDS, "avoid")


def start_state(rng, rob: Robot, order: int):
    """A configuration inside the limits (and, at order 2, a velocity)."""
    q = rob.neutral()
    lo, up = rob.position_limits()
    for c in range(rob.nv):
        if np.isfinite(lo[c]) and np.isfinite(up[c]):
            mid, half = 0.5 * (lo[c] + up[c]), 0.5 * (up[c] - lo[c])
            q[_qidx(rob, c)] = mid + rng.uniform(-0.6, 0.6) * half
    if rob.has_free_flyer:
        q[:3] = rng.normal(0.0, 0.05, 3)
        q[3:7] = pin.Quaternion(pin.exp3(rng.normal(0.0, 0.1, 3))).coeffs()
    v = rng.normal(0.0, 0.3, rob.nv) if order == 2 else np.zeros(rob.nv)
    return q, v


def draw_case(rng, robot_name: str, order: int, solver: str, policy: str, n_levels: int, steps: int,
              n_events: int) -> Case:
    rob = robot(robot_name)
    q0, v0 = start_state(rng, rob, order)
    st = State(rob).update(q0, v0, 0.0)
    kinds = FIXED_KINDS if policy == "fixed" else POLICY_KINDS
    if policy == "plan" or (policy == "stacks" and rng.random() < 0.5):  # the planned step at order 2: no inequality
        kinds = tuple(k for k in kinds if k != "pointing" or order == 1 or policy == "stacks")
    levels, count = [], 0
    for _ in range(n_levels):
        level = []
        for _ in range(1 if policy == "plan" else int(rng.choice([1, 1, 1, 2]))):
            level.append(draw_task(rng, rob, st, order, kinds, f"t{count}"))
            count += 1
        levels.append(level)
    damped = rng.random() < 0.5
    case = Case(robot_name, order, solver, q0, v0, levels, policy=policy,
                lambda_max=float(rng.choice([0.01, 0.05])) if damped else 0.0,
                eps=float(rng.choice([0.02, 0.1])) if damped else 0.0,
                damping=float(rng.choice([0.0, 0.0, 5.0])) if order == 2 else 0.0, steps=steps)
    if solver != "tpm" and solver != "nullspace" and rng.random() < 0.85:
        case.box = {"velocity_scale": float(rng.choice([0.05, 0.3, 1.0]))}
        if order == 1 and rng.random() < 0.3:
            case.box["command_rate"] = True
        if rng.random() < 0.2:  # (no position limits: the box of the readable formulas, not the kernel's)
            case.box["position"] = False
        if rng.random() < 0.3:
            case.box["acceleration_limit"] = float(rng.choice([5.0, 200.0]))
    if rng.random() < 0.2:
        case.dt = 4e-3
    if policy != "fixed":
        names = [r[1] for lv in levels for r in lv]
        case.policy_params = {"split": int(rng.integers(0, max(1, len(levels)))), "period": float(rng.choice([3e-3,
                                                                                                              5e-3])),
                              "blend": float(rng.choice([0.0, 0.0, 0.3])) if policy == "stacks" else 0.0,
                              "extras": {n: float(rng.uniform(-0.5, 0.5)) for n in names if rng.random() < 0.3}}
    for _ in range(n_events):
        k = int(rng.integers(1, steps))
        case.events.setdefault(k, []).append(draw_event(rng, rob, st, case))
    return case


EVENTS = ("target", "target", "trajectory", "harmonic_edit", "gains", "add_level", "remove_level", "replace_level",
          "replace_policy", "settings", "set_state", "glitch", "glitch", "bad_rows", "compute", "solver", "box", "copy",
          "restart", "mix")


def draw_event(rng, rob, st, case: Case):
    kind = str(rng.choice(EVENTS))
    names = [r[1] for lv in case.levels for r in lv]
    pick = str(rng.choice(names))
    if kind in ("target", "trajectory", "harmonic_edit", "restart"):
        return (kind, pick, int(rng.integers(1 << 30)))
    if kind == "gains":
        return (kind, pick, _gains(rng, case.order))
    if kind in ("add_level", "replace_level"):
        kinds = tuple(k for k in (FIXED_KINDS if case.policy == "fixed" else POLICY_KINDS) if k != "avoid")
        recipe = draw_task(rng, rob, st, case.order, kinds, f"n{int(rng.integers(1 << 20))}", absolute=True)
        return (kind, recipe, int(rng.integers(0, 8)))
    if kind == "remove_level":
        return (kind, int(rng.integers(0, 8)))
    if kind == "replace_policy":
        return (kind, int(rng.integers(1 << 30)))
    if kind == "settings":
        return (kind, float(rng.choice([0.0, 0.02, 0.05])), float(rng.choice([0.0, 0.05, 0.1])),
                float(rng.choice([0.0, 3.0])))
    if kind == "set_state":
        return (kind, rng.normal(0.0, 0.02, rob.nv).tolist(), rng.normal(0.0, 0.1, rob.nv).tolist())
    if kind == "solver" and case.solver.startswith("qp"):
        return ("compute",)
    if kind == "solver":  # another solver of the same kind (boxed or not)
        if case.policy != "fixed":
            return (kind, str(rng.choice(["tpm", "sns_tpm"])))
        return (kind, str(rng.choice(["sns_tpm", "sns"] if case.box is not None else ["tpm", "nullspace"])))
    if kind == "box":  # the box replaced (None: taken away)
        if case.box is None:
            return ("compute",)
        return (kind, None if rng.random() < 0.3 else {"velocity_scale": float(rng.choice([0.05, 0.3, 1.0]))})
    if kind == "glitch":  # (not on a pointing cone: its reference, see test_step_fuzz.py's xfail)
        vector = [r[1] for lv in case.levels for r in lv if r[0] not in ("pointing", "avoid")]
        if not vector:
            return ("compute",)
        return (kind, str(rng.choice(vector)), float(rng.choice([np.nan, np.inf, 1e160, 1e153])))
    return (kind,)

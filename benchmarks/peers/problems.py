"""The problems of the side-by-side benchmark, defined once for every contender.

Each problem is a robot (loaded with :meth:`hqp_tpm.robot.Robot.load`; the peers load the same URDF
or the same reduced pinocchio model), a priority stack, gains, and 200 seeded configurations with
their targets. The contenders (:mod:`benchmarks.peers.contenders`) read the targets from here and
express them in their own API; hqp-tpm's stack is built here (:func:`hqp_controller`), and its first
level is the common yardstick of the quality numbers (top-level residual).

Problems (velocity level unless said otherwise; ``dt`` = 1 ms):

* ``iiwa_vel``: KUKA LBR iiwa 7, end-effector pose (6 rows) > posture (7 rows, a conflicting random
  posture). EE target: the pose at a configuration 0.05 rad (std) away; kp = 10 (EE), 1 (posture).
* ``romeo_vel``: Romeo, 21 joints + free-flyer (nv = 27), the ``romeo_sns_tpm`` scenario's stack, gains and
  damping: right-sole pose (6) > CoM x-y (2) > left-foot position (3) > left-hand position (3) > right-hand
  position (3), kp = 100, ``lambda_max`` = 0.05, ``eps`` = 0.1, plus a posture level of the 21 joints (kp = 1) that
  makes m > n; targets 0.5-2 cm (std) away, the posture target the scenario's initial posture (configurations:
  0.1 rad std around it). (The scenario's command-rate bound is left out: one configuration has no previous
  command.)
* ``iiwa_acc``: iiwa, acceleration level, EE pose (priority 0) + posture; kp = 100, kd = 20 (EE),
  kp = 10, kd = 2 sqrt(10) (posture); random joint velocities (std 0.3 rad/s).
* ``iiwa_circle``: closed loop from one configuration: the EE position follows a 10 cm circle (one turn
  per second) with the orientation held, > posture held; 2,000 steps (velocity level, kp 10 / 1; the
  acceleration-level variant kp 100, kd 20 / kp 10, kd 2 sqrt(10)).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pinocchio as pin

DT = 1e-3
N_CONFIGS = 200
SEED = 14

IIWA = "iiwa7"
IIWA_EE = "iiwa_ee"
ROMEO = "romeo21"

KP_EE, KP_POSTURE = 10.0, 1.0                               # velocity level
KP_EE_ACC, KD_EE_ACC = 100.0, 20.0                          # acceleration level
KP_POSTURE_ACC, KD_POSTURE_ACC = 10.0, 2.0 * math.sqrt(10.0)
KP_ROMEO, KP_ROMEO_POSTURE = 100.0, 1.0                     # the romeo_tpm / romeo_sns_tpm scenarios' kp
ROMEO_LAMBDA_MAX, ROMEO_EPS = 0.05, 0.1                     # ... and their damping
#: Every timed step assigns the targets again, alternating between the configuration's targets and these moved by
#: :data:`NUDGE` (m, rad): the targets move every step, as a user's do.
NUDGE = 1e-4

CIRCLE_RADIUS, CIRCLE_OMEGA, CIRCLE_STEPS = 0.1, 2.0 * math.pi, 2000

#: Romeo's initial posture of the romeo_tpm scenario (degrees), the centre of the configurations.
ROMEO_POSTURE_DEG = {"RHipPitch": -10.0, "RKneePitch": 20.0, "RAnklePitch": -10.0, "LHipPitch": -10.0,
                     "LKneePitch": 20.0, "LAnklePitch": -10.0, "RShoulderYaw": -45.0, "LShoulderYaw": 45.0}
ROMEO_FRAMES = {"right_sole": "r_sole", "left_foot": "l_sole", "left_hand": "l_gripper", "right_hand": "r_gripper"}


def load_robot(name: str):
    from hqp_tpm import Robot

    return Robot.load(name)


def urdf_path(robot) -> Path:
    """The URDF file a project robot was loaded from (layout-independent: read from the robot)."""
    for attr in ("urdf_path", "urdf", "path", "source"):
        val = getattr(robot, attr, None)
        if val and str(val).endswith(".urdf") and Path(str(val)).is_file():
            return Path(str(val))
    raise FileNotFoundError(f"robot {robot.name!r} has no URDF file attribute")


@dataclass
class Config:
    """One configuration of a problem with its targets (everything a contender needs)."""

    q: np.ndarray
    v: np.ndarray
    targets: dict = field(default_factory=dict)   # task name -> pin.SE3 / position / joint vector


@dataclass
class Problem:
    name: str
    robot_name: str
    order: int
    configs: list[Config]
    description: str = ""
    lambda_max: float = 0.0   # hqp-tpm's damping of the problem (the library's own where a scenario sets it)
    eps: float = 0.0


# -- configurations ------------------------------------------------------------------------------
def _joint_box(robot, scale: float):
    lo, up = robot.position_limits()
    cols = np.flatnonzero(np.isfinite(lo) & np.isfinite(up))
    mid = 0.5 * (lo[cols] + up[cols])
    half = 0.5 * (up[cols] - lo[cols]) * scale
    return cols, mid - half, mid + half


def _fk(robot, q):
    data = robot.model.createData()
    pin.framesForwardKinematics(robot.model, data, q)
    return data


def iiwa_problem(robot, order: int = 1, n: int = N_CONFIGS, seed: int = SEED) -> Problem:
    rng = np.random.default_rng(seed + order)
    _, lo, up = _joint_box(robot, 0.8)
    fid = robot.frame_id(IIWA_EE)
    configs = []
    for _ in range(n):
        q = rng.uniform(lo, up)
        q_t = np.clip(q + rng.normal(0.0, 0.05, q.size), lo, up)
        M = _fk(robot, q_t).oMf[fid].copy()
        posture = rng.uniform(0.6 * lo, 0.6 * up)
        v = rng.normal(0.0, 0.3, robot.nv) if order == 2 else np.zeros(robot.nv)
        configs.append(Config(q, v, {"ee": M, "posture": posture}))
    name = "iiwa_vel" if order == 1 else "iiwa_acc"
    desc = ("iiwa 7, EE pose (6) > posture (7), velocity level" if order == 1 else
            "iiwa 7, acceleration level, EE pose priority 0 + posture")
    return Problem(name, IIWA, order, configs, desc)


def romeo_q0(robot) -> np.ndarray:
    return robot.configuration({k: math.radians(v) for k, v in ROMEO_POSTURE_DEG.items()})


def romeo_problem(robot, n: int = N_CONFIGS, seed: int = SEED) -> Problem:
    rng = np.random.default_rng(seed + 7)
    q0 = romeo_q0(robot)
    lo, up = robot.position_limits()
    qidx = np.array([robot.model.joints[j].idx_q for j in range(2, robot.model.njoints)])
    vidx = np.array([robot.model.joints[j].idx_v for j in range(2, robot.model.njoints)])
    fids = {k: robot.frame_id(f) for k, f in ROMEO_FRAMES.items()}
    configs = []
    for _ in range(n):
        q = q0.copy()
        q[qidx] = np.clip(q0[qidx] + rng.normal(0.0, 0.1, qidx.size), lo[vidx] + 1e-3, up[vidx] - 1e-3)
        data = _fk(robot, q)
        pin.centerOfMass(robot.model, data, q)
        sole = data.oMf[fids["right_sole"]]
        d = pin.exp6(pin.Motion(rng.normal(0.0, 0.005, 3), rng.normal(0.0, 0.01, 3)))
        targets = {
            "right_sole": sole * d,
            "com": data.com[0][:2] + rng.normal(0.0, 0.005, 2),
            "left_foot": data.oMf[fids["left_foot"]].translation + rng.normal(0.0, 0.005, 3),
            "left_hand": data.oMf[fids["left_hand"]].translation + rng.normal(0.0, 0.02, 3),
            "right_hand": data.oMf[fids["right_hand"]].translation + rng.normal(0.0, 0.02, 3),
            "posture": q0[qidx].copy(),
        }
        configs.append(Config(q, np.zeros(robot.nv), targets))
    return Problem("romeo_vel", ROMEO, 1, configs,
                   "Romeo 27 nv, sole > CoM > foot > left hand > right hand > posture, velocity level",
                   ROMEO_LAMBDA_MAX, ROMEO_EPS)


def moved(targets: dict) -> dict:
    """``targets`` moved by :data:`NUDGE` (every position and joint target; poses: translation and a rotation about
    x), the second of the two target sets a timed step alternates between."""
    out = {}
    for k, t in targets.items():
        if isinstance(t, pin.SE3):
            out[k] = pin.SE3(pin.exp3(np.array([NUDGE, 0.0, 0.0])) @ t.rotation, t.translation + NUDGE)
        else:
            out[k] = np.asarray(t, dtype=float) + NUDGE
    return out


def circle_start(robot) -> np.ndarray:
    """The closed loop's start configuration (elbow bent, away from singularities and limits)."""
    return np.array([0.0, 0.6, 0.0, -1.2, 0.0, 0.8, 0.0])


def circle_reference(p0: np.ndarray, t: float):
    """EE position, velocity and acceleration on the circle (y-z plane) through ``p0`` at t = 0."""
    r, w = CIRCLE_RADIUS, CIRCLE_OMEGA
    c, s = math.cos(w * t), math.sin(w * t)
    p = p0 + np.array([0.0, r * s, r * (c - 1.0)])
    pd = np.array([0.0, r * w * c, -r * w * s])
    pdd = np.array([0.0, -r * w * w * s, -r * w * w * c])
    return p, pd, pdd


# -- hqp-tpm side --------------------------------------------------------------------------------
def hqp_tasks(robot, problem: Problem, cfg: Config):
    """hqp-tpm stack levels (highest first) for one configuration's targets."""
    from hqp_tpm import CenterOfMass, FramePose, FramePosition, Gains, Posture

    if problem.robot_name == IIWA:
        if problem.order == 1:
            ge, gp = Gains(KP_EE), Gains(KP_POSTURE)
        else:
            ge, gp = Gains(KP_EE_ACC, KD_EE_ACC), Gains(KP_POSTURE_ACC, KD_POSTURE_ACC)
        return [FramePose(robot, IIWA_EE, cfg.targets["ee"], ge, name="ee"),
                Posture(robot, cfg.targets["posture"], gp, name="posture")]
    g, gp = Gains(KP_ROMEO), Gains(KP_ROMEO_POSTURE)
    t = cfg.targets
    return [FramePose(robot, "r_sole", t["right_sole"], g, name="right_sole"),
            CenterOfMass(t["com"], g, axes="xy", name="com"),
            FramePosition(robot, "l_sole", t["left_foot"], g, name="left_foot"),
            FramePosition(robot, "l_gripper", t["left_hand"], g, name="left_hand"),
            FramePosition(robot, "r_gripper", t["right_hand"], g, name="right_hand"),
            Posture(robot, t["posture"], gp, name="posture")]


def assign_targets(tasks: dict, targets: dict) -> None:
    """Give each hqp-tpm task (by name) its target from ``targets`` through its public ``target`` property (as a user
    moving targets does, every step): a pose its ``pin.SE3``, the others their values."""
    for name, task in tasks.items():
        task.target = targets[name]


def joint_limits_box(robot, order: int):
    """hqp-tpm's joint box (URDF velocity limits, position limits one period ahead)."""
    from hqp_tpm import JointLimits

    return JointLimits(robot, order=order, dt=DT, position=True, velocity=True)


def hqp_controller(robot, problem: Problem, cfg: Config, solver: str = "tpm", tasks: list | None = None):
    """A controller at ``cfg`` with the problem's stack (``solver``: ``tpm``, ``sns_tpm``, ``qp:daqp``...) and
    damping; ``tasks``: the stack's tasks (:func:`hqp_tasks`) when the caller keeps them."""
    from hqp_tpm import Controller, Stack

    stack = Stack.of(*(tasks if tasks is not None else hqp_tasks(robot, problem, cfg)))
    box = joint_limits_box(robot, problem.order) if solver != "tpm" else None
    return Controller(robot, stack, order=problem.order, dt=DT, solver=solver, box=box, q0=cfg.q, v0=cfg.v,
                      lambda_max=problem.lambda_max, eps=problem.eps)


def hqp_circle_controller(robot, order: int, solver: str = "tpm"):
    """The closed loop of ``iiwa_circle`` in hqp-tpm: EE position on the circle + orientation held > posture."""
    from hqp_tpm import Controller, FrameOrientation, FramePosition, Gains, Harmonic, Posture, Stack

    q0 = circle_start(robot)
    fid = robot.frame_id(IIWA_EE)
    p0 = _fk(robot, q0).oMf[fid].translation.copy()
    r, w = CIRCLE_RADIUS, CIRCLE_OMEGA
    circle = Harmonic(center=p0 - np.array([0.0, 0.0, r]), cos_amplitude=np.array([0.0, 0.0, r]),
                      sin_amplitude=np.array([0.0, r, 0.0]), omega=w)
    if order == 1:
        ge, gp = Gains(KP_EE), Gains(KP_POSTURE)
    else:
        ge, gp = Gains(KP_EE_ACC, KD_EE_ACC), Gains(KP_POSTURE_ACC, KD_POSTURE_ACC)
    ee = (FramePosition(robot, IIWA_EE, circle, ge, name="ee_position"),
          FrameOrientation(robot, IIWA_EE, None, ge, name="ee_orientation"))
    stack = Stack.of(ee, Posture(robot, None, gp, name="posture"))
    box = joint_limits_box(robot, order) if solver != "tpm" else None
    ctrl = Controller(robot, stack, order=order, dt=DT, solver=solver, box=box, q0=q0)
    return ctrl, p0


def first_level(ctrl):
    """``(J, b)`` of the controller's highest level at its current state (the quality yardstick)."""
    res = ctrl.compute()
    lv = res.levels[0]
    return np.array(lv.J), np.array(lv.b)


def quality(J0, b0, x, v_max) -> tuple[float, float]:
    """Top-level residual ``|J0 x - b0|`` and the largest joint-velocity box violation of ``x`` (0 if inside)."""
    res = float(np.linalg.norm(J0 @ x - b0))
    viol = float(np.max(np.abs(x) - v_max, initial=0.0)) if v_max is not None else float("nan")
    return res, max(viol, 0.0) if viol == viol else viol

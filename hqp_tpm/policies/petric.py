"""Kinematic obstacle avoidance of papers/004 (Petrič, Gams, Likar, Žlajpah), velocity level, as stacks.

Every link-obstacle pair gives a *critical point* ``A_o`` (the nearest point of the arm to obstacle ``i``,
from the :class:`~hqp_tpm.geometry.distances.DistanceField` of the robot's link geometries) with distance ``d_i =
||d_o,i||`` and unit direction ``n_o`` (obstacle -> arm). Its avoidance task is one-dimensional, the reduced
operational space (14): ``J_do = n_o^T J_o`` (the 1-D :class:`~hqp_tpm.tasks.avoidance.Avoidance`), with the
avoiding velocity (15)-(16) ``xd_o = alpha_v v_o``, ``alpha_v = (d_m/d)^2 - 1`` below the critical distance
``d_m`` and 0 above it, and the smoothing gain (18) ``alpha_h`` (1 below ``d_m``, ``(1 + cos(pi (d - d_m)/(d_i -
d_m)))/2`` up to the influence distance ``d_i``, 0 beyond). (The printed (18) has ``1 - cos``: it rises from 0 at
``d_m`` to 1 at ``d_i``, the opposite of the text -- "between d_m and d_i only a part of the homogeneous solution
is included", "alpha_h close to zero ... while it is away from the obstacle" -- and jumps at ``d_m`` and at
``d_i``; the gain implemented here is the continuous one the text describes.)

The schemes (``scheme``), each as stacks solved by the controller's own solver (tpm, nullspace, qp...), the
combination done in the controller's ``blend`` hook with ``resolve`` (other stacks, same solver):

* ``"exact"``, (17) and (19)-(20): ``qd = x_E + sum_i w_i alpha_h,i (x_i - x_E)`` with ``x_E`` the solution of
  ``[ee]`` and ``x_i`` that of ``[ee > avoid_i]`` (``x_i - x_E`` is the homogeneous solution
  ``(J_do N)^# (xd_o - J_do J^# xd)`` of (11)), ``w_i`` (20) over the obstacles within ``d_i``
  (``combine = "nearest"``: the worst-case obstacle alone, the variant the paper improves on). The returned
  stack is ``[ee > avoid_nearest]``. (The paper compensates ``J_do J^# xd_e`` with the feed-forward velocity
  only; here the whole EE command ``xd = xd_d + K e`` (12), which the stack solution gives.)
* ``"approximate"``, (22)-(23): ``[ee > JointVelocity(sum_i J_do,i^# xd_o,i)]`` = ``J^# xd + N sum_i ...``
  (:mod:`hqp_tpm.tasks.joint_velocity`); no ``alpha_h`` in (22)-(23).
* ``"primary"``, (25): while the nearest obstacle is within ``d_m``, the avoidance is the primary task
  ``T_a`` and the EE task ``T_b`` secondary, else ``[ee]`` alone.
* ``"transition"``, (26)-(31) with ``lambda = alpha_h`` (30)-(31): ``qd = J_a^# xd_a + (I - alpha_h J_a^# J_a)
  J_b^# xd_b`` for the nearest obstacle, i.e. ``alpha_h x_P + (1 - alpha_h) (x_A + x_E)`` with ``x_P`` the
  primary-task solution (25), ``x_A`` the solution of ``[avoid]`` alone and ``x_E`` that of ``[ee]``.
* ``"pwdls"``, (37)-(39), Figs. 12-13: no hierarchy, ``qd = J_E^# xd_E`` for the EE task and the nearest
  obstacle's avoidance with priority factors ``p_ee`` and ``p_avoid / alpha_h`` (41) and damping
  ``pwdls_damping`` (:mod:`hqp_tpm.solvers.pwdls`): the avoidance weighs nothing at ``d_i`` and
  ``1/p_avoid`` from ``d_m``
  on, so the priority changes continuously (the paper leaves the choice of ``p_i`` open).

``secondary`` says what "secondary" means in (25)/(30): ``"projected"`` (default) the paper's printed
``N_a J_b^# xd_b`` (stack ``[avoid > JointVelocity(x_E)]``), ``"prioritized"`` the hierarchy of the solvers
``(J_b N_a)^# (xd_b - J_b J_a^# xd_a)`` (stack ``[avoid > ee]``); they differ in how much of the EE task
survives, not in the avoidance. The paper stops the main task below a distance ``d_b``; here ``alpha_v`` is only
held at its value at ``d_b`` below it (default 0.02 m: ``alpha_v`` = 99 with ``d_m`` = 0.2 m), so that a
penetration (``d <= 0``, where (16) is undefined) still pushes out along ``n_o``.

``probe`` records per step ``d_obstacle`` (smallest link-obstacle distance), ``d_obstacle_<name>`` per
obstacle, ``alpha_h`` and ``alpha_v`` of the nearest obstacle, ``transition_weight`` (the weight of the
avoidance-first solution: ``alpha_h`` for ``transition``, 1/0 for ``primary``, 0 otherwise),
``avoid_priority`` (0 no avoidance task, 1 below the EE task, 2 above it or, pwdls, weighted with it),
``active_obstacles`` (within ``d_i``) and ``avoid_rate`` (``J_do qd`` of the nearest obstacle's critical point,
m/s). ``hqp-tpm run --crosscheck`` compares the other solver's solution of the returned stack with the blended
command, so it reports the blend too; ``tests/test_planar_avoidance.py`` compares the blended commands of
both solvers.
"""

from __future__ import annotations

import math

import numpy as np

from hqp_tpm.control.policy import DistancePolicy, SceneItems, StackPolicy
from hqp_tpm.control.stack import Stack
from hqp_tpm.errors import ScenarioError, unknown_name
from hqp_tpm.geometry.distances import DistanceField
from hqp_tpm.geometry.obstacles import Obstacle
from hqp_tpm.robot.state import State
from hqp_tpm.solvers.pwdls import pwdls
from hqp_tpm.tasks.avoidance import Avoidance
from hqp_tpm.tasks.base import Task
from hqp_tpm.tasks.joint_velocity import JointVelocity

SCHEMES = ("exact", "approximate", "primary", "transition", "pwdls")
SECONDARY = ("projected", "prioritized")
COMBINE = ("weighted", "nearest")


def alpha_v(d: float, d_m: float) -> float:
    """Obstacle-avoidance gain (16): ``(d_m/d)^2 - 1`` below ``d_m``, else 0 (``inf`` at ``d <= 0``)."""
    if d >= d_m:
        return 0.0
    return math.inf if d <= 0.0 else (d_m / d) ** 2 - 1.0


def alpha_h(d: float, d_m: float, d_i: float) -> float:
    """Smoothing gain (18) as the text describes it: 1 up to ``d_m``, cosine down to 0 at ``d_i``."""
    if d <= d_m:
        return 1.0
    if d >= d_i:
        return 0.0
    return 0.5 * (1.0 + math.cos(math.pi * (d - d_m) / (d_i - d_m)))


def weights(d, d_i: float) -> np.ndarray:
    """Weights (20) of the obstacles at distances ``d`` (all within ``d_i``): ``(d_i - d_k)/sum(d_i - d)``."""
    g = d_i - np.asarray(d, dtype=float)
    s = g.sum()
    return g / s if s > 0 else np.full(g.shape, 1.0 / max(g.size, 1))


class LabeledStack(Stack):
    """A stack whose recorded label is the combination the policy actually commands."""

    def __init__(self, levels, text: str):
        super().__init__(levels)
        self.text = text

    def label(self) -> str:
        return self.text


class Petric(DistancePolicy, StackPolicy):
    """The avoidance schemes of papers/004 for an EE task and the link geometries of the robot."""

    blends = True

    def __init__(self, robot, ee_task: Task, obstacles: list[Obstacle], *, scheme: str = "exact",
                 d_m: float = 0.2, d_i: float = 0.3, v_o: float = 0.5, d_b: float = 0.02,
                 secondary: str = "projected", combine: str = "weighted", p_ee: float = 5.0, p_avoid: float = 1.0,
                 pwdls_damping: float = 0.01, record_range: float = 1.0):
        if scheme not in SCHEMES:
            raise unknown_name("scheme", scheme, SCHEMES, ScenarioError)
        if secondary not in SECONDARY:
            raise unknown_name("secondary", secondary, SECONDARY, ScenarioError)
        if combine not in COMBINE:
            raise unknown_name("combine", combine, COMBINE, ScenarioError)
        for name, v in (("d_m", d_m), ("d_i", d_i), ("v_o", v_o), ("d_b", d_b), ("record_range", record_range),
                        ("pwdls_damping", pwdls_damping)):
            if not (np.isfinite(v) and v >= 0):
                raise ScenarioError(f"petric policy: {name} = {v!r} must be finite and >= 0")
        if not (p_ee > 0 and p_avoid > 0):
            raise ScenarioError(f"petric policy: p_ee = {p_ee!r} and p_avoid = {p_avoid!r} must be > 0 (41)")
        if not 0 < d_b < d_m < d_i:
            raise ScenarioError(f"petric policy: need 0 < d_b < d_m < d_i, got d_b = {d_b!r}, d_m = {d_m!r}, "
                                f"d_i = {d_i!r}")
        if robot.collision_model is None or not len(robot.collision_model.geometryObjects):
            raise ScenarioError(f"petric policy: robot {robot.name!r} has no collision geometry (the links)")
        self.robot, self.ee_task, self.obstacles = robot, ee_task, list(obstacles)
        self.scheme, self.secondary, self.combine = scheme, secondary, combine
        self.p_ee, self.p_avoid, self.pwdls_damping = float(p_ee), float(p_avoid), float(pwdls_damping)
        self.d_m, self.d_i, self.v_o, self.d_b = float(d_m), float(d_i), float(v_o), float(d_b)
        self.field = DistanceField(robot.model, robot.collision_model, [], self.obstacles,
                                   surveillance=max(record_range, d_i))
        self.avoid = [Avoidance(f"avoid_{o.name}", 1) for o in self.obstacles]
        self.joint = JointVelocity(robot.nv, "nullspace_velocity")
        self.thresholds = {"d_obstacle": {"d_m": self.d_m, "d_i": self.d_i}}
        self.channels = ("d_obstacle", *(f"d_obstacle_{o.name}" for o in self.obstacles), "alpha_h", "alpha_v",
                         "avoid_rate", "transition_weight", "avoid_priority", "active_obstacles")
        self._crit: list[tuple[int, float]] = []  # (obstacle, distance) within d_i, nearest first
        self._last: dict = {}

    # hooks -------------------------------------------------------------------------------------
    def tasks(self) -> list[Task]:
        return [self.ee_task]

    def scene(self) -> SceneItems:
        return SceneItems(self.obstacles, ee_task=self.ee_task, field=self.field)

    # the critical points -----------------------------------------------------------------------
    def distances(self) -> np.ndarray:
        """Per obstacle: the distance of its critical point (nearest link), ``inf`` beyond the field's range."""
        f = self.field
        D = np.where(f.computed, f.distance, np.inf)
        return D.min(axis=0) if D.size else np.full(f.n_obstacles, np.inf)

    def _assign(self, state: State) -> None:
        """Critical point, J_do (14) and xd_o = alpha_v v_o (15) of every obstacle within d_i."""
        f = self.field
        D = np.where(f.computed, f.distance, np.inf)
        crit = []
        for j in range(f.n_obstacles):
            k = int(np.argmin(D[:, j]))
            d = float(D[k, j])
            if d < self.d_i:
                av = alpha_v(max(d, self.d_b), self.d_m)
                self.avoid[j].assign(f.jacobian(state.data, k, j), f.jdot_qdot(state.data, k, j), f.normal[k, j],
                                     av * self.v_o, f.p_robot[k, j])
                crit.append((j, d))
        crit.sort(key=lambda c: c[1])
        self._crit = crit

    def __call__(self, state: State, t: float) -> Stack:
        self._assign(state)
        ee, crit = self.ee_task, self._crit
        prio, weight = 0, 0.0
        if not crit:
            stack = Stack.of(ee)
        elif self.scheme == "exact":
            stack, prio = Stack.of(ee, self.avoid[crit[0][0]]), 1
        elif self.scheme == "approximate":
            qd0 = np.zeros(self.robot.nv)
            for j, _ in crit:
                a = self.avoid[j]
                J = a.jacobian(state)[0]
                jj = J.dot(J)
                if a.magnitude > 0 and jj > 1e-12:
                    qd0 += J * (a.magnitude / jj)  # J_do^# xd_o of (23): a 1-row pseudo-inverse, no inversion
            if qd0.any():
                self.joint.assign(qd0)
                stack, prio = Stack.of(ee, self.joint), 1
            else:
                stack = Stack.of(ee)
        elif self.scheme == "pwdls":  # (37)-(39) in blend; [ee] is solved first, unused
            a = self.avoid[crit[0][0]]
            weight = alpha_h(crit[0][1], self.d_m, self.d_i)
            stack, prio = LabeledStack([(ee,)], f"{a.name} ~ {ee.name} (pwdls)"), 2
        else:
            j, d = crit[0]
            weight = (1.0 if d < self.d_m else 0.0) if self.scheme == "primary" else alpha_h(d, self.d_m, self.d_i)
            if weight == 0.0:
                stack = Stack.of(ee)
            else:
                prio = 2
                a = self.avoid[j]
                if self.secondary == "prioritized":
                    stack = Stack.of(a, ee)
                else:  # [ee] is solved first; blend solves [avoid > JointVelocity(x_E)] (25)
                    stack = LabeledStack([(ee,)], f"{a.name} > {ee.name}")
                if self.scheme == "transition" and weight < 1.0:  # a partial priority (30): the weight is recorded
                    stack = LabeledStack(stack.levels, f"{a.name} >~ {ee.name}")
        self._last = {"priority": prio, "weight": weight}
        return stack

    def blend(self, state: State, t: float, stack: Stack, x: np.ndarray, resolve) -> np.ndarray:
        """The scheme's combination of stack solutions (see the module docstring)."""
        crit = self._crit
        if not crit or self._last["priority"] == 0:
            return x
        ee = self.ee_task
        if self.scheme == "exact":  # (19)-(20); x = solution of [ee > avoid_nearest]
            x_E = resolve(Stack.of(ee))
            if self.combine == "nearest":
                crit = crit[:1]
            w = weights([d for _, d in crit], self.d_i)
            out = x_E.copy()
            for (j, d), wj in zip(crit, w, strict=True):
                x_j = x if j == crit[0][0] else resolve(Stack.of(ee, self.avoid[j]))
                out += wj * alpha_h(d, self.d_m, self.d_i) * (x_j - x_E)
            return out
        if self.scheme == "approximate":
            return x
        if self.scheme == "pwdls":  # p of the avoidance p_avoid / alpha_h: no weight at d_i, p_avoid from d_m on
            a, lam = self.avoid[crit[0][0]], self._last["weight"]
            if lam == 0.0:
                return x
            levels = [ee.level(state, t, 1), a.level(state, t, 1)]
            return pwdls(levels, [self.p_ee, self.p_avoid / lam], self.pwdls_damping)
        j = crit[0][0]
        a = self.avoid[j]
        lam = self._last["weight"]
        if self.secondary == "prioritized":
            x_P = x
            x_E = resolve(Stack.of(ee)) if lam < 1.0 else None
        else:
            x_E = x
            self.joint.assign(x_E)
            x_P = resolve(Stack.of(a, self.joint))  # (25): J_a^# xd_a + N_a J_b^# xd_b
        if lam >= 1.0:
            return x_P
        x_A = resolve(Stack.of(a))  # J_a^# xd_a
        return lam * x_P + (1.0 - lam) * (x_A + x_E)  # (30)-(31)

    def probe(self, ctrl, res) -> dict:
        d = self.distances()
        out = {"d_obstacle": float(d.min()) if d.size and np.isfinite(d.min()) else np.nan}
        for o, dj in zip(self.obstacles, d, strict=True):
            out[f"d_obstacle_{o.name}"] = float(dj) if np.isfinite(dj) else np.nan
        if self._crit:
            j, dn = self._crit[0]
            out["alpha_h"] = alpha_h(dn, self.d_m, self.d_i)
            out["alpha_v"] = alpha_v(max(dn, self.d_b), self.d_m)  # the gain applied (held at d_b below it)
            out["avoid_rate"] = float(self.avoid[j].jacobian(ctrl.state)[0].dot(res.command))
        else:
            out["alpha_h"] = out["alpha_v"] = out["avoid_rate"] = 0.0
        out["transition_weight"] = float(self._last.get("weight", 0.0))
        out["avoid_priority"] = float(self._last.get("priority", 0))
        out["active_obstacles"] = float(len(self._crit))
        return out

    def summary(self, arrays: dict) -> dict:
        dt = float(arrays["t"][1] - arrays["t"][0]) if arrays["t"].size > 1 else 0.0
        d = arrays["d_obstacle"]
        return {"d_m": self.d_m, "d_i": self.d_i, "scheme": self.scheme, "secondary": self.secondary,
                "time_below_d_m_s": float((d < self.d_m).sum() * dt),
                "time_avoidance_primary_s": float((arrays["avoid_priority"] == 2).sum() * dt),
                "time_avoidance_secondary_s": float((arrays["avoid_priority"] == 1).sum() * dt)}

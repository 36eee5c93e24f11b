"""Whole-body collision avoidance on Romeo (issue 7): obstacles and self-collisions as priority levels.

Stack of every step (highest first)::

    sole hold > [avoid_obstacle] > [avoid_self] > CoM x-y > left foot > left hand > right hand

``avoid_obstacle`` is present while some robot-obstacle pair is closer than ``d_obstacle_activation``,
``avoid_self`` while the closest checked self pair is closer than ``d_self_activation``.

Collision model for control (:func:`control_geometries`): the romeo21 collision meshes of the arms
(upper arm, forearm, wrist roll, hand), the torso, the pelvis and the legs (thigh, shin, ankle), each
replaced by its convex hull (coal's Qhull). The head, the neck and the
tiny finger/thumb meshes are left out: the fingertips stick out of the hand hull by at most 1.3 cm
and the thumb by at most 2.2 cm, less than the safety distance ``d_obstacle_safe``.
Self pairs (:func:`self_pairs`): every arm part against the torso, pelvis and legs, and the forearm
and hand of one arm against the other arm, minus adjacent links (same joint, or joints connected
only through links without collision geometry) and minus the pairs ``romeo.srdf`` disables.

Avoidance rows (velocity level). For a pair at distance ``d`` with unit normal ``n`` (pointing away
from the obstacle / from the second body) and witness-point Jacobian ``J_c`` (self pairs:
``J_c = J_p1 - J_p2``), the distance rate is ``d_dot = n^T J_c qd``. The level asks

    ``n^T J_c qd >= r(d) = xi (d_a - d) / (d_a - d_s)``   (``d_a``: activation, ``d_s``: safety distance)

a *repulsive* velocity damper: zero at the activation distance, ``xi`` at the safety distance,
larger below. It is a one-sided inequality :class:`~hqp_tpm.solvers.levels.Level`
(``lower = r(d)``, ``upper = +inf``), the one formulation both solvers consume:

* the analytic SNS-TPM keeps an inequality row while it is violated by ``qd = 0``, i.e. while
  ``r(d) > 0`` -- always, since the level exists only for ``d < d_a`` -- and then tracks its bound as
  an equality: ``d_dot = r(d)`` exactly;
* the cascaded QP treats it as a true inequality: ``d_dot >= r(d)``.

Whenever the level is present the pair therefore separates (``d_dot >= r(d) > 0``), which keeps the
distance near ``d_a``; the runner's ``--crosscheck`` solves the active rows as equalities with the QP
(the SNS-TPM's own stack). The classical damper ``d_dot >= -xi (d - d_s)/(d_a - d_s)`` was not used:
its bound is negative (satisfied by ``qd = 0``), so the analytic solvers would never activate it.

With ``obstacle_rows = "per_obstacle"`` (default) the ``avoid_obstacle`` level has one row per
obstacle in range (its closest robot part): both hands may be near their obstacles at the same
time, and a single row would leave the other pair uncontrolled. ``"closest"``: one row, the closest
pair overall. The self level always has one row, the closest self pair.

Distances for control come from a field whose broad phase culls every pair whose bounding spheres are
farther apart than the activation distance (such a pair cannot be active: its distance is at least that lower
bound). ``probe`` records the nearest distances up to ``record_range`` from the same update and the few culled
pairs that could be nearer (:meth:`DistanceField.nearest_within
<hqp_tpm.geometry.distances.DistanceField.nearest_within>`: the numbers of a field updated at that range); the
viewer draws a second field at ``record_range`` (:attr:`WholeBody.record_field`, updated by the viewer).

``probe`` records ``d_obstacle`` (closest robot-obstacle distance), ``d_self`` (closest checked self
pair), ``n_avoid_obstacle`` and ``n_avoid_self`` (rows of the avoidance levels); the runner records
the stack label.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pinocchio as pin

from hqp_tpm.control.policy import DistancePolicy, PlanningPolicy, SceneItems, moving_targets
from hqp_tpm.errors import ParameterError, RobotFileError, ScenarioError
from hqp_tpm.geometry import _compiled as _kernels
from hqp_tpm.geometry.distances import DistanceField
from hqp_tpm.geometry.obstacles import Obstacle, convexified
from hqp_tpm.robot import _compiled
from hqp_tpm.robot.state import State
from hqp_tpm.tasks.avoidance import PairAvoidance
from hqp_tpm.tasks.base import Task

#: Arm parts (upper arm, forearm, wrist, hand) per side, torso/pelvis and legs of romeo21's collision model.
ARMS = {
    "L": ("LShoulderYawLink_0", "LElbowYawLink_0", "LWristRollLink_0", "l_wrist_0"),
    "R": ("RShoulderYawLink_0", "RElbowYawLink_0", "RWristRollLink_0", "r_wrist_0"),
}
TRUNK = ("body_0", "torso_0", "LHipPitchLink_0", "LKneePitchLink_0", "l_ankle_0",
         "RHipPitchLink_0", "RKneePitchLink_0", "r_ankle_0")
CONTROL_GEOMETRIES = (*ARMS["L"], *ARMS["R"], *TRUNK)


def romeo_srdf() -> Path:
    """``romeo.srdf`` of example-robot-data."""
    import example_robot_data as erd

    path = Path(erd.getModelPath("romeo_description/srdf/romeo.srdf")) / "romeo_description/srdf/romeo.srdf"
    if not path.is_file():
        raise RobotFileError(f"romeo.srdf not found at {path}")
    return path


def srdf_disabled_links(path: Path | None = None) -> set[frozenset[str]]:
    """Link pairs ``<disable_collisions link1 link2>`` of an SRDF (default: romeo.srdf)."""
    root = ET.parse(path or romeo_srdf()).getroot()
    return {frozenset((e.get("link1"), e.get("link2"))) for e in root.iter("disable_collisions")}


def _link(geometry_name: str) -> str:
    return geometry_name.rsplit("_", 1)[0]


def adjacent(model: pin.Model, geometry_model: pin.GeometryModel, a: str, b: str) -> bool:
    """Same joint, or one joint the nearest geometry-carrying ancestor of the other (links in between bare)."""
    carrying = {g.parentJoint for g in geometry_model.geometryObjects}
    ja = geometry_model.geometryObjects[geometry_model.getGeometryId(a)].parentJoint
    jb = geometry_model.geometryObjects[geometry_model.getGeometryId(b)].parentJoint

    def up(j):
        j = model.parents[j]
        while j > 0 and j not in carrying:
            j = model.parents[j]
        return j

    return ja == jb or up(ja) == jb or up(jb) == ja


def self_pairs(model: pin.Model, geometry_model: pin.GeometryModel, srdf: Path | None = None) -> list[tuple[str, str]]:
    """Arm parts against torso/pelvis/legs, forearm and hand against the other arm; no adjacent/SRDF pairs.

    The SRDF is applied with pinocchio: ``addAllCollisionPairs`` then ``removeCollisionPairs``.
    """
    gm = geometry_model.copy()
    gm.addAllCollisionPairs()
    pin.removeCollisionPairs(model, gm, str(srdf or romeo_srdf()))
    allowed = {frozenset((gm.geometryObjects[p.first].name, gm.geometryObjects[p.second].name))
               for p in gm.collisionPairs}
    candidates = [(a, b) for side in "LR" for a in ARMS[side] for b in TRUNK]
    candidates += [(a, b) for a in ARMS["L"] for b in ARMS["R"]
                   if a.startswith(("LElbow", "l_wrist")) or b.startswith(("RElbow", "r_wrist"))]
    return [(a, b) for a, b in candidates
            if frozenset((a, b)) in allowed and not adjacent(model, geometry_model, a, b)]


def control_geometries(robot, names=CONTROL_GEOMETRIES) -> pin.GeometryModel:
    """The selected collision geometries of ``robot``, BVH meshes as convex hulls (``coal.Convex.convexHull``)."""
    src = robot.collision_model
    gm = pin.GeometryModel()
    for name in names:
        if src is None or not src.existGeometryName(name):
            raise ScenarioError(f"robot {robot.name!r} has no collision geometry {name!r}")
        obj = pin.GeometryObject(src.geometryObjects[src.getGeometryId(name)])
        obj.geometry = convexified(obj.geometry, f"geometry {name!r}")
        gm.addGeometryObject(obj)
    return gm


def repulsive_bound(d, d_activation: float, d_safe: float, xi: float) -> np.ndarray:
    """``r(d) = xi (d_a - d)/(d_a - d_s)``: 0 at the activation distance, ``xi`` at the safety distance (a list of
    distances: each by Python's float operations, the IEEE operations numpy does, in fewer calls)."""
    def r(x):
        return xi * (d_activation - x) / (d_activation - d_safe)
    return np.array([r(float(x)) for x in d]) if type(d) is list else r(np.asarray(d, dtype=float))


class WholeBody(DistancePolicy, PlanningPolicy):
    """Dynamic stack: sole hold > obstacle avoidance > self avoidance > CoM > left foot > hands."""

    channels = ("d_obstacle", "d_self", "n_avoid_obstacle", "n_avoid_self")

    def __init__(self, robot, top: list[Task], below: list[Task], obstacles: list[Obstacle], *,
                 d_obstacle_activation: float = 0.10, d_obstacle_safe: float = 0.03, xi_obstacle: float = 0.3,
                 d_self_activation: float = 0.05, d_self_safe: float = 0.01, xi_self: float = 0.3,
                 obstacle_rows: str = "per_obstacle", record_range: float = 0.3,
                 geometries=CONTROL_GEOMETRIES, pairs=None):
        for what, da, ds in (("obstacle", d_obstacle_activation, d_obstacle_safe),
                             ("self", d_self_activation, d_self_safe)):
            if not 0.0 <= ds < da:
                raise ParameterError(f"{what}: need 0 <= d_safe < d_activation, got {ds}, {da}")
        if obstacle_rows not in ("per_obstacle", "closest"):
            raise ParameterError(f"obstacle_rows must be 'per_obstacle' or 'closest', got {obstacle_rows!r}")
        self.robot = robot
        self.top, self.below = list(top), list(below)
        self.obstacles = list(obstacles)
        self.d_obs = (float(d_obstacle_activation), float(d_obstacle_safe), float(xi_obstacle))
        self.d_self = (float(d_self_activation), float(d_self_safe), float(xi_self))
        self.obstacle_rows = obstacle_rows
        gm = control_geometries(robot, geometries)
        self.pairs = self_pairs(robot.model, robot.collision_model) if pairs is None else list(pairs)
        # control: pairs whose bounding spheres are farther apart than the activation distances cannot be
        # active, so the broad phase culls them (tests/test_whole_body.py); the record field (record_range) is the
        # viewer's; probe() reads the control field (DistanceField.nearest_within)
        self.field = DistanceField(robot.model, gm, (), self.obstacles, surveillance=d_obstacle_activation,
                                   self_pairs=self.pairs, self_surveillance=d_self_activation)
        self.record_field = DistanceField(robot.model, gm, (), self.obstacles,
                                          surveillance=max(record_range, d_obstacle_activation, d_self_activation),
                                          self_pairs=self.pairs)
        self.avoid_obstacle = PairAvoidance("avoid_obstacle")
        self.avoid_self = PairAvoidance("avoid_self")
        self.thresholds = {"d_obstacle": {"activation": d_obstacle_activation, "safe": d_obstacle_safe},
                           "d_self": {"activation": d_self_activation, "safe": d_self_safe}}
        self._last = {"n_avoid_obstacle": 0.0, "n_avoid_self": 0.0}
        self._closest = (np.zeros(len(self.obstacles), dtype=np.int64), np.zeros(len(self.obstacles)))

    def tasks(self) -> list[Task]:
        """Every task :meth:`plan` may stack, in stack order: the top tasks, the two avoidance levels, the rest (what
        the controller starts and ``--explain``/``hqp-tpm explain`` account for)."""
        return [*self.top, self.avoid_obstacle, self.avoid_self, *self.below]

    def scene(self) -> SceneItems:
        return SceneItems(self.obstacles, field=self.record_field, targets=moving_targets(self.tasks()))

    # ------------------------------------------------------------------ rows
    def obstacle_pairs(self) -> list[tuple[int, int, float]]:
        """(element, obstacle, distance) of the pairs to avoid: per obstacle (or overall) closest, within activation."""
        f = self.field
        if f.distance.size == 0:
            return []
        if self.obstacle_rows == "per_obstacle" and _compiled.ENABLED:  # one compiled call, the same choices
            element, value = self._closest
            if not _kernels.closest_per_column(f.distance, f.in_range, self.d_obs[0], element, value):
                return []
            return [(e, j, d) for j, (e, d) in enumerate(zip(element.tolist(), value.tolist(), strict=True)) if e >= 0]
        D = np.where(f.in_range, f.distance, np.inf)
        if self.obstacle_rows == "closest":
            e, j = np.unravel_index(int(np.argmin(D)), D.shape)
            d = float(D[e, j])
            return [(int(e), int(j), d)] if d < self.d_obs[0] else []
        closest = D.argmin(axis=0)  # per obstacle, its first nearest element (as np.argmin(D[:, j]) chooses)
        d = D[closest, np.arange(D.shape[1])].tolist()
        return [(e, j, d[j]) for j, e in enumerate(closest.tolist()) if d[j] < self.d_obs[0]]

    def plan(self, state: State, t: float) -> tuple[tuple[Task, ...], dict]:
        """This step's tasks, one per level (highest first), no extra command (``__call__`` wraps them in a
        :class:`Stack`; the planned step, :mod:`~hqp_tpm.control._planned_step`, writes their rows)."""
        f, data, model = self.field, state.data, self.robot.model
        levels: list[Task] = list(self.top)
        rows = self.obstacle_pairs()
        if rows:
            J = np.empty((len(rows), model.nv))
            for i, (e, j, _) in enumerate(rows):  # n^T J_c per pair
                f.normal_jacobian(data, e, j, J[i])
            d = [r[2] for r in rows]
            self.avoid_obstacle.assign(J, repulsive_bound(d, *self.d_obs), d)
            levels.append(self.avoid_obstacle)
        k, d_s = f.nearest_self()
        has_self = k >= 0 and d_s < self.d_self[0]
        if has_self:
            J = f.self_normal_jacobian(data, k, np.empty(model.nv))
            self.avoid_self.assign(J, repulsive_bound([d_s], *self.d_self), [d_s])
            levels.append(self.avoid_self)
        levels += self.below
        self._last = {"n_avoid_obstacle": float(len(rows)), "n_avoid_self": float(has_self)}
        return tuple(levels), {}

    def probe(self, ctrl, res) -> dict:
        """Per step: closest robot-obstacle and self distances (NaN beyond the recorded range), avoidance rows."""
        # the record field's numbers (surveillance record_range) from the control field's last update (the step's
        # state) and the few culled pairs that could be nearer (DistanceField.nearest_within)
        d_obs, d_self = self.field.nearest_within(self.record_field.surveillance)
        return {"d_obstacle": float(d_obs) if np.isfinite(d_obs) else np.nan,
                "d_self": float(d_self) if np.isfinite(d_self) else np.nan, **self._last}

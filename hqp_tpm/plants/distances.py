"""Independent distances: the pairs a run's :class:`~hqp_tpm.geometry.distances.DistanceField` computes with coal
(or in closed form), computed again by MuJoCo (``mj_geomDistance``) on the plant's own geometry and kinematics.

The plant's model gets, as contact-free geoms, the field's control points (spheres of radius
:data:`POINT_RADIUS` at their frames, the radius added back) and its static obstacles (spheres, capsules, boxes);
the robot's collision geometry is the plant's own (pinocchio's ``<link>_<k>`` is the k-th URDF collision geom of
MuJoCo's body ``<link>``). Each control step,
before the plant moves, :class:`DistanceCheck` compares every pair the field computed at that state. Without sensor
noise or delay both sides see the same configuration, so the difference checks the geometry and the kinematics of
two independent implementations. Moving obstacles and shapes without a MuJoCo primitive (convex meshes) are left out.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import coal
import numpy as np
import pinocchio as pin

#: Radius (m) of the sphere standing for a control point or a point obstacle (added back to MuJoCo's distance).
POINT_RADIUS = 1e-9
#: Largest distance MuJoCo is asked to compute (m); pairs farther apart read as this.
DISTMAX = 100.0


@dataclass(frozen=True)
class ExtraGeom:
    """A geom added to the plant: ``kind`` sphere/capsule/box with MuJoCo's ``size``, at ``placement`` in pinocchio
    frame ``frame`` (None: the world). Contact-free unless ``contact`` (then it touches the ``floor``, e.g. a
    humanoid's sole when its meshes are left out)."""

    name: str
    kind: str
    size: tuple
    frame: int | None
    placement: pin.SE3
    contact: bool = False


def _obstacle_geom(obs) -> ExtraGeom | None:
    shape = obs.shape
    if isinstance(shape, coal.Sphere):
        kind, size = "sphere", (max(float(shape.radius), POINT_RADIUS),)
    elif isinstance(shape, coal.Capsule):
        kind, size = "capsule", (float(shape.radius), float(shape.halfLength))
    elif isinstance(shape, coal.Box):
        kind, size = "box", tuple(float(h) for h in shape.halfSide)
    else:
        return None
    return ExtraGeom(f"obstacle:{obs.name}", kind, size, None, obs.placement)


def field_geoms(robot, field) -> list[ExtraGeom]:
    """The geoms the plant needs to check ``field``: its control points and its static primitive obstacles."""
    out = [ExtraGeom(f"point:{name}", "sphere", (POINT_RADIUS,), robot.frame_id(name), pin.SE3.Identity())
           for name, kind in zip(field.names, field.kinds, strict=True) if kind == "point"]
    out += [g for obs in field.obstacles if not obs.is_moving and (g := _obstacle_geom(obs)) is not None]
    return out


class DistanceCheck:
    """``check() -> float``: the largest ``|d_field - d_mujoco|`` over the pairs ``field`` computed at the plant's
    current state (NaN when no pair was computed); :attr:`pairs` is how many pairs can be compared."""

    def __init__(self, plant, field) -> None:
        self.plant, self.field = plant, field
        self.mujoco = plant.mujoco
        model = plant.model

        def geom(name: str) -> int | None:
            """A geom by name; pinocchio's ``<link>_<k>`` (the link's k-th URDF collision) by body and rank."""
            try:
                return int(model.geom(name).id)
            except KeyError:
                pass
            match = re.fullmatch(r"(.*)_(\d+)", name)
            if match is None:
                return None
            try:
                body = int(model.body(match.group(1)).id)
            except KeyError:
                return None
            own = [g for g in range(model.ngeom) if model.geom_bodyid[g] == body
                   and not model.geom(g).name.startswith(("point:", "obstacle:"))]
            k = int(match.group(2))
            return own[k] if k < len(own) else None

        elems = []
        for name, kind in zip(field.names, field.kinds, strict=True):
            elems.append((geom(f"point:{name}"), POINT_RADIUS) if kind == "point" else (geom(name), 0.0))
        obs = []
        for o in field.obstacles:
            g = None if o.is_moving else geom(f"obstacle:{o.name}")
            point = isinstance(o.shape, coal.Sphere) and o.shape.radius < POINT_RADIUS
            obs.append((g, POINT_RADIUS if point else 0.0))
        self._pairs = [(e, j, ge, go, re_ + ro) for e, (ge, re_) in enumerate(elems) for j, (go, ro) in enumerate(obs)
                       if ge is not None and go is not None]
        self._self = [(k, elems[a][0], elems[b][0]) for k, (a, b) in enumerate(field.self_pairs)
                      if elems[a][0] is not None and elems[b][0] is not None and not elems[a][1] and not elems[b][1]]

    @property
    def pairs(self) -> int:
        return len(self._pairs) + len(self._self)

    def __call__(self) -> float:
        model, data, f = self.plant.model, self.plant.data, self.field
        self.mujoco.mj_kinematics(model, data)  # positions of the current qpos (mj_step left the previous ones)
        worst = np.nan
        for e, j, g1, g2, radii in self._pairs:
            if f.computed[e, j] and np.isfinite(f.distance[e, j]):
                d = self.mujoco.mj_geomDistance(model, data, g1, g2, DISTMAX, None) + radii
                worst = np.fmax(worst, abs(d - f.distance[e, j]))
        for k, g1, g2 in self._self:
            if f.self_computed[k] and np.isfinite(f.self_distance[k]):
                d = self.mujoco.mj_geomDistance(model, data, g1, g2, DISTMAX, None)
                worst = np.fmax(worst, abs(d - f.self_distance[k]))
        return float(worst)

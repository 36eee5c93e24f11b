"""Obstacles of the collision-avoidance task (papers/000 Sec. III-B, eqs. (22)-(31)).

An :class:`Obstacle` is a named coal shape placed in the world by a :class:`pinocchio.SE3`,
optionally moving: either along a callable ``t -> SE3`` or with a constant linear velocity.
The paper's obstacles are points: ``Obstacle.sphere(name, center)`` with the default radius 0.

Meshes are turned into their convex hull (``coal.Convex.convexHull``, Qhull) by default: raw triangle meshes
are far too slow for a control loop (measured: ~24 ms for Romeo's 44 link-sphere pairs on meshes,
~20 µs on convex hulls).
"""

from __future__ import annotations

from collections.abc import Callable

import coal
import numpy as np
import pinocchio as pin

from hqp_tpm.errors import GeometryError, NonFiniteError, ShapeError
from hqp_tpm.robot.spatial import rotation_z_to

__all__ = ["GeometryError", "Obstacle", "bounding_sphere", "convex_from_points", "convexified"]


def _vector(what: str, value, n: int = 3) -> np.ndarray:
    """``value`` as a finite float vector of length ``n`` (typed errors name ``what`` and the value)."""
    arr = np.asarray(value, dtype=float)
    if arr.shape != (n,):
        raise ShapeError(f"{what} must have shape ({n},), got shape {arr.shape}: {value!r}")
    if not np.all(np.isfinite(arr)):
        raise NonFiniteError(f"{what} must be finite, got {arr.tolist()}")
    return arr.copy()


def checked_scalar(what: str, value, minimum: float = 0.0, strict: bool = False) -> float:
    """``value`` as a finite float ``>= minimum`` (``> minimum`` if ``strict``)."""
    try:
        x = float(value)
    except (TypeError, ValueError) as exc:
        raise GeometryError(f"{what} must be a number, got {value!r}") from exc
    if not np.isfinite(x):
        raise NonFiniteError(f"{what} must be finite, got {x}")
    if x < minimum or (strict and x == minimum):
        op = ">" if strict else ">="
        raise GeometryError(f"{what} must be {op} {minimum}, got {x}")
    return x


def _rotation(what: str, value) -> np.ndarray:
    """A 3x3 rotation matrix (orthonormal, det +1, to 1e-6)."""
    if value is None:
        return np.eye(3)
    R = np.asarray(value, dtype=float)
    if R.shape != (3, 3):
        raise ShapeError(f"{what} must be a 3x3 rotation matrix, got shape {R.shape}")
    if not np.all(np.isfinite(R)):
        raise NonFiniteError(f"{what} must be finite, got {R.tolist()}")
    if not np.allclose(R.T @ R, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
        raise GeometryError(f"{what} is not a rotation matrix: {R.tolist()}")
    return R.copy()


def _se3(what: str, value) -> pin.SE3:
    """A finite pin.SE3 (None -> identity)."""
    if value is None:
        return pin.SE3.Identity()
    if not isinstance(value, pin.SE3):
        raise GeometryError(f"{what} must be a pinocchio.SE3, got {type(value).__name__}")
    if not np.all(np.isfinite(value.homogeneous)):
        raise NonFiniteError(f"{what} must be finite, got\n{value}")
    return pin.SE3(value)


#: Smallest/largest singular value of the centred vertices below which they are flat (no 3-D hull).
FLAT_TOL = 1e-9


def convex_from_points(points, what: str = "mesh") -> coal.ConvexBase:
    """A coal convex shape that is the convex hull of ``points`` (N x 3): ``coal.Convex.convexHull`` (Qhull)."""
    P = np.asarray(points, dtype=float)
    if P.ndim != 2 or P.shape[1] != 3 or P.shape[0] < 4:
        raise ShapeError(f"{what} vertices must be an (N >= 4, 3) array, got shape {P.shape}")
    if not np.all(np.isfinite(P)):
        raise NonFiniteError(f"{what} vertices must be finite")
    s = np.linalg.svd(P - P.mean(axis=0), compute_uv=False)
    if not s[2] > FLAT_TOL * s[0]:  # coal's Qhull call does not survive flat input (it crashes the process)
        raise GeometryError(f"{what}: vertices are degenerate (flat or collinear), no 3-D convex hull")
    verts = coal.StdVec_Vec3s()
    verts.extend(P)
    shape = coal.Convex.convexHull(verts, True, None)
    shape.computeLocalAABB()
    return shape


def convexified(shape: coal.CollisionGeometry, what: str) -> coal.CollisionGeometry:
    """The convex hull of a BVH mesh (control must not query raw meshes); other shapes unchanged."""
    if isinstance(shape, coal.BVHModelBase):
        return convex_from_points(np.asarray(shape.vertices(), dtype=float), what=what)
    return shape


def bounding_sphere(shape: coal.CollisionGeometry) -> tuple[np.ndarray, float]:
    """Centre (shape frame) and radius of a sphere enclosing ``shape`` (tight for the primitives)."""
    if isinstance(shape, coal.Sphere):
        return np.zeros(3), float(shape.radius)
    if isinstance(shape, coal.Capsule):
        return np.zeros(3), float(shape.radius + shape.halfLength)
    if isinstance(shape, coal.Box):
        return np.zeros(3), float(np.linalg.norm(shape.halfSide))
    if isinstance(shape, coal.Cylinder):
        return np.zeros(3), float(np.hypot(shape.radius, shape.halfLength))
    if isinstance(shape, coal.ConvexBase):
        P = np.asarray(shape.points(), dtype=float)
        c = 0.5 * (P.min(axis=0) + P.max(axis=0))
        return c, float(np.max(np.linalg.norm(P - c, axis=1)))
    if isinstance(shape, coal.BVHModelBase):
        P = np.asarray(shape.vertices(), dtype=float)
        c = 0.5 * (P.min(axis=0) + P.max(axis=0))
        return c, float(np.max(np.linalg.norm(P - c, axis=1)))
    shape.computeLocalAABB()
    return np.asarray(shape.aabb_center, dtype=float).copy(), float(shape.aabb_radius)


class Obstacle:
    """A named coal shape at ``placement`` (world frame), static or moving.

    ``motion`` is a callable ``t -> pin.SE3`` giving the placement at time ``t``; ``velocity`` a
    constant world-frame linear velocity (placement(t) = placement translated by ``velocity * t``).
    At most one of the two may be given.
    """

    __slots__ = ("name", "shape", "placement", "motion", "velocity", "local_center", "bounding_radius")

    def __init__(self, name: str, shape: coal.CollisionGeometry, placement: pin.SE3 | None = None,
                 motion: Callable[[float], pin.SE3] | None = None, velocity=None):
        if not isinstance(name, str) or not name:
            raise GeometryError(f"obstacle name must be a non-empty string, got {name!r}")
        if not isinstance(shape, coal.CollisionGeometry):
            raise GeometryError(f"obstacle {name!r}: shape must be a coal.CollisionGeometry, "
                                f"got {type(shape).__name__}")
        if motion is not None and velocity is not None:
            raise GeometryError(f"obstacle {name!r}: give either motion or velocity, not both")
        if motion is not None and not callable(motion):
            raise GeometryError(f"obstacle {name!r}: motion must be a callable t -> SE3, got {motion!r}")
        self.name = name
        self.shape = shape
        self.placement = _se3(f"obstacle {name!r} placement", placement)
        self.motion = motion
        self.velocity = None if velocity is None else _vector(f"obstacle {name!r} velocity", velocity)
        self.local_center, self.bounding_radius = bounding_sphere(shape)

    # ------------------------------------------------------------------ constructors
    @classmethod
    def sphere(cls, name: str, center, radius: float = 0.0, **motion) -> Obstacle:
        """A sphere; ``radius = 0`` is the paper's point obstacle ``o_j`` (eqs. (22), (25))."""
        c = _vector(f"obstacle {name!r} center", center)
        r = checked_scalar(f"obstacle {name!r} radius", radius)
        return cls(name, coal.Sphere(r), pin.SE3(np.eye(3), c), **motion)

    @classmethod
    def box(cls, name: str, center, half_extents, rotation=None, **motion) -> Obstacle:
        """A box of half side lengths ``half_extents`` centred at ``center``, axes given by ``rotation``."""
        c = _vector(f"obstacle {name!r} center", center)
        h = _vector(f"obstacle {name!r} half_extents", half_extents)
        if np.any(h < 0):
            raise GeometryError(f"obstacle {name!r}: half_extents must be >= 0, got {h.tolist()}")
        R = _rotation(f"obstacle {name!r} rotation", rotation)
        return cls(name, coal.Box(*(2.0 * h)), pin.SE3(R, c), **motion)

    @classmethod
    def capsule(cls, name: str, a, b, radius: float, **motion) -> Obstacle:
        """A capsule around the segment from ``a`` to ``b`` (world frame) with ``radius`` (0: a segment)."""
        pa = _vector(f"obstacle {name!r} end point a", a)
        pb = _vector(f"obstacle {name!r} end point b", b)
        r = checked_scalar(f"obstacle {name!r} radius", radius)
        axis = pb - pa
        length = float(np.linalg.norm(axis))
        R = rotation_z_to(axis) if length > 0.0 else np.eye(3)
        return cls(name, coal.Capsule(r, length), pin.SE3(R, 0.5 * (pa + pb)), **motion)

    @classmethod
    def mesh(cls, name: str, vertices, faces=None, convex: bool = True, placement: pin.SE3 | None = None,
             **motion) -> Obstacle:
        """A triangle mesh (``vertices`` N x 3, ``faces`` F x 3 indices) in the frame ``placement``.

        ``convex=True`` (default) keeps only its convex hull, which is what control needs; ``convex=False``
        keeps the raw mesh as a BVH (exact but slow, and GJK-based signed distance is not available inside).
        """
        V = np.asarray(vertices, dtype=float)
        if V.ndim != 2 or V.shape[1] != 3:
            raise ShapeError(f"obstacle {name!r} vertices must be an (N, 3) array, got shape {V.shape}")
        if not np.all(np.isfinite(V)):
            raise NonFiniteError(f"obstacle {name!r} vertices must be finite")
        if faces is not None:
            F = np.asarray(faces)
            if F.ndim != 2 or F.shape[1] != 3:
                raise ShapeError(f"obstacle {name!r} faces must be an (F, 3) index array, got shape {F.shape}")
            if F.size and (F.min() < 0 or F.max() >= len(V)):
                raise GeometryError(f"obstacle {name!r}: face indices out of range [0, {len(V)})")
        if convex:
            shape = convex_from_points(V, what=f"obstacle {name!r}")
        else:
            if faces is None:
                raise GeometryError(f"obstacle {name!r}: a non-convex mesh needs faces")
            shape = coal.BVHModelOBBRSS()
            shape.beginModel(len(F), len(V))
            verts = coal.StdVec_Vec3s()
            for v in V:
                verts.append(v)
            tris = coal.StdVec_Triangle()
            for a, b, c in F:
                tris.append(coal.Triangle(int(a), int(b), int(c)))
            shape.addSubModel(verts, tris)
            shape.endModel()
            shape.computeLocalAABB()
        return cls(name, shape, placement, **motion)

    # ------------------------------------------------------------------ motion
    @property
    def is_moving(self) -> bool:
        return self.motion is not None or self.velocity is not None

    def placement_at(self, t: float) -> pin.SE3:
        """World placement at time ``t`` (the static placement if the obstacle does not move)."""
        if self.motion is not None:
            M = self.motion(t)
            if not isinstance(M, pin.SE3):
                raise GeometryError(f"obstacle {self.name!r}: motion({t}) returned {type(M).__name__}, not SE3")
            return M
        if self.velocity is not None:
            return pin.SE3(self.placement.rotation, self.placement.translation + self.velocity * t)
        return self.placement

    def linear_velocity_at(self, t: float, h: float = 1e-6) -> np.ndarray:
        """World velocity of the shape origin at ``t`` (central difference of ``motion`` if given)."""
        if self.motion is not None:
            return (self.motion(t + h).translation - self.motion(t - h).translation) / (2.0 * h)
        if self.velocity is not None:
            return self.velocity.copy()
        return np.zeros(3)

    def __repr__(self) -> str:
        kind = type(self.shape).__name__
        p = np.array2string(self.placement.translation, precision=4)
        moving = ", moving" if self.is_moving else ""
        return f"Obstacle({self.name!r}, {kind} at {p}{moving})"

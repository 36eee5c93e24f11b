"""Library calls that replaced hand-written math, each against the code it replaced (kept here as the reference).

* ``coal.Convex.convexHull`` for the convex hulls (was scipy's ``ConvexHull`` turned into a ``coal.Convex``);
* ``pin.skew`` for the witness-point Jacobian ``J_v - [r]x J_w`` (was a row-permutation trick);
* ``pin.exp3`` for the DMP coupling rotation (was a hand-written Rodrigues formula);
* ``pin.Quaternion.FromTwoVectors`` for "a rotation whose z axis is a" (was a helper-vector construction,
  written in the capsule obstacle and the viewer).
"""

from __future__ import annotations

import math

import coal
import numpy as np
import pinocchio as pin
import pytest

from hqp_tpm.geometry.distances import point_jacobian
from hqp_tpm.geometry.obstacles import Obstacle, convex_from_points
from hqp_tpm.robot.model import Robot
from hqp_tpm.robot.spatial import rotation_z_to


# ------------------------------------------------------------------ the replaced code, verbatim
def scipy_hull(P) -> coal.Convex:
    from scipy.spatial import ConvexHull

    P = np.asarray(P, dtype=float)
    hull = ConvexHull(P)
    index = {int(k): i for i, k in enumerate(hull.vertices)}
    verts = coal.StdVec_Vec3s()
    for k in hull.vertices:
        verts.append(P[k])
    centroid = P[hull.vertices].mean(axis=0)
    tris = coal.StdVec_Triangle()
    for simplex in hull.simplices:
        a, b, c = (int(k) for k in simplex)
        if np.dot(np.cross(P[b] - P[a], P[c] - P[a]), P[a] - centroid) < 0:
            b, c = c, b
        tris.append(coal.Triangle(index[a], index[b], index[c]))
    shape = coal.Convex(verts, tris)
    shape.computeLocalAABB()
    return shape


_CROSS_ROWS = np.array([5, 3, 4, 4, 5, 3])


def row_trick_jacobian(model, data, joint_id, p_world):
    J = pin.getJointJacobian(model, data, int(joint_id), pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
    r0, r1, r2 = (np.asarray(p_world, dtype=float) - data.oMi[int(joint_id)].translation).tolist()
    P = np.array([[r1], [r2], [r0], [r2], [r0], [r1]]) * J[_CROSS_ROWS]
    return J[:3] - (P[:3] - P[3:])


def rodrigues(axis_angle):
    th = float(np.linalg.norm(axis_angle))
    if th < 1e-12:
        return np.eye(3)
    k = axis_angle / th
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(th) * K + (1 - math.cos(th)) * K @ K


def helper_frame(axis):
    z = np.asarray(axis, dtype=float)
    z = z / np.linalg.norm(z)
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(z, x), z])


# ------------------------------------------------------------------ helpers
def _distance(s1, M1, s2, M2=None):
    M2 = pin.SE3.Identity() if M2 is None else M2
    req, res = coal.DistanceRequest(), coal.DistanceResult()
    req.enable_signed_distance = True
    return coal.distance(s1, coal.Transform3s(M1.rotation, M1.translation), s2,
                         coal.Transform3s(M2.rotation, M2.translation), req, res)


def _same_hull(a, b, probes, tol):
    Pa, Pb = np.asarray(a.points()), np.asarray(b.points())
    assert len(Pa) == len(Pb)
    assert np.array_equal(np.unique(Pa, axis=0), np.unique(Pb, axis=0))  # the same vertices, other order
    for M, shape in probes:
        assert abs(_distance(a, pin.SE3.Identity(), shape, M) - _distance(b, pin.SE3.Identity(), shape, M)) < tol


@pytest.fixture(scope="module")
def romeo():
    return Robot.load("romeo21")


# ------------------------------------------------------------------ tests
def test_coal_hull_equals_the_scipy_hull_on_random_clouds():
    rng = np.random.default_rng(0)
    for n in (4, 10, 200):
        P = rng.standard_normal((n, 3)) * rng.uniform(0.01, 1.0, 3)
        probes = [(pin.SE3(pin.exp3(rng.standard_normal(3)), 2.0 * rng.standard_normal(3)),
                   coal.Sphere(0.05) if k % 2 else coal.Box(0.1, 0.2, 0.05)) for k in range(20)]
        probes += [(pin.SE3(np.eye(3), P.mean(0) + 0.01 * rng.standard_normal(3)), coal.Sphere(0.0))]  # inside
        _same_hull(convex_from_points(P), scipy_hull(P), probes, 1e-9)


def test_coal_hull_equals_the_scipy_hull_on_romeo_meshes(romeo):
    """The meshes of the whole-body policy's control geometries (the hulls it builds every construction)."""
    from hqp_tpm.policies.whole_body import CONTROL_GEOMETRIES

    rng = np.random.default_rng(1)
    gm = romeo.collision_model
    for name in CONTROL_GEOMETRIES:
        V = np.asarray(gm.geometryObjects[gm.getGeometryId(name)].geometry.vertices(), dtype=float)
        c = V.mean(0)
        probes = [(pin.SE3(np.eye(3), c + 0.3 * rng.standard_normal(3)), coal.Sphere(0.02)) for _ in range(10)]
        probes += [(pin.SE3(np.eye(3), c), coal.Sphere(0.0))]  # penetrating (EPA)
        _same_hull(convex_from_points(V, name), scipy_hull(V), probes, 1e-9)


def test_point_jacobian_equals_the_row_trick(romeo):
    model = romeo.model
    data = model.createData()
    rng = np.random.default_rng(2)
    for _ in range(30):
        q = pin.randomConfiguration(model, -np.ones(model.nq), np.ones(model.nq))
        pin.computeJointJacobians(model, data, q)
        jid = int(rng.integers(1, model.njoints))
        p = rng.uniform(-1.0, 1.0, 3)
        np.testing.assert_allclose(point_jacobian(model, data, jid, p), row_trick_jacobian(model, data, jid, p),
                                   rtol=0, atol=1e-14)


def test_exp3_equals_rodrigues():
    rng = np.random.default_rng(3)
    for scale in (0.0, 1e-13, 1e-6, 0.1, 1.0, math.pi - 1e-9, 3.0):
        for _ in range(20):
            w = scale * rng.standard_normal(3)
            # below |w| = 1e-12 the old formula returned the identity (an error of |w|)
            np.testing.assert_allclose(pin.exp3(w), rodrigues(w), rtol=0, atol=1e-12)


def test_rotation_z_to_has_the_same_z_axis_and_capsules_the_same_distances():
    rng = np.random.default_rng(4)
    axes = [*rng.standard_normal((50, 3)), np.array([0, 0, 1.0]), np.array([0, 0, -1.0]), np.array([1.0, 0, 0])]
    axes += [np.array([e, 0.3 * e, s]) for e in (1e-2, 1e-5, 1e-8) for s in (-1.0, 1.0)]  # near +-z
    for a in axes:
        R = rotation_z_to(a)
        np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-14)
        assert np.linalg.det(R) > 0
        np.testing.assert_allclose(R[:, 2], helper_frame(a)[:, 2], rtol=0, atol=1e-14)
    # a capsule is symmetric about its axis: the rotation about z does not change any distance
    for _ in range(20):
        a, b = rng.standard_normal(3), rng.standard_normal(3)
        new = Obstacle.capsule("c", a, b, 0.1)
        old = pin.SE3(helper_frame(b - a), 0.5 * (a + b))
        for _ in range(5):
            M = pin.SE3(pin.exp3(rng.standard_normal(3)), 2.0 * rng.standard_normal(3))
            box = coal.Box(0.2, 0.1, 0.3)
            assert abs(_distance(new.shape, new.placement, box, M) - _distance(new.shape, old, box, M)) < 1e-12

"""DistanceField and Obstacle: analytic distances/witness points, penetration, broad phase vs brute force,
normals, point Jacobian and J-dot q-dot against finite differences, moving obstacles, typed errors."""

import coal
import example_robot_data as erd
import numpy as np
import pinocchio as pin
import pytest

from hqp_tpm.errors import HqpTpmError, NonFiniteError, ShapeError, UnknownFrameError, UnknownNameError
from hqp_tpm.geometry import distances
from hqp_tpm.geometry.distances import DistanceField, point_jacobian, point_jdot_qdot
from hqp_tpm.geometry.obstacles import GeometryError, Obstacle

TOL = 1e-9


def rot_y(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_z(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


# ---------------------------------------------------------------- models
CAP_R, CAP_L = 0.05, 0.4
BALL_R = 0.04


def tiny():
    """RZ-RY-RX arm. At q = 0: capsule 'link2' = segment (0,0,.3)-(.4,0,.3), radius .05; sphere 'ball3'
    at (.5,0,.3), radius .04; box 'base' 0.1x0.1x0.2 at (0,0,.1); frames 'cp_mid' (.2,0,.3), 'tip' (.5,.05,.3)."""
    model = pin.Model()
    j1 = model.addJoint(0, pin.JointModelRZ(), pin.SE3.Identity(), "j1")
    j2 = model.addJoint(j1, pin.JointModelRY(), pin.SE3(np.eye(3), np.array([0.0, 0.0, 0.3])), "j2")
    j3 = model.addJoint(j2, pin.JointModelRX(), pin.SE3(np.eye(3), np.array([0.4, 0.0, 0.0])), "j3")
    model.addFrame(pin.Frame("cp_mid", j2, pin.SE3(np.eye(3), np.array([0.2, 0.0, 0.0])), pin.FrameType.OP_FRAME))
    model.addFrame(pin.Frame("tip", j3, pin.SE3(np.eye(3), np.array([0.1, 0.05, 0.0])), pin.FrameType.OP_FRAME))
    geom = pin.GeometryModel()
    geom.addGeometryObject(pin.GeometryObject("link2", j2, pin.SE3(rot_y(np.pi / 2), np.array([0.2, 0.0, 0.0])),
                                              coal.Capsule(CAP_R, CAP_L)))
    geom.addGeometryObject(pin.GeometryObject("ball3", j3, pin.SE3(np.eye(3), np.array([0.1, 0.0, 0.0])),
                                              coal.Sphere(BALL_R)))
    geom.addGeometryObject(pin.GeometryObject("base", 0, pin.SE3(np.eye(3), np.array([0.0, 0.0, 0.1])),
                                              coal.Box(0.1, 0.1, 0.2)))
    return model, geom


def kinematics(model, q, v=None):
    data = model.createData()
    if v is None:
        pin.forwardKinematics(model, data, q)
    else:
        pin.forwardKinematics(model, data, q, v, np.zeros(model.nv))
    pin.updateFramePlacements(model, data)
    return data


def capsule_segment(model, data):
    """World end points of the tiny model's capsule axis."""
    M = data.oMi[model.getJointId("j2")]
    return M.act(np.zeros(3)), M.act(np.array([CAP_L, 0.0, 0.0]))


def closest_on_segment(a, b, p):
    t = np.clip((p - a) @ (b - a) / ((b - a) @ (b - a)), 0.0, 1.0)
    return a + t * (b - a)


@pytest.fixture(autouse=True, params=["pairwise", "batched"])
def coal_path(request, monkeypatch):
    """Run every test through both post-processing paths of the coal queries."""
    monkeypatch.setattr(distances, "BATCH_MIN", 10**9 if request.param == "pairwise" else 0)
    return request.param


@pytest.fixture(scope="module")
def panda():
    robot = erd.load("panda")
    robot.collision_model.removeAllCollisionPairs()  # 44 default self pairs: not wanted here
    return robot.model, robot.collision_model


@pytest.fixture(scope="module")
def panda_convex(panda):
    """Panda with its meshes replaced by convex hulls once (convexifying is the slow part of construction)."""
    model, geom = panda
    return model, DistanceField(model, geom).geometry_model


ANALYTIC = pytest.mark.parametrize("analytic", [True, False], ids=["numpy-spheres", "coal-only"])


# ---------------------------------------------------------------- analytic cases
@ANALYTIC
def test_control_point_vs_sphere(analytic):
    model, geom = tiny()
    rng = np.random.default_rng(0)
    obs = [Obstacle.sphere("s", [0.3, 0.2, 0.5], 0.1), Obstacle.sphere("p", [0.1, -0.3, 0.2])]
    field = DistanceField(model, None, ["cp_mid", "tip"], obs, surveillance=10.0, analytic_spheres=analytic)
    for _ in range(5):
        data = kinematics(model, rng.uniform(-2, 2, model.nq))
        field.update(data)
        for name in ("cp_mid", "tip"):
            e = field.element_index(name)
            p = data.oMf[model.getFrameId(name)].translation
            for j, o in enumerate(obs):
                c, r = o.placement.translation, o.shape.radius
                n = (p - c) / np.linalg.norm(p - c)
                assert field.distance[e, j] == pytest.approx(np.linalg.norm(p - c) - r, abs=TOL)
                np.testing.assert_allclose(field.p_robot[e, j], p, atol=TOL)
                np.testing.assert_allclose(field.p_obstacle[e, j], c + r * n, atol=TOL)
                np.testing.assert_allclose(field.normal[e, j], n, atol=TOL)
    assert field.in_range.all()


@ANALYTIC
def test_capsule_link_vs_point_and_sphere(analytic):
    model, geom = tiny()
    rng = np.random.default_rng(1)
    obs = [Obstacle.sphere("point", [0.2, 0.1, 0.45]), Obstacle.sphere("ball", [0.35, -0.15, 0.2], 0.06)]
    field = DistanceField(model, geom, [], obs, surveillance=10.0, geometries=["link2"], analytic_spheres=analytic)
    for k in range(6):
        q = np.zeros(model.nq) if k == 0 else rng.uniform(-1.5, 1.5, model.nq)
        data = kinematics(model, q)
        field.update(data)
        a, b = capsule_segment(model, data)
        if k == 0:
            np.testing.assert_allclose([a, b], [[0, 0, 0.3], [0.4, 0, 0.3]], atol=1e-15)
        for j, o in enumerate(obs):
            c, r = o.placement.translation, o.shape.radius
            s = closest_on_segment(a, b, c)
            n = (s - c) / np.linalg.norm(s - c)
            assert field.distance[0, j] == pytest.approx(np.linalg.norm(s - c) - CAP_R - r, abs=TOL)
            np.testing.assert_allclose(field.p_robot[0, j], s - CAP_R * n, atol=TOL)
            np.testing.assert_allclose(field.p_obstacle[0, j], c + r * n, atol=TOL)
            np.testing.assert_allclose(field.normal[0, j], n, atol=TOL)


def box_distance(center, R, half, p):
    """Signed distance of point p to a box, and the closest point on its surface (world)."""
    x = R.T @ (p - center)
    if np.all(np.abs(x) <= half):
        k = int(np.argmin(half - np.abs(x)))
        y = x.copy()
        y[k] = np.sign(x[k]) * half[k]
        return -(half[k] - abs(x[k])), center + R @ y
    y = np.clip(x, -half, half)
    return np.linalg.norm(x - y), center + R @ y


@ANALYTIC
def test_box_obstacle(analytic):
    model, geom = tiny()
    rng = np.random.default_rng(2)
    R = rot_z(0.4) @ rot_y(0.3)
    center, half = np.array([0.3, 0.1, 0.35]), np.array([0.05, 0.1, 0.08])
    box = Obstacle.box("box", center, half, rotation=R)
    field = DistanceField(model, geom, ["cp_mid", "tip"], [box], surveillance=10.0, geometries=["ball3"],
                          analytic_spheres=analytic)
    for _ in range(8):
        data = kinematics(model, rng.uniform(-1.5, 1.5, model.nq))
        field.update(data)
        for name, radius in (("cp_mid", 0.0), ("tip", 0.0), ("ball3", BALL_R)):
            e = field.element_index(name)
            if name == "ball3":
                p = field.geometry_model.geometryObjects[0].placement
                p = data.oMi[int(field.joint_ids[e])].act(p.translation)
            else:
                p = data.oMf[model.getFrameId(name)].translation
            d, w = box_distance(center, R, half, p)
            n = (p - w) / np.linalg.norm(p - w) * (1 if d > 0 else -1)
            assert field.distance[e, 0] == pytest.approx(d - radius, abs=TOL)
            np.testing.assert_allclose(field.p_obstacle[e, 0], w, atol=TOL)
            np.testing.assert_allclose(field.p_robot[e, 0], p - radius * n, atol=TOL)
            np.testing.assert_allclose(field.normal[e, 0], n, atol=TOL)


def test_capsule_and_convex_mesh_obstacles():
    model, geom = tiny()
    rng = np.random.default_rng(10)
    a, b = np.array([0.3, -0.2, 0.1]), np.array([0.1, 0.3, 0.6])
    cube = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float) * [0.05, 0.1, 0.15]
    R, c = rot_z(0.3) @ rot_y(-0.5), np.array([-0.2, 0.2, 0.3])
    obs = [Obstacle.capsule("pole", a, b, 0.03), Obstacle.mesh("cube", cube, placement=pin.SE3(R, c))]
    field = DistanceField(model, geom, ["cp_mid", "tip"], obs, surveillance=10.0)
    for _ in range(8):
        data = kinematics(model, rng.uniform(-2, 2, model.nq))
        field.update(data)
        for name in ("cp_mid", "tip"):
            e = field.element_index(name)
            p = data.oMf[model.getFrameId(name)].translation
            s = closest_on_segment(a, b, p)
            assert field.distance[e, 0] == pytest.approx(np.linalg.norm(p - s) - 0.03, abs=TOL)
            np.testing.assert_allclose(field.p_obstacle[e, 0], s + 0.03 * unit(p - s), atol=TOL)
            d, w = box_distance(c, R, np.array([0.05, 0.1, 0.15]), p)  # hull of the cube's corners (GJK: 1e-6)
            assert field.distance[e, 1] == pytest.approx(d, abs=1e-6)
            np.testing.assert_allclose(field.p_obstacle[e, 1], w, atol=1e-6)


def unit(v):
    return v / np.linalg.norm(v)


@ANALYTIC
def test_penetration_gives_negative_distance(analytic):
    model, geom = tiny()
    data = kinematics(model, np.zeros(model.nq))  # cp_mid at (.2,0,.3), capsule axis (0,0,.3)-(.4,0,.3)
    obs = [
        Obstacle.sphere("big", [0.23, 0.0, 0.34], 0.1),  # contains cp_mid: d = 0.05 - 0.1
        Obstacle.sphere("inside_capsule", [0.1, 0.02, 0.3]),  # point 0.02 from the axis: d = 0.02 - 0.05
        Obstacle.box("box", [0.2, 0.0, 0.31], [0.3, 0.2, 0.1]),  # cp_mid 0.09 above the bottom face: d = -0.09
    ]
    field = DistanceField(model, geom, ["cp_mid"], obs, surveillance=0.1, geometries=["link2"],
                          analytic_spheres=analytic)
    field.update(data)
    cap, cp = field.element_index("link2"), field.element_index("cp_mid")
    assert field.distance[cp, 0] == pytest.approx(0.05 - 0.1, abs=TOL)
    np.testing.assert_allclose(field.normal[cp, 0], [-0.6, 0.0, -0.8], atol=TOL)  # out of the sphere, through p
    np.testing.assert_allclose(field.p_obstacle[cp, 0], [0.23 - 0.06, 0.0, 0.34 - 0.08], atol=TOL)
    assert field.distance[cap, 1] == pytest.approx(0.02 - CAP_R, abs=TOL)
    np.testing.assert_allclose(field.normal[cap, 1], [0.0, -1.0, 0.0], atol=TOL)
    np.testing.assert_allclose(field.p_robot[cap, 1], [0.1, CAP_R, 0.3], atol=TOL)  # surface point nearest o
    assert field.distance[cp, 2] == pytest.approx(-0.09, abs=TOL)
    np.testing.assert_allclose(field.normal[cp, 2], [0.0, 0.0, -1.0], atol=TOL)
    np.testing.assert_allclose(field.p_obstacle[cp, 2], [0.2, 0.0, 0.21], atol=TOL)
    assert field.in_range[cp, 0] and field.in_range[cp, 2] and field.in_range[cap, 1]
    assert not field.in_range[cp, 1]  # 0.102 > surveillance 0.1
    nearest = field.nearest("point")
    assert nearest.element == cp and nearest.obstacle_index == 2 and nearest.value == pytest.approx(-0.09)


@ANALYTIC
def test_degenerate_normal_is_a_documented_unit_vector(analytic):
    model, geom = tiny()
    data = kinematics(model, np.zeros(model.nq))  # cp_mid at (.2,0,.3)
    obs = [Obstacle.sphere("at_point", [0.2, 0.0, 0.3]),  # coincides with the control point
           Obstacle.sphere("surface", [0.2, 0.0, 0.4], 0.1)]  # control point on its surface
    field = DistanceField(model, None, ["cp_mid"], obs, surveillance=0.1, analytic_spheres=analytic)
    field.update(data)
    assert np.all(np.isfinite(field.normal[0])) and np.allclose(np.linalg.norm(field.normal[0], axis=1), 1.0)
    assert field.distance[0, 0] == pytest.approx(0.0, abs=TOL)
    assert field.distance[0, 1] == pytest.approx(0.0, abs=TOL)
    np.testing.assert_allclose(field.normal[0, 1], [0.0, 0.0, -1.0], atol=1e-9)  # away from the sphere centre
    # the fallback keeps the previous normal when nothing else defines one
    data = kinematics(model, np.array([0.0, 1e-3, 0.0]))
    field.update(data)
    previous = field.normal[0, 0].copy()
    moved = DistanceField(model, None, ["cp_mid"], obs[:1], surveillance=0.1, analytic_spheres=analytic)
    moved.update(data)
    np.testing.assert_allclose(moved.normal[0, 0], previous, atol=1e-12)


# ---------------------------------------------------------------- broad phase vs brute force
def scattered_obstacles(rng, centres):
    """Point, sphere, box, capsule and convex obstacles near the given points."""
    c = [centres[k] + rng.normal(0, 0.05, 3) for k in range(6)]
    verts = rng.normal(0, 0.05, (20, 3))
    return [
        Obstacle.sphere("o1", c[0]), Obstacle.sphere("o2", c[1]), Obstacle.sphere("o3", c[2], 0.05),
        Obstacle.box("box", c[3], [0.04, 0.08, 0.02], rotation=rot_z(rng.uniform(0, 3))),
        Obstacle.capsule("pole", c[4], c[4] + [0.0, 0.1, 0.2], 0.03),
        Obstacle.mesh("rock", verts, placement=pin.SE3(rot_y(0.7), c[5])),
    ]


def check_same_in_range(fast, slow):
    assert slow.computed.all()
    mask = slow.distance <= slow.surveillance
    np.testing.assert_array_equal(fast.in_range, mask)
    np.testing.assert_allclose(fast.distance[mask], slow.distance[mask], atol=1e-12)
    np.testing.assert_allclose(fast.p_robot[mask], slow.p_robot[mask], atol=1e-12)
    np.testing.assert_allclose(fast.normal[mask], slow.normal[mask], atol=1e-12)
    assert np.all(fast.distance[~fast.computed] == np.inf)
    smask = slow.self_distance <= slow.surveillance
    np.testing.assert_array_equal(fast.self_in_range, smask)
    np.testing.assert_allclose(fast.self_distance[smask], slow.self_distance[smask], atol=1e-12)
    return int(mask.sum()), int((~fast.computed).sum())


def test_broad_phase_keeps_every_pair_in_range_panda(panda_convex):
    model, geom = panda_convex
    rng = np.random.default_rng(3)
    points = ["panda_link3", "panda_link4", "panda_link5", "panda_link7", "panda_hand"]
    self_pairs = [("panda_link1_0", "panda_link5_0"), ("panda_link2_0", "panda_hand_0"),
                  ("panda_link3_0", "panda_leftfinger_0")]
    in_range = culled = 0
    data0 = model.createData()
    for _ in range(12):
        pin.framesForwardKinematics(model, data0, pin.randomConfiguration(model))
        centres = [data0.oMf[model.getFrameId(f)].translation for f in rng.choice(points, 6)]
        obs = scattered_obstacles(rng, centres)
        kw = dict(control_points=points, obstacles=obs, surveillance=0.15, self_pairs=self_pairs)
        fast = DistanceField(model, geom, **kw)
        slow = DistanceField(model, geom, broad_phase=False, **kw)
        for _ in range(4):
            data = kinematics(model, pin.randomConfiguration(model))
            fast.update(data)
            slow.update(data)
            a, b = check_same_in_range(fast, slow)
            in_range, culled = in_range + a, culled + b
    assert in_range > 20 and culled > 1000  # neither vacuous nor without culling


def test_broad_phase_keeps_every_pair_in_range_tiny():
    model, geom = tiny()
    rng = np.random.default_rng(4)
    in_range = 0
    for _ in range(30):
        centres = rng.uniform([-0.5, -0.5, 0.0], [0.5, 0.5, 0.6], (6, 3))
        obs = scattered_obstacles(rng, centres)
        kw = dict(control_points=["cp_mid", "tip"], obstacles=obs, surveillance=0.2, self_pairs=[("base", "ball3")])
        fast, slow = DistanceField(model, geom, **kw), DistanceField(model, geom, broad_phase=False, **kw)
        for _ in range(3):
            data = kinematics(model, rng.uniform(-3, 3, model.nq))
            fast.update(data)
            slow.update(data)
            in_range += check_same_in_range(fast, slow)[0]
    assert in_range > 20


def test_normals_unit_and_pointing_away(panda_convex):
    model, geom = panda_convex
    rng = np.random.default_rng(5)
    data = kinematics(model, pin.randomConfiguration(model))
    centres = [data.oMi[j].translation for j in rng.integers(1, 8, 6).tolist()]
    obs = scattered_obstacles(rng, centres)
    field = DistanceField(model, geom, ["panda_link4", "panda_hand"], obs, surveillance=0.5, broad_phase=False)
    field.update(data)
    n, d = field.normal, field.distance
    np.testing.assert_allclose(np.linalg.norm(n, axis=2), 1.0, atol=1e-12)
    # p_robot - p_obstacle = d n: the robot witness lies on the obstacle's outer side (also when d < 0)
    np.testing.assert_allclose(field.p_robot - field.p_obstacle, d[..., None] * n, atol=1e-9)
    # point obstacles: n . (p_robot - o) > 0 outside; inside a link, n points from the link surface to o
    for j in (0, 1):
        o = obs[j].placement.translation
        np.testing.assert_array_equal(np.sign(np.einsum("ek,ek->e", n[:, j], field.p_robot[:, j] - o)),
                                      np.sign(d[:, j]))
    assert (d < 0).any() and (d > 0).any()
    # moving a control point along n increases its distance to the obstacle
    e = field.element_index("panda_hand")
    for j, o in enumerate(obs):
        shifted = pin.SE3(np.eye(3), field.p_robot[e, j] + 1e-4 * n[e, j])
        d2 = coal.distance(coal.Sphere(0.0), shifted, o.shape, o.placement, coal.DistanceRequest(),
                           coal.DistanceResult())
        assert d2 == pytest.approx(d[e, j] + 1e-4, abs=1e-6)


def test_geom_data_from_caller_matches_internal(panda):
    model, geom = panda
    obs = [Obstacle.sphere("o", [0.3, 0.1, 0.6], 0.05), Obstacle.box("b", [0.1, -0.3, 0.4], [0.1, 0.1, 0.1])]
    names = ["panda_leftfinger_0", "panda_rightfinger_1", "panda_link5_0"]
    field = DistanceField(model, geom, ["panda_hand"], obs, surveillance=1.0, geometries=names, convexify=True)
    conv_geom = field.geometry_model
    caller_field = DistanceField(model, conv_geom, ["panda_hand"], obs, surveillance=1.0, geometries=names[::-1])
    gdata = pin.GeometryData(conv_geom)
    for _ in range(3):
        data = kinematics(model, pin.randomConfiguration(model))
        pin.updateGeometryPlacements(model, data, conv_geom, gdata)
        field.update(data)
        caller_field.update(data, gdata)
        order = [caller_field.element_index(n) for n in field.names]
        np.testing.assert_allclose(caller_field.distance[order], field.distance, atol=1e-12)


# ---------------------------------------------------------------- Jacobians
def test_point_jacobian_and_jdot_qdot_against_finite_differences(panda):
    model, _ = panda
    rng = np.random.default_rng(7)
    h = 1e-6
    for _ in range(5):
        q = pin.randomConfiguration(model)
        v = rng.standard_normal(model.nv)
        jid = int(rng.integers(1, model.njoints))
        data = kinematics(model, q, v)
        pin.computeJointJacobians(model, data, q)
        p_local = rng.uniform(-0.2, 0.2, 3)
        p = data.oMi[jid].act(p_local)
        J = point_jacobian(model, data, jid, p)

        def at(qq, jid=jid, p_local=p_local):
            d = model.createData()
            pin.computeJointJacobians(model, d, qq)
            pp = d.oMi[jid].act(p_local)
            return pp, point_jacobian(model, d, jid, pp)

        J_fd = np.column_stack([(at(pin.integrate(model, q, h * e))[0] - at(pin.integrate(model, q, -h * e))[0])
                                / (2 * h) for e in np.eye(model.nv)])
        np.testing.assert_allclose(J, J_fd, atol=1e-6)
        Jdot_qdot_fd = (at(pin.integrate(model, q, h * v))[1] - at(pin.integrate(model, q, -h * v))[1]) / (2 * h) @ v
        data = kinematics(model, q, v)  # FK with v and zero acceleration
        np.testing.assert_allclose(point_jdot_qdot(model, data, jid, p), Jdot_qdot_fd, atol=1e-6)
        # cross-check: classical acceleration of a frame at the point
        probe = pin.Model(model)
        fid = probe.addFrame(pin.Frame("probe", jid, pin.SE3(np.eye(3), p_local), pin.FrameType.OP_FRAME))
        d2 = kinematics(probe, q, v)
        a = pin.getFrameClassicalAcceleration(probe, d2, fid, pin.LOCAL_WORLD_ALIGNED).linear
        np.testing.assert_allclose(point_jdot_qdot(probe, d2, jid, p), a, atol=1e-12)



def test_point_kinematics_equal_their_literal_formulas(panda):
    """J_c (pin.skew) equals the np.cross form of (28) to rounding, J-dot_c q-dot (floats) that of (29) exactly."""
    model, _ = panda
    rng = np.random.default_rng(3)
    LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
    for _ in range(50):
        q = pin.randomConfiguration(model)
        data = kinematics(model, q, rng.standard_normal(model.nv))
        pin.computeJointJacobians(model, data, q)
        jid = int(rng.integers(1, model.njoints))
        p = rng.uniform(-1.0, 1.0, 3)
        J = pin.getJointJacobian(model, data, jid, LWA)
        r = p - data.oMi[jid].translation
        np.testing.assert_allclose(point_jacobian(model, data, jid, p), J[:3] - np.cross(r, J[3:], axis=0),
                                   rtol=0, atol=1e-14)
        M, v, a = data.oMi[jid], data.v[jid], data.a[jid]
        w = M.rotation @ v.angular
        expected = (M.rotation @ (a.linear + np.cross(v.angular, v.linear)) + np.cross(M.rotation @ a.angular, r)
                    + np.cross(w, np.cross(w, r)))
        np.testing.assert_array_equal(point_jdot_qdot(model, data, jid, p), expected)

def test_field_jacobian_of_witness_point():
    model, geom = tiny()
    q = np.array([0.3, -0.5, 0.8])
    data = kinematics(model, q)
    pin.computeJointJacobians(model, data, q)
    field = DistanceField(model, geom, ["tip"], [Obstacle.sphere("o", [0.5, 0.3, 0.5])], surveillance=1.0,
                          geometries=["link2"])
    field.update(data)
    e = field.element_index("link2")
    J = field.jacobian(data, e, 0)
    # numerical: witness point moved with the link (fixed in joint 2's frame)
    p_local = data.oMi[2].actInv(field.p_robot[e, 0])
    h = 1e-6
    cols = []
    for k in range(3):
        dq = np.zeros(3)
        dq[k] = h
        dp = kinematics(model, q + dq).oMi[2].act(p_local) - kinematics(model, q - dq).oMi[2].act(p_local)
        cols.append(dp / (2 * h))
    np.testing.assert_allclose(J, np.column_stack(cols), atol=1e-6)


# ---------------------------------------------------------------- moving obstacles, nearest
@ANALYTIC
def test_moving_obstacles(analytic):
    model, geom = tiny()
    data = kinematics(model, np.zeros(model.nq))  # tip at (.5,.05,.3)

    def circle(t):
        return pin.SE3(np.eye(3), np.array([0.5 + 0.2 * np.cos(t), 0.05 + 0.2 * np.sin(t), 0.3]))

    obs = [Obstacle.sphere("linear", [0.0, 0.0, 0.0], 0.01, velocity=[0.1, 0.0, 0.0]),
           Obstacle.sphere("circle", [0.0, 0.0, 0.0], motion=circle),
           Obstacle.box("static", [1.0, 1.0, 1.0], [0.1, 0.1, 0.1])]
    assert obs[0].is_moving and obs[1].is_moving and not obs[2].is_moving
    field = DistanceField(model, None, ["tip"], obs, surveillance=5.0, analytic_spheres=analytic)
    tip = np.array([0.5, 0.05, 0.3])
    for t in (0.0, 0.7, 2.5):
        field.update(data, None, t)
        c0 = np.array([0.1 * t, 0.0, 0.0])
        np.testing.assert_allclose(obs[0].placement_at(t).translation, c0)
        assert field.distance[0, 0] == pytest.approx(np.linalg.norm(tip - c0) - 0.01, abs=TOL)
        assert field.distance[0, 1] == pytest.approx(0.2, abs=TOL)
        np.testing.assert_allclose(field.p_obstacle[0, 1], circle(t).translation, atol=TOL)
        np.testing.assert_allclose(field.obstacle_placements[1].translation, circle(t).translation)
    np.testing.assert_allclose(obs[1].linear_velocity_at(0.0), [0.0, 0.2, 0.0], atol=1e-6)
    np.testing.assert_allclose(obs[0].linear_velocity_at(3.0), [0.1, 0.0, 0.0])


def test_nearest_per_element_and_overall():
    model, geom = tiny()
    rng = np.random.default_rng(8)
    obs = [Obstacle.sphere(f"o{k}", c) for k, c in enumerate(rng.uniform(-0.5, 0.5, (4, 3)) + [0, 0, 0.3])]
    field = DistanceField(model, geom, ["cp_mid", "tip"], obs, surveillance=0.3)
    for _ in range(10):
        field.update(kinematics(model, rng.uniform(-3, 3, model.nq)))
        res = field.nearest("point")
        np.testing.assert_array_equal(res.elements, [3, 4])
        D = np.where(field.in_range[3:], field.distance[3:], np.inf)
        np.testing.assert_array_equal(res.distance, D.min(axis=1))
        assert res.value == D.min()
        if np.isfinite(res.value):
            assert field.distance[res.element, res.obstacle_index] == res.value
        else:
            assert res.element == -1 and res.obstacle_index == -1
        assert field.nearest().value == np.where(field.in_range, field.distance, np.inf).min()
    empty = DistanceField(model, geom, [], [], surveillance=0.3)
    empty.update(kinematics(model, np.zeros(3)))
    assert empty.nearest().value == np.inf and empty.nearest().element == -1


def test_self_pairs_match_direct_coal():
    model, geom = tiny()
    field = DistanceField(model, geom, [], [], surveillance=10.0, self_pairs=[("link2", "base"), ("ball3", "base")])
    rng = np.random.default_rng(9)
    for _ in range(5):
        data = kinematics(model, rng.uniform(-3, 3, model.nq))
        field.update(data)
        gdata = pin.GeometryData(geom)
        pin.updateGeometryPlacements(model, data, geom, gdata)
        for k, (a, b) in enumerate([(0, 2), (1, 2)]):
            d = coal.distance(geom.geometryObjects[a].geometry, gdata.oMg[a], geom.geometryObjects[b].geometry,
                              gdata.oMg[b], coal.DistanceRequest(), coal.DistanceResult())
            assert field.self_distance[k] == pytest.approx(d, abs=1e-12)
            assert np.linalg.norm(field.self_normal[k]) == pytest.approx(1.0)
        k, d = field.nearest_self()
        assert d == field.self_distance.min()


# ---------------------------------------------------------------- errors
def test_typed_errors():
    model, geom = tiny()
    with pytest.raises(NonFiniteError, match="nan"):
        Obstacle.sphere("x", [np.nan, 0.0, 0.0])
    with pytest.raises(NonFiniteError, match="inf"):
        Obstacle.box("x", [0.0, np.inf, 0.0], [1, 1, 1])
    with pytest.raises(GeometryError, match="-0.5"):
        Obstacle.sphere("x", [0, 0, 0], -0.5)
    with pytest.raises(GeometryError, match="-1"):
        Obstacle.capsule("x", [0, 0, 0], [0, 0, 1], -1)
    with pytest.raises(ShapeError):
        Obstacle.sphere("x", [0, 0])
    with pytest.raises(GeometryError, match="rotation"):
        Obstacle.box("x", [0, 0, 0], [1, 1, 1], rotation=2 * np.eye(3))
    with pytest.raises(GeometryError):
        Obstacle.sphere("x", [0, 0, 0], velocity=[1, 0, 0], motion=lambda t: pin.SE3.Identity())
    with pytest.raises(GeometryError, match="degenerate"):
        Obstacle.mesh("flat", [[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]])
    with pytest.raises(UnknownFrameError, match="'nope'.*'tip'"):
        DistanceField(model, geom, ["nope"], [])
    with pytest.raises(UnknownNameError, match="'nope'.*'ball3'"):
        DistanceField(model, geom, [], [], geometries=["nope"])
    with pytest.raises(UnknownNameError, match="'nope'"):
        DistanceField(model, geom, [], [], self_pairs=[("base", "nope")])
    with pytest.raises(GeometryError, match="duplicate obstacle"):
        DistanceField(model, geom, [], [Obstacle.sphere("a", [0, 0, 0])] * 2)
    with pytest.raises(GeometryError, match="surveillance"):
        DistanceField(model, geom, [], [], surveillance=-0.1)
    field = DistanceField(model, geom, ["tip"], [])
    with pytest.raises(UnknownNameError, match="'geometry', 'point'"):
        field.nearest("link")
    with pytest.raises(UnknownNameError):
        field.obstacle_index("nope")
    assert issubclass(GeometryError, HqpTpmError) and issubclass(GeometryError, ValueError)


def test_convexified_panda_geometry_is_convex(panda):
    model, geom = panda
    field = DistanceField(model, geom, [], [], geometries=["panda_link4_0", "panda_leftfinger_0"])
    shapes = [g.geometry for g in field.geometry_model.geometryObjects]
    assert isinstance(shapes[0], coal.ConvexBase) and isinstance(shapes[1], coal.Box)
    assert isinstance(geom.geometryObjects[4].geometry, coal.BVHModelBase)  # caller's model untouched


def _records(field):
    return [a.copy() for a in (field.distance, field.p_robot, field.p_obstacle, field.normal, field.computed,
                               field.in_range, field.snapshot()[1])]


@pytest.mark.parametrize("radius", [0.0, 0.05])
def test_sphere_block_in_place_equals_its_reference_bit_for_bit(radius):
    """The in-place sphere block (views of the records) against the readable one: identical arrays, also when a
    control point sits on an obstacle's centre (fallback normal) and with spherical links (non-zero radii)."""
    model, geom = tiny()
    rng = np.random.default_rng(11)
    data = kinematics(model, rng.uniform(-2, 2, model.nq), rng.normal(size=model.nv))
    tip = data.oMf[model.getFrameId("tip")].translation.copy()
    obs = [Obstacle.sphere("a", [0.3, 0.2, 0.5], radius), Obstacle.sphere("b", [0.1, -0.3, 0.2]),
           Obstacle.sphere("on_tip", tip, radius)]
    geoms = ["ball3"] if radius else []
    fast = DistanceField(model, geom, ["cp_mid", "tip"], obs, surveillance=0.3, geometries=geoms)
    slow = DistanceField(model, geom, ["cp_mid", "tip"], obs, surveillance=0.3, geometries=geoms)
    assert fast._sph_views
    slow._update_spheres = slow._update_spheres_reference
    for q in [None, *rng.uniform(-2, 2, (20, model.nq))]:
        d = data if q is None else kinematics(model, q, rng.normal(size=model.nv))
        fast.update(d)
        slow.update(d)
        for a, b in zip(_records(fast), _records(slow), strict=True):
            np.testing.assert_array_equal(a, b)


def test_pairwise_and_batched_coal_paths_give_the_same_bits(panda_convex, monkeypatch):
    """Whether a pair's result is post-processed alone or in a batch (which depends on how many pairs the broad
    phase kept) does not change a bit of it: the normal's norm is the same einsum in both paths (``u.dot(u)``
    differs from it in the last bit for about 1 vector in 9, which made a culled whole-body run diverge)."""
    model, geom = panda_convex
    rng = np.random.default_rng(5)
    points = ["panda_link3", "panda_link5", "panda_hand"]
    data0 = model.createData()
    pin.framesForwardKinematics(model, data0, pin.randomConfiguration(model))
    obs = scattered_obstacles(rng, [data0.oMf[model.getFrameId(f)].translation for f in rng.choice(points, 6)])
    fields = {}
    for path, batch in (("pairwise", 10**9), ("batched", 0)):
        monkeypatch.setattr(distances, "BATCH_MIN", batch)
        field = DistanceField(model, geom, points, obs, surveillance=10.0, analytic_spheres=False)
        field.update(data0)
        fields[path] = field
    assert fields["pairwise"].computed.all()
    for name in ("distance", "p_robot", "p_obstacle", "normal"):
        np.testing.assert_array_equal(getattr(fields["pairwise"], name), getattr(fields["batched"], name), err_msg=name)


@pytest.mark.parametrize("name", ["lwr_relaxed", "romeo_obstacles_sns_tpm"])
def test_a_controller_with_a_distance_field_copies_and_pickles(name):
    """A controller whose policy owns distance fields (Algorithm 1, the whole-body avoidance) deep-copies and pickles
    (coal's functors and pinocchio's GeometryData do not: the field is built again from its arguments, its history
    restored), and the copy goes on as the original does, to the bit (on 82bfea4: RuntimeError from boost.python)."""
    import copy
    import pickle

    from hqp_tpm.app.build import build_run
    from hqp_tpm.app.scenario import load

    ctrl = build_run(load(name)).controller
    for _ in range(30):
        ctrl.step()
    copies = [copy.deepcopy(ctrl), pickle.loads(pickle.dumps(ctrl))]
    for _ in range(60):
        want = ctrl.step().command
        for twin in copies:
            np.testing.assert_array_equal(twin.step().command, want)
    assert copies[0].policy.field is not ctrl.policy.field

"""The compiled kernels of the distance field and of Algorithm 1 (hqp_tpm.geometry._compiled) equal the readable
code: the sphere block, Algorithm 1's nearest pairs and the broad phase bit for bit (their choices must be the
same), the witness point's J-dot q-dot and the avoidance row within 1e-12 of their scale (:func:`close`: the
kernels rotate 3-vectors in a fixed order, numpy's ``R.dot(x)`` in the order of the CPU's BLAS kernel, so the two
agree bit for bit on some machines and a few ulps apart on others), on random draws and on the ties, infinities
and NaN the readable code decides."""

import example_robot_data as erd
import numpy as np
import pinocchio as pin
import pytest

from hqp_tpm.app.build import build
from hqp_tpm.app.scenario import load
from hqp_tpm.geometry import _compiled as kernels
from hqp_tpm.geometry.distances import DistanceField
from hqp_tpm.geometry.obstacles import Obstacle
from hqp_tpm.geometry.witness import point_jdot_qdot
from hqp_tpm.robot import _compiled

pytestmark = pytest.mark.skipif(not _compiled.AVAILABLE, reason="numba is not importable")


def close(actual, desired):
    """``actual`` equals ``desired`` within 1e-12 of ``max(1, |desired|)``."""
    desired = np.asarray(desired, dtype=float)
    scale = max(1.0, float(np.abs(desired).max(initial=0.0)))
    np.testing.assert_allclose(actual, desired, rtol=0, atol=1e-12 * scale)


def _records(field):
    return [a.copy() for a in (field.distance, field.p_robot, field.p_obstacle, field.normal, field.computed,
                               field.in_range, field.snapshot()[1])]


@pytest.fixture(scope="module")
def panda():
    robot = erd.load("panda")
    return robot.model


@pytest.mark.parametrize("radius", [0.0, 0.07])
def test_sphere_block_kernel_equals_the_readable_block(panda, radius, monkeypatch):
    """Control points against point and sphere obstacles, 300 random configurations: every record equal."""
    model = panda
    rng = np.random.default_rng(5)
    frames = [f.name for f in model.frames if f.name.startswith("panda_link")]
    obs = [Obstacle.sphere(f"o{i}", rng.uniform(-0.6, 0.6, 3), radius * i) for i in range(4)]
    fast = DistanceField(model, None, frames, obs, surveillance=0.4)
    slow = DistanceField(model, None, frames, obs, surveillance=0.4)
    assert fast._sph_kernel_args is not None
    slow._update_spheres = slow._update_spheres_reference
    data = model.createData()
    for _ in range(300):
        q = pin.randomConfiguration(model)
        pin.forwardKinematics(model, data, q)
        pin.updateFramePlacements(model, data)
        monkeypatch.setattr(_compiled, "ENABLED", True)
        fast.update(data)
        monkeypatch.setattr(_compiled, "ENABLED", False)
        slow.update(data)
        for a, b in zip(_records(fast), _records(slow), strict=True):
            np.testing.assert_array_equal(a, b)


def test_sphere_block_kernel_hands_coinciding_centres_to_the_readable_code(panda):
    """A control point on an obstacle's centre: the kernel returns False before writing, the fallback normal
    is the readable code's."""
    model = panda
    data = model.createData()
    q = pin.neutral(model)
    pin.forwardKinematics(model, data, q)
    pin.updateFramePlacements(model, data)
    p = data.oMf[model.getFrameId("panda_link4")].translation.copy()
    obs = [Obstacle.sphere("on", p), Obstacle.sphere("off", p + 0.1)]
    field = DistanceField(model, None, ["panda_link4", "panda_link7"], obs, surveillance=0.4)
    field.update(data)
    ref = DistanceField(model, None, ["panda_link4", "panda_link7"], obs, surveillance=0.4)
    ref._update_spheres = ref._update_spheres_reference
    ref.update(data)
    for x, y in zip(_records(field), _records(ref), strict=True):
        np.testing.assert_array_equal(x, y)
    before = _records(field)
    field.normal[...] = 7.0  # what the kernel would overwrite
    a = field._sph_kernel_args
    assert not kernels.sphere_block(field._elem_center, a[0], field._obs_center, a[1], *a[2:])
    assert (field.normal == 7.0).all()
    field.normal[...] = before[3]
    assert np.isfinite(field.normal[0, 0]).all() and field.distance[0, 0] == 0.0


def test_point_jdot_qdot_kernel_equals_the_readable_function(panda, monkeypatch):
    """The field's witness-point J-dot q-dot, compiled and readable, at 500 random states and points."""
    model = panda
    rng = np.random.default_rng(9)
    field = DistanceField(model, None, ["panda_link3"], [Obstacle.sphere("o", [0.3, 0.0, 0.5])], surveillance=9.0)
    data = model.createData()
    for _ in range(500):
        q = pin.randomConfiguration(model)
        v = rng.normal(size=model.nv) * rng.choice([1e-3, 1.0, 30.0])
        pin.forwardKinematics(model, data, q, v, np.zeros(model.nv))
        pin.updateFramePlacements(model, data)
        field.update(data)
        field.p_robot[0, 0] = rng.uniform(-1, 1, 3)
        monkeypatch.setattr(_compiled, "ENABLED", True)
        fast = field.jdot_qdot(data, 0, 0)
        monkeypatch.setattr(_compiled, "ENABLED", False)
        slow = field.jdot_qdot(data, 0, 0)
        close(fast, slow)
        np.testing.assert_array_equal(slow, point_jdot_qdot(model, data, field.joint_ids[0], field.p_robot[0, 0]))


def _nearest_both(policy, monkeypatch):
    out = []
    for enabled in (True, False):
        monkeypatch.setattr(_compiled, "ENABLED", enabled)
        out.append(policy._nearest())
    return out


def _same(a, b):
    assert len(a) == len(b)
    for x, y in zip(a, b, strict=True):
        if x is None or y is None:
            assert x is None and y is None
        else:
            np.testing.assert_array_equal(x, y)


def test_algorithm1_nearest_kernel_takes_the_readable_choices(monkeypatch):
    """Random distances with ties, out-of-range pairs, +inf and NaN: the same (j_ee, d_ee, n_ee, k, j, d, r_hat)."""
    ctrl = build(load("lwr_relaxed"))[1]
    policy = ctrl.policy
    f = policy.field
    rng = np.random.default_rng(3)
    M, H = f.distance.shape
    f.normal[...] = rng.normal(size=f.normal.shape)
    for trial in range(3000):
        D = rng.choice([0.01, 0.05, 0.1, 0.14, 0.2, 0.6], size=(M, H)) if trial % 2 else rng.uniform(-0.1, 0.7, (M, H))
        if trial % 5 == 0:
            D[rng.random((M, H)) < 0.3] = np.inf
        if trial % 50 == 0:
            D[rng.integers(M), rng.integers(H)] = np.nan
        f.distance[...] = D
        f.in_range[...] = rng.random((M, H)) < 0.8 if trial % 3 else D <= f.surveillance
        a, b = _nearest_both(policy, monkeypatch)
        _same(a, b)
    f.in_range[...] = False  # nothing in range
    a, b = _nearest_both(policy, monkeypatch)
    _same(a, b)
    assert a[0] == -1 and a[3] == -1 and a[5] == np.inf


@pytest.mark.parametrize("order", [1, 2])
def test_avoidance_row_kernel_equals_the_readable_avoidance_rows(panda, order):
    """DistanceField.avoidance_row (one compiled call: J_c, J-dot q-dot and the 1-D row (29)) against the readable
    Avoidance rows from DistanceField.jacobian/jdot_qdot, at 400 random states, points and normals; the lazily
    assigned pair (Avoidance.assign_pair) gives the readable rows too. Two Data objects in turn: the joint views
    the field keeps are those of the Data it is given."""
    from hqp_tpm.tasks.avoidance import Avoidance

    model = panda
    rng = np.random.default_rng(order + 20)
    frames = ["panda_link3", "panda_link5", "panda_hand"]
    field = DistanceField(model, None, frames, [Obstacle.sphere("o", [0.3, 0.0, 0.5])], surveillance=9.0)
    datas = [model.createData(), model.createData()]
    ref, lazy = Avoidance("ref"), Avoidance("lazy")
    J, b = np.zeros((1, model.nv)), np.zeros(1)
    for i in range(400):
        data = datas[int(rng.integers(2))] if i > 100 else datas[0]
        q = pin.randomConfiguration(model)
        v = rng.normal(size=model.nv) * rng.choice([1e-3, 1.0, 30.0])
        pin.forwardKinematics(model, data, q, v, np.zeros(model.nv))
        pin.computeJointJacobians(model, data)
        pin.updateFramePlacements(model, data)
        field.update(data)
        k = int(rng.integers(len(frames)))
        field.p_robot[k, 0] = rng.uniform(-1, 1, 3)
        normal = rng.normal(size=3)
        normal /= np.linalg.norm(normal)
        mag = float(rng.uniform(0, 3))
        ref.assign(field.jacobian(data, k, 0), field.jdot_qdot(data, k, 0), normal, mag)
        field.avoidance_row(data, k, 0, normal, mag, order, J, b)
        close(J, ref.jacobian(None))
        close(b, ref.command(None, 0.0, order))
        lazy.assign_pair(field, data, k, 0, normal, mag)
        close(lazy.jacobian(None), ref.jacobian(None))
        close(lazy.command(None, 0.0, order), ref.command(None, 0.0, order))


def test_near_pairs_kernel_equals_the_readable_broad_phase():
    """The broad phase's compiled kernel keeps the pairs the readable one keeps (same index arrays), on random
    centres and radii with pairs exactly at the surveillance distance."""
    from hqp_tpm.geometry.pairs import near_pairs

    rng = np.random.default_rng(17)
    for trial in range(2000):
        A, B, K = int(rng.integers(1, 12)), int(rng.integers(1, 5)), int(rng.integers(0, 40))
        Ca, Cb = rng.uniform(-1, 1, (A, 3)), rng.uniform(-1, 1, (B, 3))
        ra, rb = rng.uniform(0, 0.3, A), rng.uniform(0, 0.3, B)
        ia, ib = rng.integers(0, A, K), rng.integers(0, B, K)
        s = float(rng.uniform(0, 0.5))
        ref = near_pairs(Ca[ia], Cb[ib], ra[ia], rb[ib], s)
        if K and trial % 4 == 0:  # a pair exactly at the threshold
            s = float(np.sqrt(np.einsum("ij,ij->i", Ca[ia] - Cb[ib], Ca[ia] - Cb[ib]))[0] - ra[ia[0]] - rb[ib[0]])
            ref = near_pairs(Ca[ia], Cb[ib], ra[ia], rb[ib], s)
            assert 0 in ref
        np.testing.assert_array_equal(kernels.near_pairs(Ca, ia, Cb, ib, ra, rb, s), ref)


def test_points_only_short_update_equals_the_full_update():
    """A field of control points and fixed sphere obstacles (lwr_relaxed's) takes DistanceField.update's short path
    (frame positions, the compiled sphere block, in_range): the records of the full update bit for bit, at random
    states, with two Data objects in turn (a new Data goes through the full update first)."""
    ctrl = build(load("lwr_relaxed"))[1]
    model, f = ctrl.robot.model, ctrl.policy.field
    assert f._points_only
    full = DistanceField(model, None, f.names, f.obstacles, surveillance=f.surveillance)
    full._points_only = False
    datas = [model.createData(), model.createData()]
    rng = np.random.default_rng(8)
    for i in range(300):
        data = datas[int(rng.integers(2))] if i > 50 else datas[0]
        q = pin.randomConfiguration(model) if i % 2 else rng.uniform(-3, 3, model.nq)
        pin.forwardKinematics(model, data, q)
        pin.updateFramePlacements(model, data)
        f.update(data, None, 0.001 * i)
        full.update(data, None, 0.001 * i)
        for x, y in zip(_records(f), _records(full), strict=True):
            np.testing.assert_array_equal(x, y)
        assert f.t == full.t


def _romeo_fields(surveillance: float, self_surveillance: float):
    """Two fields of romeo_obstacles_sns_tpm's collision model, self pairs and obstacles (a sphere and a box), plus
    a box whose face passes through a control point (coinciding witness points: the fallback normal)."""
    from hqp_tpm.policies import whole_body as wb

    ctx = build(load("romeo_obstacles_sns_tpm"))
    robot, policy = ctx[0], ctx[3]
    data = robot.model.createData()
    q0 = ctx[1].q.copy()
    pin.framesForwardKinematics(robot.model, data, q0)
    p = data.oMf[robot.model.getFrameId("l_gripper")].translation
    touching = Obstacle.box("touch", p + [0.0, 0.0, 0.05], [0.05, 0.05, 0.05])
    obstacles = [*policy.obstacles, touching]
    fields = [DistanceField(robot.model, wb.control_geometries(robot), ["l_gripper", "r_gripper"], obstacles,
                            surveillance=surveillance, self_pairs=policy.pairs, self_surveillance=self_surveillance)
              for _ in range(2)]
    return robot, q0, fields


@pytest.mark.parametrize("surveillance", [0.1, 0.5])  # few pairs queried (one at a time) and many (in a batch)
def test_compiled_update_equals_the_readable_update_with_meshes_and_self_pairs(surveillance, monkeypatch):
    """Convex meshes, control points, sphere and box obstacles, self pairs: the compiled update (bounding-sphere
    centres, the coal queries' records, the self pairs' records in compiled calls) writes the records of the
    readable update bit for bit, at 150 configurations around romeo's (q0 itself: a control point on a box's face)."""
    robot, q0, (fast, slow) = _romeo_fields(surveillance, surveillance / 2)
    data = robot.model.createData()
    rng = np.random.default_rng(4)
    queried = set()
    for i in range(150):
        q = q0.copy()
        if i:
            q[7:] += rng.normal(scale=0.4, size=robot.model.nq - 7)
        pin.framesForwardKinematics(robot.model, data, q)
        monkeypatch.setattr(_compiled, "ENABLED", True)
        fast.update(data, None, 0.001 * i)
        monkeypatch.setattr(_compiled, "ENABLED", False)
        slow.update(data, None, 0.001 * i)
        for x, y in zip(_records(fast), _records(slow), strict=True):
            np.testing.assert_array_equal(x, y)
        for x, y in zip((fast.self_distance, fast.self_p1, fast.self_p2, fast.self_normal, fast.self_computed,
                         fast.self_in_range, fast.snapshot()[2]),
                        (slow.self_distance, slow.self_p1, slow.self_p2, slow.self_normal, slow.self_computed,
                         slow.self_in_range, slow.snapshot()[2]), strict=True):
            np.testing.assert_array_equal(x, y)
        close(fast._elem_center, slow._elem_center)  # (bit for bit where Eigen sums SE3.act as the kernel does)
        queried.add((int(fast.computed.sum()) >= 8, bool(fast.self_computed.any())))
        if i == 0:  # the control point on the box's face: witness points coincide, coal's normal (pointing out)
            e, j = fast.element_index("l_gripper"), fast.obstacle_index("touch")
            assert fast.distance[e, j] == pytest.approx(0.0, abs=1e-9)
            np.testing.assert_allclose(fast.normal[e, j], [0.0, 0.0, -1.0], atol=1e-9)
    assert (True, True) in queried if surveillance > 0.2 else (False, True) in queried


def test_normal_jacobian_kernel_equals_normal_times_the_point_jacobian(monkeypatch):
    """The whole-body obstacle rows n^T J_c, compiled (numpy's dot for both products) and readable
    (``normal @ jacobian``), at 300 random Romeo configurations and witness points (:func:`close`; bit for bit where
    numba and numpy call the same BLAS kernels)."""
    robot, q0, (field, _) = _romeo_fields(9.0, 0.05)
    model, data = robot.model, robot.model.createData()
    rng = np.random.default_rng(12)
    for _ in range(300):
        q = q0.copy()
        q[7:] += rng.normal(scale=0.4, size=model.nq - 7)
        pin.computeJointJacobians(model, data, q)
        pin.updateFramePlacements(model, data)
        e, j = int(rng.integers(field.n_elements)), int(rng.integers(field.n_obstacles))
        field.p_robot[e, j] = rng.uniform(-1, 1, 3)
        field.normal[e, j] = rng.normal(size=3)
        monkeypatch.setattr(_compiled, "ENABLED", True)
        fast = field.normal_jacobian(data, e, j, np.empty(model.nv))
        monkeypatch.setattr(_compiled, "ENABLED", False)
        slow = field.normal_jacobian(data, e, j, np.empty(model.nv))
        close(fast, slow)
        np.testing.assert_array_equal(slow, field.normal[e, j] @ field.jacobian(data, e, j))


def test_closest_per_obstacle_kernel_takes_the_readable_choices(monkeypatch):
    """WholeBody.obstacle_pairs ("per_obstacle"), compiled and readable: the same (element, obstacle, distance) on
    random grids with ties, culled (+inf) pairs, pairs out of range and beyond the activation distance."""
    from hqp_tpm.policies.whole_body import WholeBody

    policy = build(load("romeo_obstacles_sns_tpm"))[3]
    assert isinstance(policy, WholeBody) and policy.obstacle_rows == "per_obstacle"
    f = policy.field
    rng = np.random.default_rng(21)
    sizes = set()
    for _ in range(500):
        D = rng.choice([-0.01, 0.02, 0.05, 0.09, 0.099, 0.1, 0.2, np.inf], size=f.distance.shape)
        D[rng.random(D.shape) < 0.3] = rng.uniform(-0.02, 0.3)
        f.distance[...] = D
        f.in_range[...] = (D <= f.surveillance) & (rng.random(D.shape) < rng.choice([0.03, 0.1, 0.9]))
        both = []
        for enabled in (True, False):
            monkeypatch.setattr(_compiled, "ENABLED", enabled)
            both.append(policy.obstacle_pairs())
        assert both[0] == both[1]
        sizes.add(len(both[0]))
    assert sizes == {0, 1, 2}


def test_self_normal_jacobian_kernel_equals_the_readable_self_row(monkeypatch):
    """The whole-body self row n^T (J_1 - J_2), compiled and readable, at 300 random Romeo configurations and witness
    points (:func:`close`; bit for bit where numba and numpy call the same BLAS kernels)."""
    from hqp_tpm.geometry.witness import point_jacobian

    robot, q0, (field, _) = _romeo_fields(0.1, 0.05)
    model, data = robot.model, robot.model.createData()
    rng = np.random.default_rng(13)
    for _ in range(300):
        q = q0.copy()
        q[7:] += rng.normal(scale=0.4, size=model.nq - 7)
        pin.computeJointJacobians(model, data, q)
        k = int(rng.integers(len(field.self_pairs)))
        field.self_p1[k], field.self_p2[k] = rng.uniform(-1, 1, (2, 3))
        field.self_normal[k] = rng.normal(size=3)
        monkeypatch.setattr(_compiled, "ENABLED", True)
        fast = field.self_normal_jacobian(data, k, np.empty(model.nv))
        monkeypatch.setattr(_compiled, "ENABLED", False)
        slow = field.self_normal_jacobian(data, k, np.empty(model.nv))
        close(fast, slow)
        a, b = field.self_pairs[k]
        np.testing.assert_array_equal(slow, field.self_normal[k] @ (
            point_jacobian(model, data, field.joint_ids[a], field.self_p1[k])
            - point_jacobian(model, data, field.joint_ids[b], field.self_p2[k])))

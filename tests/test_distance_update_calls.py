"""The distance field's compiled update in three calls around the coal queries (hqp_tpm.geometry.distances,
``DistanceField._update_compiled``): the geometry placements read through one view of pinocchio's memory, and the
records it writes equal the readable update's bit for bit, also when a record had pairs and then has none."""

import numpy as np
import pinocchio as pin
import pytest

from hqp_tpm.app.build import build
from hqp_tpm.app.scenario import load
from hqp_tpm.geometry import distances
from hqp_tpm.geometry.distances import DistanceField
from hqp_tpm.robot import _compiled

pytestmark = pytest.mark.skipif(not _compiled.AVAILABLE, reason="numba is not importable")


@pytest.fixture(scope="module")
def whole_body():
    ctx = build(load("romeo_obstacles_sns_tpm"))
    return ctx[0], ctx[1].q.copy(), ctx[3]


def _fields(policy, n=2):
    f = policy.field
    return [DistanceField(f.model, f.geometry_model, (), policy.obstacles, surveillance=f.surveillance,
                          self_pairs=policy.pairs, self_surveillance=f.self_surveillance) for _ in range(n)]


def test_placements_block_reads_every_geometry_placement(whole_body):
    """The (ng, 4, 3) view holds each placement's rotation (columns) and origin, at every configuration pinocchio
    writes (the memory it views is pinocchio's own: no copy to refresh)."""
    robot, q0, policy = whole_body
    field = _fields(policy, 1)[0]
    data = robot.model.createData()
    rng = np.random.default_rng(1)
    for i in range(20):
        q = q0.copy()
        q[7:] += rng.normal(scale=0.5, size=robot.model.nq - 7)
        pin.framesForwardKinematics(robot.model, data, q)
        field.update(data, None, 0.001 * i)
        if field._geom_views is None:  # (a pinocchio that returns copies: the per-placement reads)
            pytest.skip("this pinocchio returns copies of the placements")
        block = field._block
        assert block is not None and block.shape == (field.n_geometries, 4, 3) and not block.flags.writeable
        for k, M in enumerate(field._gdata.oMg):
            np.testing.assert_array_equal(block[k, :3].T, M.rotation)
            np.testing.assert_array_equal(block[k, 3], M.translation)


def test_placements_block_refuses_placements_not_side_by_side():
    """Placements that are not one run of pinocchio's memory (separate SE3 objects): None, the per-placement reads."""
    refs = [pin.SE3.Random() for _ in range(3)]
    assert distances._placements_block(refs) is None
    assert distances._placements_block([]) is None


def test_compiled_update_equals_the_readable_update_of_the_whole_body_field(whole_body, monkeypatch):
    """The whole-body field (convex hulls, a sphere and a box, self pairs; no control points): the records of the
    compiled update equal the readable update's bit for bit over 300 configurations whose pair counts go up and
    down (records with pairs, then with none: cleared), the compiled update took the three-call path, and its
    nearest self pair (found in its last call) is the readable ``nearest_self``'s."""
    robot, q0, policy = whole_body
    fast, slow = _fields(policy)
    calls = []
    monkeypatch.setattr(fast, "_update_compiled", lambda f=fast._update_compiled: calls.append(1) or f())
    data = robot.model.createData()
    rng = np.random.default_rng(2)
    counts, nearest = [], set()
    for i in range(300):
        q = q0.copy()
        q[7:] += rng.normal(scale=[0.05, 0.6][i % 7 < 3], size=robot.model.nq - 7)
        pin.framesForwardKinematics(robot.model, data, q)
        monkeypatch.setattr(_compiled, "ENABLED", True)
        fast.update(data, None, 0.001 * i)
        monkeypatch.setattr(_compiled, "ENABLED", False)
        slow.update(data, None, 0.001 * i)
        for x, y in zip((fast.distance, fast.p_robot, fast.p_obstacle, fast.normal, fast.computed, fast.in_range,
                         fast.self_distance, fast.self_p1, fast.self_p2, fast.self_normal, fast.self_computed,
                         fast.self_in_range, *fast.snapshot()[1:]),
                        (slow.distance, slow.p_robot, slow.p_obstacle, slow.normal, slow.computed, slow.in_range,
                         slow.self_distance, slow.self_p1, slow.self_p2, slow.self_normal, slow.self_computed,
                         slow.self_in_range, *slow.snapshot()[1:]), strict=True):
            np.testing.assert_array_equal(x, y)
        assert fast._nearest_self is not None  # (found by the update's last call)
        k, d = fast.nearest_self()
        assert (k, d) == slow.nearest_self() and type(k) is int and type(d) is float
        nearest.add(k >= 0)
        counts.append((int(fast.computed.sum()), int(fast.self_computed.sum())))
    assert len(calls) == 300 and nearest == {True, False}
    obstacle, self_ = np.array(counts).T
    for n in (obstacle, self_):  # pairs queried, and steps with none right after steps with some
        assert n.max() > 0 and ((n[1:] == 0) & (n[:-1] > 0)).any()


def test_repulsive_bound_of_a_list_equals_the_arrays():
    """WholeBody's bound r(d) of a list of distances (Python floats, the plan's path) equals the array's bit for bit,
    ties at the activation and safety distances and penetrations included."""
    from hqp_tpm.policies.whole_body import repulsive_bound

    rng = np.random.default_rng(3)
    for _ in range(3000):
        d = rng.choice([0.1, 0.03, 0.0, -0.01, rng.uniform(-0.05, 0.12)], size=int(rng.integers(1, 4))).tolist()
        for args in ((0.1, 0.03, 0.3), (0.05, 0.01, 0.3)):
            fast, slow = repulsive_bound(d, *args), repulsive_bound(np.array(d), *args)
            assert fast.dtype == slow.dtype == np.float64
            np.testing.assert_array_equal(fast, slow)

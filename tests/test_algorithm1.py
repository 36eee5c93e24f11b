"""Algorithm 1 of papers/000: the stack it builds in hand-made situations on the LWR IV."""

import numpy as np
import pytest

from hqp_tpm.errors import UnknownNameError
from hqp_tpm.geometry.obstacles import Obstacle
from hqp_tpm.policies.algorithm1 import Algorithm1
from hqp_tpm.robot.model import Robot
from hqp_tpm.robot.state import State
from hqp_tpm.tasks import FramePosition, Gains, Pointing

Q0 = np.array([0.923, -0.854, 0.903, 1.195, 0.971, 1.796, 0.0])
CPS = [f"lwr_cp_{k}" for k in range(1, 9)]


@pytest.fixture(scope="module")
def lwr():
    return Robot.load("lwr4")


def make(lwr, obstacles, alpha_deg=5.0, inequality=True, dim=1):
    ee = FramePosition(lwr, "lwr_ee", None, Gains(40, 20), name="ee")
    st = State(lwr).update(Q0, np.zeros(7))
    z = st.rotation(lwr.frame_id("lwr_ee"))[:, 2]
    ee.start(st)
    pointing = Pointing(lwr, "lwr_ee", z, np.deg2rad(alpha_deg), Gains(5, 2), inequality=inequality,
                        name="pointing")
    pol = Algorithm1(lwr, ee, pointing, CPS, "lwr_ee", obstacles, avoidance_dim=dim)
    pol.update(st, 0.0)
    return pol, st


def point_near(lwr, frame, d):
    """A point obstacle at distance d from a frame origin, perpendicular to the arm's segments there."""
    st = State(lwr).update(Q0, np.zeros(7))
    p = st.position(lwr.frame_id(frame))
    upper = st.position(lwr.frame_id("lwr_elbow")) - st.position(lwr.frame_id("lwr_shoulder"))
    fore = st.position(lwr.frame_id("lwr_wrist")) - st.position(lwr.frame_id("lwr_elbow"))
    n = np.cross(upper, fore)
    return p + d * n / np.linalg.norm(n)


def labels(pol, st):
    return pol(st, 0.0).label()


def test_no_obstacle_in_range_gives_ee_only(lwr):
    pol, st = make(lwr, [Obstacle.sphere("far", [3.0, 3.0, 3.0])])
    assert labels(pol, st) == "ee"  # pointing inside its cone (axis = current z)
    assert pol.probe(None, None)["active_point"] == -1


def test_body_point_in_surveillance_band_is_appended_last(lwr):
    pol, st = make(lwr, [Obstacle.sphere("o", point_near(lwr, "lwr_cp_3", 0.10))])
    assert labels(pol, st) == "ee > avoid"
    assert pol.probe(None, None)["active_point"] == 2
    assert pol.probe(None, None)["d_minimal"] == pytest.approx(0.10, abs=1e-12)


def test_dangerous_body_point_goes_above_the_ee_task(lwr):
    pol, st = make(lwr, [Obstacle.sphere("o", point_near(lwr, "lwr_cp_6", 0.03))])
    assert labels(pol, st) == "avoid > ee"


def test_dangerous_body_point_goes_below_an_ee_that_is_closer(lwr):
    o_body = Obstacle.sphere("ob", point_near(lwr, "lwr_cp_6", 0.04))
    o_ee = Obstacle.sphere("oe", point_near(lwr, "lwr_ee", 0.02))
    pol, st = make(lwr, [o_body, o_ee])
    stack = pol(st, 0.0)
    assert stack.label() == "ee > avoid"
    # the EE repulsion (30) is added to the EE command, away from the obstacle
    extra = stack.extras["ee"]
    n = st.position(lwr.frame_id("lwr_ee")) - o_ee.placement.translation
    assert np.dot(extra, n) > 0 and np.linalg.norm(extra) > 1.0


def test_active_pointing_sits_between_ee_and_low_priority_avoidance(lwr):
    o = Obstacle.sphere("o", point_near(lwr, "lwr_cp_3", 0.10))
    pol, st = make(lwr, [o])
    pol.pointing.z_d = -pol.pointing.z_d  # axis now outside the cone: e > 0
    assert labels(pol, st) == "ee > pointing > avoid"
    pol_eq, st = make(lwr, [o], inequality=False)
    assert labels(pol_eq, st) == "ee > pointing > avoid"  # the equality is always in the stack


def test_avoidance_task_is_n_transpose_J(lwr):
    o = Obstacle.sphere("o", point_near(lwr, "lwr_cp_3", 0.10))
    pol, st = make(lwr, [o])
    stack = pol(st, 0.0)
    level = stack.to_levels(st, 0.0, 2)[-1]
    J_c = pol.field.jacobian(st.data, 2, 0)
    n = pol.avoid.normal
    np.testing.assert_allclose(level.J, (n @ J_c).reshape(1, -1), atol=1e-14)
    np.testing.assert_allclose(np.linalg.norm(n), 1.0)
    assert level.b[0] == pytest.approx(pol.body_repulsion.magnitude(0.10), rel=1e-12)  # qd = 0: no Jdot term
    pol3, st = make(lwr, [o], dim=3)
    assert pol3(st, 0.0).to_levels(st, 0.0, 2)[-1].J.shape == (3, 7)


def test_unknown_direction_is_rejected_at_construction(lwr):
    ee = FramePosition(lwr, "lwr_ee", None, Gains(40, 20), name="ee")
    with pytest.raises(UnknownNameError, match="'mean', 'nearest'"):
        Algorithm1(lwr, ee, None, CPS, "lwr_ee", [], direction="average")


def test_nearest_from_one_masked_grid_equals_nearest_element(lwr):
    """Algorithm1._nearest (one masked copy of the grid) makes nearest_element's choices: same element, obstacle,
    distance and direction, on random grids with ties, +inf (culled) pairs, pairs out of range and beyond eps2."""
    from hqp_tpm.geometry.repulsion import nearest_element

    pol, _ = make(lwr, [Obstacle.sphere(f"o{i}", [3.0 + i, 3.0, 3.0]) for i in range(3)])
    f, th = pol.field, pol.th
    rng = np.random.default_rng(3)
    seen = set()
    for _ in range(400):
        D = rng.choice([-0.01, 0.02, 0.05, 0.09, 0.15, 0.2, np.inf], size=f.distance.shape)
        D[rng.random(D.shape) < 0.3] = rng.uniform(-0.01, 0.3)
        if rng.random() < 0.3:  # no body point within eps2
            D[pol.body] = rng.choice([0.16, 0.3, np.inf], size=D[pol.body].shape)
        f.distance[...] = D
        f.normal[...] = rng.normal(size=f.normal.shape)
        f.in_range[...] = (D <= f.surveillance) & (rng.random(D.shape) < 0.9)
        j_ee, d_ee, n_ee, k, j, d_min, r_hat = pol._nearest()
        ref_ee = nearest_element(f.distance[pol.ee], f.normal[pol.ee], f.in_range[pol.ee])
        ref = nearest_element(f.distance[pol.body], f.normal[pol.body], f.in_range[pol.body], "nearest", th.eps2)
        assert (j_ee, d_ee) == ref_ee[1:3] and (k, j, d_min) == ref[:3]
        for a, b in ((n_ee, ref_ee[3]), (r_hat, ref[3])):
            assert (a is None) == (b is None)
            if a is not None:
                np.testing.assert_array_equal(a, b)
        seen.add((k >= 0, j_ee >= 0))
    assert seen == {(True, True), (True, False), (False, True), (False, False)}


@pytest.mark.parametrize("where", ["lwr_cp_6", "lwr_cp_3"])  # avoidance above the EE task, appended last
def test_explain_accounts_for_the_avoidance_task(lwr, where):
    """Every task plan() stacks is one of tasks() (the policy contract), so the ``--explain`` record and ``hqp-tpm
    explain`` account for the avoidance task: its fraction met, desired and achieved rows (312f146: no ``avoid``)."""
    from hqp_tpm.app.explain import Explainer
    from hqp_tpm.control.controller import Controller

    pol, st = make(lwr, [Obstacle.sphere("o", point_near(lwr, where, 0.03 if where == "lwr_cp_6" else 0.10))])
    ctrl = Controller(lwr, pol, order=2, solver="tpm", lambda_max=0.05, eps=0.1, q0=Q0)
    ex = Explainer(ctrl)
    res = ctrl.step(record=True)
    stacked = [task for level in res.stack.levels for task in level]
    assert pol.avoid in stacked and set(stacked) <= set(pol.tasks())
    row = ex.probe(ctrl, res)
    i = ex.tasks.index("avoid")
    level = next(lv for lv in res.levels if lv.name == "avoid")
    np.testing.assert_array_equal(row["explain_desired_avoid"], level.b)
    np.testing.assert_allclose(row["explain_achieved_avoid"], level.J @ res.command, rtol=0, atol=1e-12)
    assert 0.0 <= row["explain_fraction"][i] <= 1.0

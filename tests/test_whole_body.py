"""Whole-body collision avoidance on Romeo (issue 7): collision model, self pairs, policy, short runs."""

import coal
import numpy as np
import pinocchio as pin
import pytest

from hqp_tpm.app import build, runner, scenario
from hqp_tpm.geometry.distances import DistanceField
from hqp_tpm.geometry.obstacles import Obstacle
from hqp_tpm.policies import whole_body as wb
from hqp_tpm.policies.whole_body import WholeBody
from hqp_tpm.robot.model import Robot
from hqp_tpm.robot.state import State
from hqp_tpm.tasks import CenterOfMass, FramePose, FramePosition, Gains


@pytest.fixture(scope="module")
def romeo():
    return Robot.load("romeo21")


@pytest.fixture(scope="module")
def pairs(romeo):
    return wb.self_pairs(romeo.model, romeo.collision_model)


def _link_joint(romeo, name):
    cm = romeo.collision_model
    return cm.geometryObjects[cm.getGeometryId(name)].parentJoint


# ----------------------------------------------------------------------------- self pairs
def test_self_pairs_exclude_adjacent_and_srdf_disabled(romeo, pairs):
    disabled = wb.srdf_disabled_links()
    assert len(disabled) > 500  # romeo.srdf really was read
    model = romeo.model
    assert pairs, "no self pair left"
    for a, b in pairs:
        assert frozenset((a[:-2], b[:-2])) not in disabled, (a, b)
        ja, jb = _link_joint(romeo, a), _link_joint(romeo, b)
        assert ja != jb and model.parents[ja] != jb and model.parents[jb] != ja, (a, b)
        assert not wb.adjacent(model, romeo.collision_model, a, b)
    keys = {frozenset(p) for p in pairs}
    # kept: hands against the torso and the thighs, the two hands against each other
    for p in (("l_wrist_0", "torso_0"), ("r_wrist_0", "RHipPitchLink_0"), ("l_wrist_0", "r_wrist_0")):
        assert frozenset(p) in keys, p
    # upper arm / torso: adjacent (through the bare shoulder-pitch link) and disabled by the SRDF
    assert wb.adjacent(model, romeo.collision_model, "LShoulderYawLink_0", "torso_0")
    assert frozenset(("LShoulderYawLink_0", "torso_0")) not in keys
    # forearm / same-side shin: "Never" in the SRDF, not adjacent
    assert frozenset(("LElbowYawLink", "LKneePitchLink")) in disabled
    assert frozenset(("LElbowYawLink_0", "LKneePitchLink_0")) not in keys


def test_control_geometries_are_convex_hulls(romeo):
    a = wb.control_geometries(romeo)
    assert [g.name for g in a.geometryObjects] == list(wb.CONTROL_GEOMETRIES)
    assert all(isinstance(g.geometry, coal.Convex) for g in a.geometryObjects)


# ----------------------------------------------------------------------------- distances vs coal
OBSTACLES = [Obstacle.sphere("ball", [0.36, 0.38, -0.06], 0.05),
             Obstacle.box("block", [0.33, -0.55, -0.17], [0.12, 0.10, 0.06])]


def _coal_distance(s1, M1, s2, M2):
    req, res = coal.DistanceRequest(), coal.DistanceResult()
    req.enable_signed_distance = True
    return coal.distance(s1, coal.Transform3s(M1.rotation, M1.translation), s2,
                         coal.Transform3s(M2.rotation, M2.translation), req, res)


def test_convexified_distances_agree_with_coal(romeo, pairs):
    model, data = romeo.model, romeo.model.createData()
    gm = wb.control_geometries(romeo)
    gd = pin.GeometryData(gm)
    field = DistanceField(model, gm, (), OBSTACLES, surveillance=10.0, self_pairs=pairs, broad_phase=False)
    rng = np.random.default_rng(7)
    lo, up = model.lowerPositionLimit.copy(), model.upperPositionLimit.copy()
    lo[:7], up[:7] = 0.0, 0.0
    for k in range(3):
        q = romeo.neutral() if k == 0 else pin.neutral(model) + 0.5 * (rng.uniform(lo, up) - pin.neutral(model))
        q[:7] = pin.neutral(model)[:7]
        pin.forwardKinematics(model, data, q)
        pin.updateFramePlacements(model, data)
        pin.updateGeometryPlacements(model, data, gm, gd)
        field.update(data)
        for e, g in enumerate(gm.geometryObjects):
            for j, o in enumerate(OBSTACLES):
                ref = _coal_distance(g.geometry, gd.oMg[e], o.shape, o.placement_at(0.0))
                assert field.distance[e, j] == pytest.approx(ref, abs=1e-6), (g.name, o.name)
        names = [g.name for g in gm.geometryObjects]
        for s, (a, b) in enumerate(pairs):
            ia, ib = names.index(a), names.index(b)
            ref = _coal_distance(gm.geometryObjects[ia].geometry, gd.oMg[ia], gm.geometryObjects[ib].geometry,
                                 gd.oMg[ib])
            assert field.self_distance[s] == pytest.approx(ref, abs=1e-6), (a, b)


# ----------------------------------------------------------------------------- policy
def _policy(romeo, q, obstacles):
    st = State(romeo).update(q, np.zeros(romeo.nv))
    sole = FramePose(romeo, "r_sole", None, Gains(100.0), name="right_sole")
    below = [CenterOfMass(None, Gains(100.0), axes="xy", name="com"),
             FramePosition(romeo, "l_sole", None, Gains(100.0), name="left_foot"),
             FramePosition(romeo, "l_gripper", None, Gains(100.0), name="left_hand"),
             FramePosition(romeo, "r_gripper", None, Gains(100.0), name="right_hand")]
    for task in [sole, *below]:
        task.start(st)
    pol = WholeBody(romeo, [sole], below, obstacles, d_obstacle_activation=0.10, d_self_activation=0.05)
    pol.update(st, 0.0)
    return pol, st


BASE = "right_sole > com > left_foot > left_hand > right_hand"


def test_obstacle_level_inserted_when_and_only_when_within_threshold(romeo):
    q = romeo.configuration({"RShoulderYaw": -0.8, "LShoulderYaw": 0.8})
    st = State(romeo).update(q, np.zeros(romeo.nv))
    hand = st.position(romeo.frame_id("l_gripper"))
    seen = set()
    for dz in (0.09, 0.12, 0.15, 0.18, 0.25, 0.40):
        pol, st = _policy(romeo, q, [Obstacle.sphere("ball", hand - [0.0, 0.0, dz], 0.03)])
        stack = pol(st, 0.0)
        rec = pol.probe(None, None)
        inside = rec["d_obstacle"] < 0.10
        seen.add(inside)
        assert stack.label() == (BASE.replace("right_sole", "right_sole > avoid_obstacle") if inside else BASE)
        assert rec["n_avoid_obstacle"] == float(inside)
        if inside:
            lv = stack.to_levels(st, 0.0, 1)[1]
            assert lv.name == "avoid_obstacle" and not lv.is_equality and lv.lower[0] > 0 and lv.upper[0] == np.inf
            assert lv.active_rows().all()  # the analytic solvers keep the row (violated at qd = 0)
            d = rec["d_obstacle"]
            assert lv.lower[0] == pytest.approx(wb.repulsive_bound(d, 0.10, 0.03, 0.3))
            # the row is the distance rate: finite differences of the distance along a random qd
            qd = np.random.default_rng(1).standard_normal(romeo.nv) * 0.1
            qd[:6] = 0.0
            pol2, _ = _policy(romeo, pin.integrate(romeo.model, q, qd * 1e-6), pol.obstacles)
            rate = (pol2.probe(None, None)["d_obstacle"] - d) / 1e-6
            assert lv.J[0] @ qd == pytest.approx(rate, abs=1e-4)
    assert seen == {True, False}


def test_self_level_inserted_when_and_only_when_within_threshold(romeo):
    seen = set()
    for yaw in (-0.3, -0.1, 0.3):
        q = romeo.configuration({"LShoulderPitch": 0.8, "LShoulderYaw": yaw, "RShoulderYaw": -0.8})
        pol, st = _policy(romeo, q, [Obstacle.sphere("far", [5.0, 5.0, 5.0], 0.1)])
        stack = pol(st, 0.0)
        rec = pol.probe(None, None)
        inside = rec["d_self"] < 0.05
        seen.add(inside)
        assert rec["n_avoid_self"] == float(inside)
        assert stack.label() == (BASE.replace("right_sole", "right_sole > avoid_self") if inside else BASE)
        if inside:
            lv = stack.to_levels(st, 0.0, 1)[1]
            assert lv.lower[0] > 0 and lv.active_rows().all()
            qd = np.random.default_rng(2).standard_normal(romeo.nv) * 0.1
            qd[:6] = 0.0
            pol2, _ = _policy(romeo, pin.integrate(romeo.model, q, qd * 1e-6), pol.obstacles)
            rate = (pol2.probe(None, None)["d_self"] - rec["d_self"]) / 1e-6
            assert lv.J[0] @ qd == pytest.approx(rate, abs=1e-4)
    assert seen == {True, False}


# ----------------------------------------------------------------------------- short runs
@pytest.mark.parametrize("name", ["romeo_obstacles_sns_tpm", "romeo_obstacles_qp"])
def test_short_run_keeps_distances_positive_and_boxes(name):
    sc = scenario.load(name)
    ctx = build.build_run(sc)
    ctrl, policy = ctx.controller, ctx.policy

    def box_probe(c, res):
        lo, up = c.box(c.state, res.t)
        x = res.command
        return {"box_violation": float(max(0.0, np.max(lo - x), np.max(x - up)))}

    def all_distances(c, res):  # every pair, also those beyond the recorded range
        f = policy.field
        return {"d_obs_all": float(f.distance.min()), "d_self_all": float(f.self_distance.min())}

    rec, _ = runner.run(ctrl, 900, probes=[policy.probe, box_probe, all_distances])
    a = rec.arrays()
    assert np.nanmin(a["d_obstacle"]) > 0.0 and a["d_obs_all"].min() > 0.0
    assert a["d_self_all"].min() > 0.0
    assert a["box_violation"].max() <= 1e-9
    vmax = ctx.velocity_limits
    assert (np.abs(a["dq"]) <= vmax + 1e-9).all()
    # the avoidance really worked: the ball is engaged in the first 0.9 s (romeo_tpm would penetrate it)
    assert (a["n_avoid_obstacle"] > 0).any()
    assert np.nanmin(a["d_obstacle"]) > 0.05


def test_pairs_culled_at_the_activation_distances_could_not_have_been_active():
    """The control field culls pairs beyond the activation distances (0.10 m obstacles, 0.05 m self): along the
    scenario's first 0.4 s (the ball engaged from 0.24 s) the stack, the chosen pairs and the avoidance rows equal
    those from a field that computes every pair (no broad phase) up to the recorded range; the culled pairs' true
    distances exceed the activation distances."""
    import copy

    ctx = build.build_run(scenario.load("romeo_obstacles_sns_tpm"))
    ctrl, pol = ctx.controller, ctx.policy
    assert pol.field.surveillance == 0.10 and pol.field.self_surveillance == 0.05
    ref = copy.copy(pol)
    ref.field = DistanceField(ctx.robot.model, wb.control_geometries(ctx.robot), (), pol.obstacles,
                              surveillance=0.3, self_pairs=pol.pairs, broad_phase=False)
    ref.avoid_obstacle, ref.avoid_self = wb.PairAvoidance("avoid_obstacle"), wb.PairAvoidance("avoid_self")
    labels, culled = set(), 0
    for i in range(400):
        ctrl.step()
        if i % 4:
            continue
        st, t = ctrl.state, ctrl.t
        pol.update(st, t)
        ref.update(st, t)
        a, b = pol(st, t), ref(st, t)
        assert a.label() == b.label()
        labels.add(a.label())
        assert [(e, j) for e, j, _ in pol.obstacle_pairs()] == [(e, j) for e, j, _ in ref.obstacle_pairs()]
        for la, lb in zip(a.to_levels(st, t, 1), b.to_levels(st, t, 1), strict=True):
            np.testing.assert_allclose(la.J, lb.J, rtol=0, atol=1e-12)
            if not la.is_equality:
                np.testing.assert_allclose(la.lower, lb.lower, rtol=0, atol=1e-12)
        out = ~pol.field.computed
        culled += int(out.sum())
        assert (ref.field.distance[out] > 0.10).all()
        assert (ref.field.self_distance[~pol.field.self_computed] > 0.05).all()
    assert culled > 0 and any("avoid_obstacle" in s for s in labels)


def test_recorded_distances_reach_the_record_range():
    """probe() records distances up to record_range (0.3 m) from its own field, beyond the control field's 0.10 m."""
    ctx = build.build_run(scenario.load("romeo_obstacles_sns_tpm"))
    rec, _ = runner.run(ctx.controller, 40, probes=[ctx.policy.probe])
    d = rec.arrays()["d_obstacle"]
    assert np.isfinite(d).all() and (d > 0.10).any() and (d <= 0.3).all()


def test_probe_equals_a_field_updated_at_the_record_range():
    """probe()'s distances (the control field's and the culled pairs that could be nearer, DistanceField.nearest_within)
    equal, bit for bit, those of a field updated with surveillance record_range at the same state: along the first
    1.1 s of romeo_obstacles_sns_tpm (no pair in range, the obstacle row, obstacle and self rows), and at a state
    where nothing is within record_range (NaN). With pinocchio 3.4 and hppfcl (``make test-pin-lowest``) within
    1e-15 relative: there the probe's distance and the reference field's differed by 8.3e-17 (6 ulps) at step 390."""
    ctx = build.build_run(scenario.load("romeo_obstacles_sns_tpm"))
    ctrl, pol = ctx.controller, ctx.policy
    rel = 0.0 if int(pin.__version__.split(".")[0]) >= 4 else 1e-15
    reference = DistanceField(ctrl.robot.model, pol.record_field.geometry_model, (), pol.obstacles,
                              surveillance=pol.record_field.surveillance, self_pairs=pol.pairs, convexify=False)
    seen = set()
    for i in range(1100):
        res = ctrl.step()
        if i % 10 and i not in range(790, 830):
            continue
        got = pol.probe(ctrl, res)
        f = reference.update(ctrl.state.data, None, pol.field.t)
        for key, d, inside in (("d_obstacle", f.distance, f.in_range), ("d_self", f.self_distance, f.self_in_range)):
            want = np.where(inside, d, np.inf).min(initial=np.inf)
            if np.isfinite(want):
                assert abs(got[key] - want) <= rel * want, (i, key, got[key], want)
            else:
                assert np.isnan(got[key]), (i, key)
        seen.add(res.label())
    assert len(seen) >= 3
    far = wb.WholeBody(ctrl.robot, pol.top, pol.below, [Obstacle.sphere("far", [5.0, 0.0, 0.0], 0.1)],
                       record_range=0.05, d_obstacle_activation=0.04, d_obstacle_safe=0.01, d_self_activation=0.02)
    state = State(ctrl.robot).update(ctrl.q, ctrl.v)
    far.update(state, 0.0)
    d_obs, d_self = far.field.nearest_within(far.record_field.surveillance)
    assert d_obs == np.inf and (d_self == np.inf or d_self <= 0.05)


def test_every_stacked_task_is_one_of_the_policys_tasks(romeo):
    """The avoidance levels plan() stacks are among tasks() (the policy contract: the controller starts them,
    ``--explain`` accounts for them; 312f146 left both out)."""
    from hqp_tpm.app.explain import Explainer
    from hqp_tpm.control.controller import Controller

    seen = set()
    for yaw, dz in ((-0.3, 0.09), (0.3, 0.40)):
        q = romeo.configuration({"LShoulderPitch": 0.8, "LShoulderYaw": yaw, "RShoulderYaw": -0.8})
        st = State(romeo).update(q, np.zeros(romeo.nv))
        hand = st.position(romeo.frame_id("l_gripper"))
        pol, st = _policy(romeo, q, [Obstacle.sphere("ball", hand - [0.0, 0.0, dz], 0.03)])
        ctrl = Controller(romeo, pol, order=1, solver="tpm", lambda_max=0.05, eps=0.1, q0=q)
        ex = Explainer(ctrl)
        assert ex.tasks == [task.name for task in pol.tasks()]
        res = ctrl.step(record=True)
        stacked = [task for level in res.stack.levels for task in level]
        assert set(stacked) <= set(pol.tasks())
        frac = ex.probe(ctrl, res)["explain_fraction"]
        for name in ("avoid_obstacle", "avoid_self"):
            assert np.isnan(frac[ex.tasks.index(name)]) == (name not in res.stack.label())
            seen.add((name, name in res.stack.label()))
    assert seen == {("avoid_obstacle", True), ("avoid_obstacle", False), ("avoid_self", True), ("avoid_self", False)}


def test_pair_rows_seen_from_v_are_the_shifted_levels_active_rows():
    """PairAvoidance.rows_from (the planned step's rows under a command-rate bound) gives what
    command_rate.shifted(level, v).as_equality() gives, bit for bit, rows dropped where lower - J v <= 0 included;
    None (that path then raises the typed error) for a NaN bound or a J the level's checks refuse."""
    from hqp_tpm.control.command_rate import shifted
    from hqp_tpm.errors import MagnitudeError, NonFiniteError
    from hqp_tpm.tasks.avoidance import PairAvoidance

    rng = np.random.default_rng(6)
    task = PairAvoidance("avoid_obstacle")
    kept = set()
    for _ in range(300):
        m = int(rng.integers(1, 4))
        J, v = rng.normal(size=(m, 27)), rng.normal(size=27) * 0.1
        lower = J @ v + rng.normal(size=m) * 0.05  # about half the rows active from v
        task.assign(J, lower, np.full(m, 0.05))
        J_a, b_a = shifted(task.level(None, 0.0, 1).check_finite(), v).as_equality()
        rows = task.rows_from(v)
        np.testing.assert_array_equal(rows[0], J_a)
        np.testing.assert_array_equal(rows[1], b_a)
        kept.add(rows[1].size)
    assert kept >= {0, 1, 2}
    for J, lower, error in ((np.ones((1, 27)), [np.nan], NonFiniteError), (np.full((1, 27), np.inf), [0.1], None),
                            (np.full((1, 27), 1e-160), [0.1], MagnitudeError)):
        task.assign(J, lower, [0.05])
        assert task.rows_from(np.zeros(27)) is None
        with pytest.raises(error or NonFiniteError, match="avoid_obstacle"):
            shifted(task.level(None, 0.0, 1).check_finite(), np.zeros(27)).as_equality()

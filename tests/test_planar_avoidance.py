"""papers/004 (Petrič et al., obstacle avoidance) on the planar 5-DOF arm: the model, the 1-D avoidance Jacobian
(14) against finite differences, the gains (16), (18), (20) and the transition (27)/(31), the policy's stacks against
the paper's closed forms (11), (17), (19), (22), (25), (30), tpm against the cascaded QP, and the scenario runs."""

import copy
import importlib.util
import sys
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

from hqp_tpm.app import build, scenario
from hqp_tpm.errors import ScenarioError
from hqp_tpm.policies.petric import alpha_h, alpha_v, weights
from hqp_tpm.robot.model import Robot
from hqp_tpm.robot.state import State

ROOT = Path(__file__).resolve().parents[1]
H = 1e-6
D_M, D_I = 0.2, 0.3


@pytest.fixture(scope="module")
def planar5():
    return Robot.load("planar5")


def link_points(robot, q):
    """Joint positions and the EE of the planar arm (x-y), by summing link vectors (independent of pinocchio)."""
    phi = np.cumsum(q)
    steps = 0.5 * np.column_stack([np.cos(phi), np.sin(phi)])
    return np.vstack([np.zeros(2), np.cumsum(steps, axis=0)])


def segment_distance(c, a, b):
    u = b - a
    s = np.clip((c - a) @ u / (u @ u), 0.0, 1.0)
    return float(np.linalg.norm(a + s * u - c))


# --------------------------------------------------------------------------- the model
def test_planar_urdfs_are_generated_and_match_the_planar_kinematics(planar5):
    spec = importlib.util.spec_from_file_location("planar_to_urdf", ROOT / "tools" / "planar_to_urdf.py")
    gen = importlib.util.module_from_spec(spec)
    sys.modules["planar_to_urdf"] = gen
    spec.loader.exec_module(gen)
    assert gen.main(["--check"]) == 0
    assert Robot.load("planar4").nv == 4 and planar5.nv == 5
    model = planar5.model
    data = model.createData()
    rng = np.random.default_rng(0)
    from hqp_tpm.geometry.distances import DistanceField
    from hqp_tpm.geometry.obstacles import Obstacle

    field = DistanceField(model, planar5.collision_model, [], [Obstacle.sphere("o", [0.7, -0.4, 0.0], 0.2)],
                          surveillance=10.0, broad_phase=False)
    caps = [g.geometry for g in field.geometry_model.geometryObjects]
    assert len(caps) == 5 and all(c.radius == 0.0 and c.halfLength == 0.25 for c in caps)
    for _ in range(200):
        q = rng.uniform(-np.pi, np.pi, 5)
        pin.forwardKinematics(model, data, q)
        pin.updateFramePlacements(model, data)
        P = link_points(planar5, q)
        np.testing.assert_allclose(data.oMf[model.getFrameId("planar5_ee")].translation, [*P[-1], 0.0], atol=1e-12)
        np.testing.assert_allclose(data.oMf[model.getFrameId("planar5_tip_2")].translation, [*P[2], 0.0], atol=1e-12)
        field.update(data)
        want = [segment_distance(np.array([0.7, -0.4]), P[i], P[i + 1]) - 0.2 for i in range(5)]
        np.testing.assert_allclose(field.distance[:, 0], want, atol=1e-9)


# --------------------------------------------------------------------------- gains and transition functions
def test_alpha_v_and_alpha_h_are_continuous_and_bounded():
    d = np.linspace(0.005, 0.5, 200001)
    h = d[1] - d[0]
    ah = np.array([alpha_h(x, D_M, D_I) for x in d])
    av = np.array([alpha_v(x, D_M) for x in d])
    assert ah.min() == 0.0 and ah.max() == 1.0
    # continuous: a Lipschitz bound pi / (2 (d_i - d_m)) on the cosine, no step larger than it allows
    assert np.abs(np.diff(ah)).max() <= np.pi / (2 * (D_I - D_M)) * h * (1 + 1e-9)
    assert alpha_h(D_M, D_M, D_I) == 1.0 and alpha_h(D_I, D_M, D_I) == 0.0
    np.testing.assert_allclose(alpha_h(0.25, D_M, D_I), 0.5, atol=1e-15)
    assert (np.diff(ah) <= 1e-15).all()  # non-increasing with the distance
    # (16): zero at and beyond d_m, (d_m/d)^2 - 1 below it, continuous at d_m, decreasing
    assert (av[d >= D_M] == 0.0).all() and (av >= 0).all()
    np.testing.assert_allclose(av[d < D_M], (D_M / d[d < D_M]) ** 2 - 1)
    assert abs(alpha_v(D_M - 1e-9, D_M)) < 1e-7
    assert (np.diff(av) <= 0).all()
    # the printed (18) would be 0 just above d_m and 1 just below d_i: a jump at both ends
    printed = 0.5 * (1 - np.cos(np.pi * (np.array([D_M + 1e-9, D_I - 1e-9]) - D_M) / (D_I - D_M)))
    assert printed[0] < 1e-12 and printed[1] > 1 - 1e-12
    # (20): weights of the obstacles within d_i, non-negative, summing to one, nearer = heavier
    w = weights([0.05, 0.2, 0.29], D_I)
    np.testing.assert_allclose(w.sum(), 1.0)
    assert (w >= 0).all() and w[0] > w[1] > w[2]


def test_transition_projector_27_is_bounded_and_continuous():
    """N'(lambda) = I - lambda J^# J (27), (31): identity at 0, the null-space projector at 1, norm <= 1 between."""
    rng = np.random.default_rng(1)
    for _ in range(50):
        J = rng.standard_normal((1, 5))
        P = np.linalg.pinv(J) @ J
        lams = np.linspace(0, 1, 101)
        Ns = [np.eye(5) - lam * P for lam in lams]
        np.testing.assert_allclose(Ns[0], np.eye(5))
        np.testing.assert_allclose(Ns[-1] @ Ns[-1], Ns[-1], atol=1e-12)  # a projector at lambda = 1
        np.testing.assert_allclose(J @ Ns[-1], 0, atol=1e-12)
        assert max(np.linalg.norm(N, 2) for N in Ns) <= 1 + 1e-12
        steps = [np.linalg.norm(a - b, 2) for a, b in zip(Ns[1:], Ns[:-1], strict=True)]
        assert max(steps) <= 0.01 + 1e-12  # Lipschitz 1 in lambda


# --------------------------------------------------------------------------- the policy at a state
def controller(stem="planar5_exact", solver=None, obstacles=None, **policy):
    """A built and started controller of ``stem`` (resolving ``extends``), [policy] fields and obstacles overridden."""
    data = copy.deepcopy(scenario.read(scenario.resolve_path(stem)))
    data["policy"].update(policy)
    if obstacles is not None:
        data["obstacles"] = obstacles
    sc = scenario.parse(data, scenario.SCENARIO_DIR / f"{stem}.toml")
    robot, ctrl, tasks, pol = build.build(sc, solver=solver)
    ctrl.start()
    return robot, ctrl, tasks, pol


def at(ctrl, q, v=None, t=1.0):
    ctrl.set_state(q, np.zeros(ctrl.robot.nv) if v is None else v)
    ctrl.t = t
    return ctrl.compute()


def critical(robot, pol, st, j):
    """(J_o, n_o, d) of obstacle j's critical point from the policy's distance field (after compute)."""
    f = pol.field
    k = int(np.argmin(np.where(f.computed[:, j], f.distance[:, j], np.inf)))
    return f.jacobian(st.data, k, j), f.normal[k, j], float(f.distance[k, j])


Q_NEAR = np.deg2rad([-30.0, 25.0, 25.0, 25.0, 20.0])


def obstacle_at_distance(robot, q, d, link=3, s=0.5, radius=0.2):
    """A sphere obstacle whose surface is ``d`` from the point at fraction ``s`` of ``link``, below it (normal)."""
    P = link_points(robot, q)
    a, b = P[link - 1], P[link]
    u = (b - a) / np.linalg.norm(b - a)
    nrm = np.array([u[1], -u[0]])  # right-hand normal: below the arm's belly
    c = a + s * (b - a) + (d + radius) * nrm
    return {"name": f"o{link}", "type": "sphere", "center": [*c, 0.0], "radius": radius}


def test_avoidance_jacobian_14_is_the_distance_gradient(planar5):
    """J_do = n_o^T J_o (14) equals the finite-difference gradient of the link-obstacle distance."""
    rng = np.random.default_rng(2)
    for _ in range(10):
        q = Q_NEAR + rng.uniform(-0.2, 0.2, 5)
        obs = obstacle_at_distance(planar5, q, 0.15, link=int(rng.integers(2, 6)), s=rng.uniform(0.2, 0.8))
        robot, ctrl, tasks, pol = controller(obstacles=[obs])
        at(ctrl, q)
        J_do = pol.avoid[0].jacobian(ctrl.state)
        J_o, n_o, d = critical(robot, pol, ctrl.state, 0)
        np.testing.assert_allclose(J_do, n_o[None, :] @ J_o, atol=1e-14)

        fd = np.array([(distance(robot, pol, q + H * e) - distance(robot, pol, q - H * e)) / (2 * H)
                       for e in np.eye(5)])
        np.testing.assert_allclose(J_do[0], fd, atol=1e-7)
        # the EE task Jacobian (x-y rows) too
        ee = tasks["ee"]
        st = State(robot).update(q, np.zeros(5))
        fd_ee = np.column_stack([(ee.value(State(robot).update(q + H * e, np.zeros(5)))
                                  - ee.value(State(robot).update(q - H * e, np.zeros(5)))) / (2 * H)
                                 for e in np.eye(5)])
        np.testing.assert_allclose(ee.jacobian(st), fd_ee, atol=1e-8)


def distance(robot, pol, q):
    """The first obstacle's critical distance at ``q`` (the policy's distance field)."""
    pol.field.update(State(robot).update(q, np.zeros(robot.nv)).data)
    return pol.distances()[0]


def paper_terms(robot, ctrl, tasks, pol, j=0):
    st, t = ctrl.state, ctrl.t
    ee = tasks["ee"]
    J = ee.jacobian(st)
    xd = ee.command(st, t, 1)
    Jp = np.linalg.pinv(J)
    N = np.eye(5) - Jp @ J
    J_o, n_o, d = critical(robot, pol, st, j)
    J_do = n_o[None, :] @ J_o
    xo = alpha_v(d, D_M) * pol.v_o
    return J, xd, Jp, N, J_do, xo, d


@pytest.mark.parametrize("d", [0.12, 0.25])
def test_stacks_equal_the_papers_closed_forms(planar5, d):
    """At a state with one obstacle at d (below d_m, between d_m and d_i), each scheme's command equals the paper's
    formula computed with numpy pseudo-inverses: (17), (22), (25), (30), (37)-(39)."""
    obs = [obstacle_at_distance(planar5, Q_NEAR, d, link=3)]
    v = np.full(5, 0.1)
    got = {}
    for scheme in ("exact", "approximate", "primary", "transition", "pwdls"):
        robot, ctrl, tasks, pol = controller(scheme=scheme, obstacles=obs, p_ee=25.0, pwdls_damping=0.01)
        got[scheme] = at(ctrl, Q_NEAR, v).command
    J, xd, Jp, N, J_do, xo, dd = paper_terms(robot, ctrl, tasks, pol)
    assert abs(dd - d) < 1e-9
    ah = alpha_h(d, D_M, D_I)
    x_E = Jp @ xd
    exact = x_E + ah * (np.linalg.pinv(J_do @ N) @ (np.array([xo]) - J_do @ x_E))  # (17) with xd for xd_e
    approx = x_E + N @ np.linalg.pinv(J_do) @ np.array([xo])  # (22)
    N_o = np.eye(5) - np.linalg.pinv(J_do) @ J_do
    primary = np.linalg.pinv(J_do) @ np.array([xo]) + N_o @ x_E if d < D_M else x_E  # (25)
    transition = np.linalg.pinv(J_do) @ np.array([xo]) + (np.eye(5) - ah * np.linalg.pinv(J_do) @ J_do) @ x_E  # (30)
    J_E = np.vstack([J, J_do])
    P = np.diag([25.0, 25.0, 1.0 / ah])
    pw = J_E.T @ np.linalg.solve(J_E @ J_E.T + 0.01**2 * P, np.array([*xd, xo]))  # (37)-(39)
    for name, want in (("exact", exact), ("approximate", approx), ("primary", primary), ("transition", transition),
                       ("pwdls", pw)):
        np.testing.assert_allclose(got[name], want, atol=1e-10, err_msg=name)
    if d < D_M:  # the exact solution gives the critical point exactly xd_o (11), the approximate one less (Sec. 4.4)
        np.testing.assert_allclose(J_do @ got["exact"], [xo], atol=1e-10)
        assert 0 < (J_do @ got["approximate"])[0] - (J_do @ x_E)[0] < xo  # J_do N J_do^# xd_o, (22)
        np.testing.assert_allclose(J_do @ got["primary"], [xo], atol=1e-10)  # primary task (25) exact
    np.testing.assert_allclose(J @ got["exact"], xd, atol=1e-10)  # the EE task is untouched by (17)
    np.testing.assert_allclose(J @ got["approximate"], xd, atol=1e-10)


def test_several_obstacles_19_20(planar5):
    """Two obstacles within d_i: qd = J^# xd + sum_i w_i alpha_h,i qd_h,i (19) with the weights (20)."""
    obs = [obstacle_at_distance(planar5, Q_NEAR, 0.15, link=3), obstacle_at_distance(planar5, Q_NEAR, 0.26, link=5)]
    robot, ctrl, tasks, pol = controller(scheme="exact", obstacles=obs)
    res = at(ctrl, Q_NEAR, np.full(5, 0.1))
    assert res.stack.label() == "ee > avoid_o3"  # the nearest obstacle's stack is the one solved first
    J, xd, Jp, N, *_ = paper_terms(robot, ctrl, tasks, pol)
    x_E = Jp @ xd
    ds, terms = [], []
    for j in range(2):
        _, _, _, _, J_do, xo, d = paper_terms(robot, ctrl, tasks, pol, j)
        ds.append(d)
        terms.append(alpha_h(d, D_M, D_I) * np.linalg.pinv(J_do @ N) @ (np.array([xo]) - J_do @ x_E))
    np.testing.assert_allclose(ds, [0.15, 0.26], atol=1e-9)
    w = weights(ds, D_I)
    np.testing.assert_allclose(res.command, x_E + w[0] * terms[0] + w[1] * terms[1], atol=1e-10)
    probe = pol.probe(ctrl, res)
    assert probe["active_obstacles"] == 2 and abs(probe["d_obstacle"] - 0.15) < 1e-9


@pytest.mark.parametrize("scheme,secondary", [("exact", "projected"), ("approximate", "projected"),
                                              ("primary", "projected"), ("primary", "prioritized"),
                                              ("transition", "projected"), ("transition", "prioritized")])
def test_tpm_and_cascaded_qp_give_the_same_commands(planar5, scheme, secondary):
    """The same stacks solved by TPM and by the cascaded QP (daqp): the same commands (after the scheme's blend) to
    1e-8 at every 100th state of the first 3.2 s of the scenario's TPM run, most of them with the avoidance in the
    stack (below d_m and between d_m and d_i)."""
    stem = "planar5_primary" if scheme in ("primary", "transition") else "planar5_exact"
    _, c_tpm, _, _ = controller(stem, scheme=scheme, secondary=secondary)
    _, c_qp, _, _ = controller(stem, solver="qp:daqp", scheme=scheme, secondary=secondary)
    states = []
    for _ in range(3200):
        if c_tpm.steps % 100 == 0:
            states.append((c_tpm.q.copy(), c_tpm.v.copy(), c_tpm.t))
        c_tpm.step()
    checked = 0
    for q, v, t in states:
        a, b = at(c_tpm, q, v, t), at(c_qp, q, v, t)
        assert a.stack.label() == b.stack.label()
        np.testing.assert_allclose(b.command, a.command, atol=1e-8, rtol=0)
        checked += a.stack.label() != "ee"
    assert checked >= 5  # most of them with the avoidance in the stack


# --------------------------------------------------------------------------- scenario runs
def run(tmp_path, stem, **kw):
    from hqp_tpm.app.cli import run_scenario

    out = tmp_path / f"out_{Path(stem).stem}"
    summary = run_scenario(stem, out, progress=False, figures=False, replay=False, **kw)
    return dict(np.load(out / "trajectory.npz")), summary


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("planar")
    return {s: run(tmp, f"planar5_{s}") for s in ("exact", "approximate", "primary", "transition", "pwdls")}


def test_exact_and_approximate_runs_figs_2_5(runs):
    """Obstacle in the links' way, not the EE's: the exact avoidance keeps the nearest link above d_m = 0.2 m for the
    whole run (Fig. 3) with the EE on its line (max error < 1e-4 m; the paper: ~1e-6, continuous-time); the
    approximate one lets the links come closer (Fig. 5), with the same EE accuracy."""
    ex, ex_s = runs["exact"]
    ap, ap_s = runs["approximate"]
    assert ex_s["d_obstacle_min"] > D_M
    assert ex_s["ee_error_max"] < 1e-4 and ap_s["ee_error_max"] < 1e-4
    assert 0.0 < ap_s["d_obstacle_min"] < ex_s["d_obstacle_min"] - 0.1
    assert ex_s["time_avoidance_secondary_s"] > 1.0  # the avoidance worked for a good part of the run
    assert (ex["alpha_h"] > 0).sum() > 1000 and ex["alpha_v"].max() == 0.0  # exact: d_m never reached
    assert ap_s["time_below_d_m_s"] > 1.0  # approximate: below d_m for more than 1 s


def test_primary_and_transition_runs_figs_8_11(runs):
    """Obstacle on the EE's path: as primary task (25) the avoidance holds the nearest link at d_m (within 6 mm: the
    critical point moves between links) and the EE leaves its line; with the primary task the arm stays stuck
    (final EE error > 4 cm), with the smooth transition (30) it reaches P_2 (Sec. 5.1: "does not become stuck") and its
    command has no jumps (largest per-step change 35x smaller). The paper's "with the transition the robot comes
    closer to the obstacle" does not reproduce here: 0.2006 m vs 0.1945 m."""
    pr, pr_s = runs["primary"]
    tr, tr_s = runs["transition"]
    assert pr_s["d_obstacle_min"] > D_M - 0.006 and tr_s["d_obstacle_min"] > D_M - 0.001
    assert pr_s["ee_error_max"] > 0.3 and tr_s["ee_error_max"] > 0.3  # the EE goes around the obstacle
    e_pr = np.linalg.norm(pr["error_ee"], axis=1)
    e_tr = np.linalg.norm(tr["error_ee"], axis=1)
    assert e_pr[-1] > 0.04 and abs(e_pr[-1] - e_pr[-1000]) < 1e-3  # stuck: no progress in the last second
    assert e_tr[-1] < 1e-4
    assert tr_s["max_dq_jump"] < pr_s["max_dq_jump"] / 20
    assert pr_s["time_avoidance_primary_s"] > 5.0
    w = tr["transition_weight"]
    assert ((w > 0) & (w < 1)).sum() > 100 and np.abs(np.diff(w)).max() < 0.01  # the weight moves continuously
    assert pr_s["d_obstacle_min"] < tr_s["d_obstacle_min"]  # the paper's Fig. 11 claim is the opposite


def test_scenario_errors(tmp_path):
    cases = [('scheme = "nearest"', "'nearest' is not one of"), ("d_i = 0.1", "need 0 < d_b < d_m < d_i"),
             ('ee_task = "hand"', "unknown task 'hand'"), ("gain = 1.0", "unknown field(s) 'gain'")]
    for i, (line, msg) in enumerate(cases):
        f = tmp_path / f"bad{i}.toml"
        f.write_text(f'[scenario]\nextends = "planar5_exact"\nname = "bad"\n\n[policy]\n{line}\n')
        with pytest.raises(ScenarioError, match=msg.replace("(", r"\(").replace(")", r"\)")):
            build.build(scenario.load(f))
    f = tmp_path / "acc.toml"
    f.write_text('[scenario]\nextends = "planar5_exact"\nname = "bad"\nlevel = "acceleration"\n')
    with pytest.raises(ScenarioError, match="velocity level"):
        build.build(scenario.load(f))


def test_two_obstacles_weighted_sum_is_continuous(tmp_path):
    """(19)-(20): with two active obstacles the weighted sum of the homogeneous solutions gives continuous joint
    velocities; the worst-case obstacle alone (combine = "nearest") jumps when the nearest obstacle changes
    (Sec. 4.3: "a discontinuity in the joint velocities may occur"). The weighted one lets the links come a little
    closer (below d_m by < 1.5 cm: the weights scale each homogeneous solution down)."""
    a, s = run(tmp_path, "planar5_two_obstacles")
    spec = tmp_path / "nearest.toml"
    spec.write_text('[scenario]\nextends = "planar5_two_obstacles"\nname = "nearest"\n\n'
                    '[policy]\ncombine = "nearest"\n')
    b, t = run(tmp_path, str(spec))
    assert (a["active_obstacles"] == 2).sum() > 1500
    assert s["max_dq_jump"] < 0.01 < 1.0 < t["max_dq_jump"]
    assert s["d_obstacle_min"] > D_M - 0.015 and t["d_obstacle_min"] > D_M - 0.01
    assert s["ee_error_max"] < 1e-4 and t["ee_error_max"] < 1e-4


def test_pwdls_run_figs_12_13(runs):
    """Figs. 12-13: with the priority-weighted DLS the arm passes the obstacle on the EE's path and reaches P_2; as the
    paper says, it comes closer to the obstacle than with the smooth transition (0.175 m vs 0.2006 m, below d_m), and
    here the EE leaves its line by less (0.19 m vs 0.40 m)."""
    pw, pw_s = runs["pwdls"]
    tr, tr_s = runs["transition"]
    assert 0.15 < pw_s["d_obstacle_min"] < tr_s["d_obstacle_min"] - 0.02
    assert pw_s["ee_error_max"] < 0.6 * tr_s["ee_error_max"]
    assert np.linalg.norm(pw["error_ee"][-1]) < 5e-3
    assert pw_s["max_dq_jump"] < 0.2

"""The per-step account (hqp_tpm.solvers.account) and its robot layer (hqp_tpm.app.explain).

The account's numbers are recomputed here independently from J, x, b (and the projected Jacobian
from scipy's null_space); the blocking sets are checked on stacks whose cause is known by
construction, and their minimality by re-solving without each member.
"""

import json

import numpy as np
import pytest
from scipy.linalg import null_space

from hqp_tpm.errors import BoxError, EmptyBoxError, InfeasibleError, SolverFailedError
from hqp_tpm.solvers import Level, solve
from hqp_tpm.solvers.account import account, check_feasible, damping_lambda, deletion_filter, explain

SOLVERS = ["tpm", "nullspace", "sns_tpm", "sns", "qp"]


def _projected_smin(levels, k):
    """sigma_min of J_k restricted to the null space of the levels above (independent of the module)."""
    n = levels[0].J.shape[1]
    above = np.vstack([lv.J for lv in levels[:k]]) if k else np.zeros((0, n))
    N = null_space(above) if k else np.eye(n)
    if N.shape[1] < levels[k].J.shape[0]:
        return 0.0
    return float(np.linalg.svd(levels[k].J @ N, compute_uv=False).min())


@pytest.mark.parametrize("solver", SOLVERS)
def test_account_numbers_equal_independent_computations(solver):
    rng = np.random.default_rng(3)
    n = 7
    levels = [Level(rng.standard_normal((m, n)), 2.0 * rng.standard_normal(m), name=f"L{i}")
              for i, m in enumerate((2, 3, 1))]
    box = (np.full(n, -0.6), np.full(n, 0.6))
    lam, eps = 0.05, 0.3
    x, info = solve(solver, levels, n, box=box, lambda_max=lam, eps=eps)
    acc = account(levels, x, box=box, info=info, solver=solver, lambda_max=lam, eps=eps)
    assert [la.name for la in acc.levels] == ["L0", "L1", "L2"]
    for k, (lv, la) in enumerate(zip(levels, acc.levels, strict=True)):
        r = lv.J @ x - lv.b
        np.testing.assert_allclose(la.achieved, lv.J @ x, rtol=0, atol=1e-14)
        np.testing.assert_allclose(la.residual, r, rtol=0, atol=1e-14)
        assert la.residual_norm == pytest.approx(np.linalg.norm(r), abs=1e-14)
        expected = min(1.0, max(0.0, 1.0 - np.linalg.norm(r) / np.linalg.norm(lv.b)))
        assert la.fraction == pytest.approx(expected, abs=1e-12)
        smin = _projected_smin(levels, k)
        assert la.sigma_min == pytest.approx(smin, rel=1e-8, abs=1e-12)
        law = np.sqrt(1 - (smin / eps) ** 2) * lam if smin < eps else 0.0
        assert la.damping == pytest.approx(law, rel=1e-8, abs=1e-12)
    at = np.flatnonzero(np.isclose(x, box[1], rtol=0, atol=1e-9) | np.isclose(x, box[0], rtol=0, atol=1e-9))
    if solver in ("sns_tpm", "sns", "qp"):
        assert acc.box_kept and acc.at_bound == tuple(at)
        assert all(s == (1 if x[j] > 0 else -1) for j, s in zip(acc.at_bound, acc.sides, strict=True))
        assert not acc.beyond
    else:
        assert not acc.box_kept
        beyond = np.flatnonzero((x > box[1] + 1e-9) | (x < box[0] - 1e-9))
        assert acc.beyond == tuple(beyond)
    if solver.startswith("qp"):
        assert acc.backend == "proxqp"


def test_sns_fractions_are_the_scale_factors():
    rng = np.random.default_rng(0)
    n = 6
    levels = [Level(rng.standard_normal((2, n)), 3.0 * rng.standard_normal(2), name=f"L{i}") for i in range(2)]
    box = (np.full(n, -0.5), np.full(n, 0.5))
    x, info = solve("sns_tpm", levels, n, box=box)
    acc = account(levels, x, box=box, info=info, solver="sns_tpm")
    assert 0 < info["scale"] < 1
    for la in acc.levels:  # full-rank stack: J x = s b for every level
        assert la.fraction == pytest.approx(info["scale"], abs=1e-9)
        assert la.scale == info["scale"]
    x, info = solve("sns", levels, n, box=box)
    acc = account(levels, x, box=box, info=info, solver="sns")
    for la, s in zip(acc.levels, info["scales"], strict=True):
        assert la.scale == s


def test_inequality_level_account():
    J = np.array([[1.0, 0.0], [0.0, 1.0]])
    lv = Level(J, lower=[1.0, -np.inf], upper=[np.inf, 2.0], name="ineq")
    x = np.array([0.25, 2.5])
    acc = account([lv], x)
    la = acc.levels[0]
    np.testing.assert_allclose(la.residual, [0.25 - 1.0, 2.5 - 2.0])     # signed violation
    np.testing.assert_allclose(la.desired, [1.0, 2.0])                   # nearest admissible value
    assert la.fraction == pytest.approx(1 - np.hypot(0.75, 0.5) / 1.0)   # violation at 0: row 0 only (1.0)
    assert la.active_rows == (0, 1) and not la.met


# -- causes on hand-made stacks -----------------------------------------------------------------
def _released_met(levels, box, joints, sides, k, solver):
    lo, up = box[0].copy(), box[1].copy()
    for j, s in zip(joints, sides, strict=True):
        (up if s > 0 else lo)[j] = np.inf if s > 0 else -np.inf
    x, info = solve(solver, levels, levels[0].J.shape[1], box=(lo, up))
    return account(levels, x, box=(lo, up), info=info, solver=solver).levels[k].met


def test_higher_levels_blocking_set_is_the_one_built_in():
    n = 3
    A = Level([[1.0, 0, 0]], [1.0], name="A")
    B = Level([[0, 1.0, 0]], [1.0], name="B")
    D = Level([[0, 0, 1.0]], [0.5], name="D")           # independent: never blocks
    C = Level([[1.0, 1.0, 0]], [5.0], name="C")          # needs x0 + x1 = 5: only A and B together block it
    E = Level([[2.0, 0, 0]], [7.0], name="E")            # needs x0 = 3.5: A alone blocks it
    levels = [A, D, B, C, E]
    x = solve("tpm", levels, n)[0]
    acc = explain(levels, x, solver="tpm")
    assert [la.met for la in acc.levels] == [True, True, True, False, False]
    (cause_c,) = acc.causes[3]
    assert cause_c.kind == "higher_levels" and cause_c.levels == (0, 2)   # A and B, not D
    (cause_e,) = acc.causes[4]
    assert cause_e.kind == "higher_levels" and cause_e.levels == (0,)


def test_damping_blocking_set():
    A = Level([[1.0, 0, 0]], [1.0], name="A")
    B = Level([[0, 0, 1.0]], [1.0], name="B")
    C = Level([[1.0, 1e-3, 0]], [2.0], name="C")         # nearly dependent on A only
    lam, eps = 0.1, 0.1
    levels = [A, B, C]
    x = solve("tpm", levels, 3, lambda_max=lam, eps=eps)[0]
    acc = explain(levels, x, solver="tpm", lambda_max=lam, eps=eps)
    la = acc.levels[2]
    assert la.damping == pytest.approx(damping_lambda(1e-3, lam, eps)) and 0 < la.kept < 1
    assert Cause_kinds(acc.causes[2]) == {"damping"}
    assert acc.causes[2][0].levels == (0,)
    # a level near-singular on its own: an empty blocking set
    S = Level([[1e-3, 0, 0]], [1.0], name="S")
    x = solve("tpm", [S], 3, lambda_max=lam, eps=eps)[0]
    acc = explain([S], x, solver="tpm", lambda_max=lam, eps=eps)
    assert acc.causes[0][0].kind == "damping" and acc.causes[0][0].levels == ()


def Cause_kinds(causes):
    return {c.kind for c in causes}


@pytest.mark.parametrize("solver", ["sns_tpm", "sns", "qp"])
def test_joint_bounds_blocking_set_minimal_and_verified(solver):
    n = 4
    box = (np.full(n, -1.0), np.full(n, 1.0))
    top = Level([[0, 0, 0, 1.0]], [0.5], name="top")
    both = Level([[1.0, 0, 0, 0], [0, 1.0, 0, 0]], [2.0, -2.0], name="both")   # needs joints 0 and 1 past +-1
    levels = [top, both]
    x, info = solve(solver, levels, n, box=box)
    acc = explain(levels, x, box=box, info=info, solver=solver)
    k = 1
    assert not acc.levels[k].met
    (cause,) = [c for c in acc.causes[k] if c.kind == "joint_bounds"]
    assert set(cause.joints) == {0, 1}
    assert dict(zip(cause.joints, cause.sides, strict=True)) == {0: 1, 1: -1}
    assert cause.fraction_without == pytest.approx(1.0, abs=1e-6)
    # verified independently, and minimal: without any one member the level is not met
    assert _released_met(levels, box, cause.joints, cause.sides, k, solver)
    for drop in range(len(cause.joints)):
        rest = [j for i, j in enumerate(cause.joints) if i != drop]
        sides = [s for i, s in enumerate(cause.sides) if i != drop]
        assert not _released_met(levels, box, rest, sides, k, solver)


def test_one_of_two_saturated_joints_suffices():
    n = 3
    box = (np.full(n, -1.0), np.full(n, 1.0))
    lv = Level([[1.0, 1.0, 0]], [3.0], name="sum")     # x0 = x1 = 1 at the bounds; either one released is enough
    x, info = solve("sns", [lv], n, box=box)
    acc = explain([lv], x, box=box, info=info, solver="sns")
    (cause,) = acc.causes[0]
    assert cause.kind == "joint_bounds" and len(cause.joints) == 1 and cause.joints[0] in (0, 1)
    assert _released_met([lv], box, cause.joints, cause.sides, 0, "sns")


def test_met_levels_have_no_cause_and_analytic_solvers_never_resolve():
    n = 3
    lv = Level(np.eye(n), [1.0, 2.0, 3.0], name="all")
    x = solve("tpm", [lv], n)[0]
    calls = []
    acc = explain([lv], x, box=(np.full(n, -1.0), np.full(n, 1.0)), solver="tpm",
                  solve=lambda *a: calls.append(a))
    assert acc.causes == ((),) and not calls and acc.beyond == (1, 2)


def test_deletion_filter_irreducible():
    # property: the set still contains both 2 and 5
    assert deletion_filter(list(range(8)), lambda s: 2 in s and 5 in s) == [2, 5]


# -- infeasible hard constraints ------------------------------------------------------------------
def test_box_cannot_contain_the_top_level():
    box = (np.full(4, -1.0), np.full(4, 1.0))
    top = Level([[1.0, 1.0, 0, 0]], [5.0], name="top")
    with pytest.raises(InfeasibleError) as err:
        check_feasible([top, Level(np.eye(4), np.zeros(4), name="rest")], box, hard=1)
    assert set(err.value.conflict) == {"box upper of joint 0 (1)", "box upper of joint 1 (1)",
                                       "level 'top' row 0 (= 5)"}
    assert isinstance(err.value, SolverFailedError) and "level 'top' row 0" in str(err.value)
    check_feasible([Level([[1.0, 1.0, 0, 0]], [1.5], name="top")], box, hard=1)   # feasible: no error


def test_contradictory_inequality_levels():
    J = np.array([[1.0, 1.0, 0.0]])
    a = Level(J, lower=[2.0], name="a")
    b = Level(J, upper=[1.0], name="b")
    free = Level([[0, 0, 1.0]], lower=[-5.0], upper=[5.0], name="free")
    with pytest.raises(InfeasibleError) as err:
        check_feasible([free, a, b], None, hard=[0, 1, 2])
    assert set(err.value.conflict) == {"level 'a' row 0 lower (2)", "level 'b' row 0 upper (1)"}


def test_empty_box():
    with pytest.raises(EmptyBoxError) as err:
        check_feasible([], (np.array([0.0, 1.0]), np.array([1.0, 0.5])))
    assert isinstance(err.value, BoxError) and isinstance(err.value, InfeasibleError)
    assert "joint(s) [1]" in str(err.value) and len(err.value.conflict) == 2


# -- the robot layer, the recording and the command line -------------------------------------------
@pytest.fixture(scope="module")
def romeo_run(tmp_path_factory):
    from hqp_tpm.app.cli import run_scenario

    out = tmp_path_factory.mktemp("romeo_sns_tpm")
    summary = run_scenario("romeo_sns_tpm", out, progress=False, figures=True, replay=False, steps=6, explain=True)
    return out, summary


def test_run_records_the_account_and_explain_prints_it(romeo_run, capsys):
    from hqp_tpm.app.cli import main

    out, summary = romeo_run
    arrays = np.load(out / "trajectory.npz")
    assert arrays["explain_fraction"].shape == (6, 5)
    assert list(arrays["explain_tasks"]) == ["right_sole", "com", "left_foot", "left_hand", "right_hand"]
    # the recorded fraction is the one recomputed from the recorded desired and achieved commands
    for i, name in enumerate(arrays["explain_tasks"]):
        d, a = arrays[f"explain_desired_{name}"], arrays[f"explain_achieved_{name}"]
        r, ref = np.linalg.norm(a - d, axis=1), np.linalg.norm(d, axis=1)
        tiny = ref <= 1e-6  # a zero reference: met (1) when the residual is zero too
        expected = np.where(tiny, (r <= 1e-6).astype(float), np.clip(1 - r / np.where(tiny, 1, ref), 0, 1))
        np.testing.assert_allclose(arrays["explain_fraction"][:, i], expected, atol=1e-9)
    assert (out / "explain.png").exists()
    metrics = json.loads((out / "metrics.json").read_text())
    assert set(metrics["explain"]["by_cause_s"]) == set(arrays["explain_tasks"])
    assert main(["explain", str(out), "--t", "0.002"]) == 0
    text = capsys.readouterr().out
    assert "t = 0.0020 s" in text and "right_hand" in text and "met" in text and "joints at a bound" in text


def test_explain_reruns_a_run_without_the_account(tmp_path, capsys):
    from hqp_tpm.app.cli import main, run_scenario

    run_scenario("romeo_sns_tpm", tmp_path, progress=False, figures=False, replay=False, steps=3)
    assert "explain_fraction" not in np.load(tmp_path / "trajectory.npz")
    assert "explain" not in json.loads((tmp_path / "metrics.json").read_text())
    assert main(["explain", str(tmp_path), "--t", "0.001"]) == 0
    assert "re-ran the scenario" in capsys.readouterr().out


def test_off_by_default(monkeypatch, tmp_path):
    """Without --explain no account is computed (the benchmarks' path): the module is never called."""
    import hqp_tpm.solvers.account as acc_mod
    from hqp_tpm.app.cli import run_scenario

    def boom(*a, **k):
        raise AssertionError("account computed while the feature is off")

    monkeypatch.setattr(acc_mod, "account", boom)
    monkeypatch.setattr(acc_mod, "explain", boom)
    run_scenario("planar5_exact", tmp_path, progress=False, figures=False, replay=False, steps=20)


def test_explain_with_hard_levels_raises_the_certificate():
    box = (np.full(3, -1.0), np.full(3, 1.0))
    top = Level([[1.0, 1.0, 0]], [5.0], name="top")
    x, info = solve("qp", [top], 3, box=box)
    with pytest.raises(InfeasibleError, match="box upper of joint 0"):
        explain([top], x, box=box, info=info, solver="qp", hard=1)
    acc = explain([top], x, box=box, info=info, solver="qp")   # not declared hard: explained, no error
    assert acc.causes[0][0].kind == "joint_bounds"


def test_replay_shows_the_current_frames_account(romeo_run, tmp_path):
    from hqp_tpm.app.explain import annotate_replay

    out, _ = romeo_run
    arrays = dict(np.load(out / "trajectory.npz"))
    page = tmp_path / "replay.html"
    page.write_text('<html><body><span id="hqp-label">t = 0.000 s</span></body></html>')
    assert annotate_replay(page, arrays, fps=1000.0)
    text = page.read_text()
    assert 'id="hqp-explain"' in text and "right_hand" in text and text.count("</body>") == 1
    data = json.loads(text.split("const frames = ", 1)[1].split(";\n", 1)[0].replace("<\\/", "</"))
    assert data["t"] == [round(float(t), 6) for t in arrays["t"]] and len(data["index"]) == 6
    assert not annotate_replay(page, arrays)                     # once only
    bare = tmp_path / "bare.html"
    bare.write_text("<html><body></body></html>")
    assert not annotate_replay(bare, arrays)                     # no time label: left as it is


def test_romeo_joint_blocking_set_verified_and_minimal():
    """romeo_sns_tpm at t = 0 (the common scale factor is below 1): each level's joint blocking set, re-solved
    independently, gives the level its residual without a box; without any one member it does not."""
    from hqp_tpm.app import build, scenario
    from hqp_tpm.app.explain import Explainer

    data = scenario.read(scenario.resolve_path("romeo_sns_tpm"))
    data["limits"]["command_rate"] = False  # papers/002's box: the step is the plain solve in it (re-solved below)
    _, ctrl, _, _ = build.build(scenario.parse(data))
    res = ctrl.compute()
    acc = Explainer(ctrl).account(ctrl, res)
    box = ctrl.box(ctrl.state, res.t)
    n = ctrl.robot.nv

    def residual(lo, up, k):
        x, _ = solve("sns_tpm", res.levels, n, box=(lo, up), lambda_max=ctrl.lambda_max, eps=ctrl.eps)
        return account(res.levels, x).levels[k].residual_norm

    def released(joints, sides):
        lo, up = box[0].copy(), box[1].copy()
        for j, s in zip(joints, sides, strict=True):
            if s >= 0:
                up[j] = np.inf
            if s <= 0:
                lo[j] = -np.inf
        return lo, up

    assert acc.scale < 1 and acc.at_bound
    checked = 0
    for k, causes in enumerate(acc.causes):
        for c in causes:
            if c.kind != "joint_bounds":
                continue
            free = residual(np.full(n, -np.inf), np.full(n, np.inf), k)
            now = acc.levels[k].residual_norm
            target = free + max(1e-6 * max(1.0, np.linalg.norm(acc.levels[k].desired)), 1e-3 * (now - free))
            assert residual(*released(c.joints, c.sides), k) <= target
            for drop in range(len(c.joints)):
                keep = [i for i in range(len(c.joints)) if i != drop]
                assert residual(*released([c.joints[i] for i in keep], [c.sides[i] for i in keep]), k) > target
            checked += 1
    assert checked >= 1


def test_bound_kinds_name_the_limit_that_defines_the_bound():
    from hqp_tpm.app.explain import bound_kinds
    from hqp_tpm.robot.limits import JointLimits
    from hqp_tpm.robot.model import Robot
    from hqp_tpm.robot.state import State

    robot = Robot.load("planar5")
    limits = JointLimits(robot, order=1, dt=0.01, acceleration_limit=50.0)
    q_max = robot.position_limits()[1]
    q = np.zeros(robot.nv)
    q[1] = q_max[1] - 0.001        # position one period ahead: 0.1 rad/s (braking 0.32, v_max 3.14)
    q[2] = q_max[2] - 0.05         # braking: sqrt(2 * 50 * 0.05) = 2.24 rad/s (position 5, v_max 3.14)
    st = State(robot).update(q, np.zeros(robot.nv))
    lo, up = limits(st, 0.0)
    joints, sides = [0, 1, 2, 1], [1, 1, 1, -1]
    values = np.array([up[0], up[1], up[2], lo[1]])
    assert up[1] == pytest.approx(0.1) and up[2] == pytest.approx(np.sqrt(5.0))
    assert bound_kinds(limits, st, values, range(4), sides, columns=joints) == \
        ["velocity", "position", "braking", "velocity"]
    assert bound_kinds(lambda s, t: (lo, up), st, values, range(4), sides, columns=joints) == ["box"] * 4

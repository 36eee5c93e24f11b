"""hqp_tpm.testing: the assertions pass where the solvers agree and fail, readably, where they do not."""

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from threadpoolctl import threadpool_limits

from hqp_tpm.solvers import Level
from hqp_tpm.testing import assert_solvers_agree, assert_task_derivatives, check_solvers, load_case
from hqp_tpm.testing.strategies import boxed_stacks, dependent_stacks, robot_states, stacks

FEW = settings(max_examples=40, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
ALL = ("tpm", "nullspace", "sns_tpm", "sns", "qp:proxqp", "qp:daqp")


@pytest.fixture(autouse=True, scope="module")
def _one_blas_thread():
    with threadpool_limits(1):
        yield


def small_stack(seed=0, n=7):
    rng = np.random.default_rng(seed)
    return [(rng.standard_normal((m, n)), rng.standard_normal(m)) for m in (3, 2, 3)]


# ----------------------------------------------------------------------------------------
# Passing: the public strategies on the ranges they document.
# ----------------------------------------------------------------------------------------
@FEW
@given(stacks(full_rank=True, max_cond=1e3, n=(2, 20), levels=(1, 6)))
def test_full_rank_stacks_agree(case):
    report = assert_solvers_agree(**case.kwargs())
    assert report.ok and all(c.what == "same problem" for c in report.comparisons)


@FEW
@given(dependent_stacks(n=12))
def test_dependent_and_conflicting_stacks_agree(case):
    assert_solvers_agree(**case.kwargs(), solvers=("tpm", "nullspace", "qp:daqp"))


@FEW
@given(boxed_stacks(stacks(full_rank=True, max_cond=1e3, inequality=0.3), box="binds"))
def test_binding_boxes_keep_the_residual_order(case):
    report = assert_solvers_agree(**case.kwargs(), solvers=ALL)
    assert case.binds and any(c.what == "residual order" for c in report.comparisons)


@FEW
@given(boxed_stacks(stacks(full_rank=True, max_cond=1e3), box="contains", damping={"lambda_max": 0.05, "eps": 0.1}))
def test_boxes_containing_the_solution_change_nothing(case):
    report = assert_solvers_agree(**case.kwargs(), solvers=ALL)
    assert all(c.what in ("same problem", "in box") for c in report.comparisons)


# ----------------------------------------------------------------------------------------
# Failing, with a readable table and a saved case that reproduces it.
# ----------------------------------------------------------------------------------------
def test_a_qp_backend_with_a_loose_tolerance_fails_with_a_table(tmp_path):
    levels = small_stack()
    loose = {"qp:proxqp": {"eps_abs": 1e-1}}
    with pytest.raises(AssertionError) as err:
        assert_solvers_agree(levels, solver_options=loose, seed=0, save_to=tmp_path)
    msg = str(err.value)
    print(msg)
    lines = msg.splitlines()
    assert lines[0].startswith("solvers disagree: ") and "qp:proxqp" in lines[0]
    assert "cond(J) = " in msg and "residual per level" in msg
    header = next(line for line in lines if line.startswith("level"))
    assert all(s in header for s in ("tpm", "nullspace", "qp:proxqp", "qp:daqp"))
    assert "FAIL tpm vs qp:proxqp" in msg and "ok   tpm vs nullspace" in msg and "at joint" in msg
    saved = list(tmp_path.glob("*.npz"))
    assert len(saved) == 1 and str(saved[0]) in msg
    case = load_case(saved[0])
    assert case["seed"] == 0 and case["solver_options"] == loose
    with pytest.raises(AssertionError, match="FAIL tpm vs qp:proxqp"):
        assert_solvers_agree(**case)
    case.pop("solver_options")
    assert assert_solvers_agree(**case).ok  # the same stack with the default settings


def test_a_loose_qp_under_a_binding_box_breaks_the_residual_order(tmp_path):
    levels = small_stack(3)
    box = (-0.3 * np.ones(7), 0.3 * np.ones(7))
    with pytest.raises(AssertionError) as err:
        assert_solvers_agree(levels, ("sns_tpm", "sns", "qp:proxqp"), box=box, save_to=tmp_path,
                             solver_options={"qp:proxqp": {"eps_abs": 1e-1}})
    msg = str(err.value)
    print(msg)
    assert "FAIL qp:proxqp vs sns " in msg and "residual order" in msg and "box: 7 joints, binds" in msg
    # m = 8 > n = 7: SNS-TPM keeps level 0 exactly (its extension of Algorithm 1), so the loose QP loses to it too
    assert "FAIL qp:proxqp vs sns_tpm" in msg


def test_ill_conditioned_stacks_get_a_tolerance_that_grows_with_cond():
    """cond 1e8 with the defaults: 1e3 eps cond = 2.2e-5 (the forward error of any double solve)."""
    from hqp_tpm.testing.strategies import prescribed_matrix

    rng = np.random.default_rng(5)
    J = prescribed_matrix(rng, 6, 9, np.geomspace(1.0, 1e-8, 6))
    report = check_solvers([(J[:3], rng.standard_normal(3)), (J[3:], rng.standard_normal(3))], ("tpm", "qp:daqp"))
    assert 1e7 < report.cond < 1e9
    assert report.comparisons[0].tol > 1e-5


def test_unknown_solver_and_empty_stack_are_typed_errors():
    from hqp_tpm.errors import ShapeError, UnknownNameError

    with pytest.raises(UnknownNameError, match="tmp"):
        assert_solvers_agree(small_stack(), ("tpm", "tmp"))
    with pytest.raises(ShapeError, match="empty"):
        assert_solvers_agree([], n=3)


def test_inequality_levels_are_compared_on_their_active_rows_or_as_given():
    rng = np.random.default_rng(11)
    A = rng.standard_normal((3, 9))
    ineq = Level(A, lower=np.array([0.5, -np.inf, -2.0]), upper=np.array([np.inf, 1.0, -1.0]))
    levels = [ineq, (rng.standard_normal((3, 9)), rng.standard_normal(3))]
    report = assert_solvers_agree(levels)
    assert any("active rows" in n for n in report.notes)
    report = assert_solvers_agree(levels, inequalities="as_given")  # QP vs the analytic ones: no relation
    assert {(c.a, c.b) for c in report.comparisons} == {("tpm", "nullspace"), ("qp:proxqp", "qp:daqp")}


# ----------------------------------------------------------------------------------------
# The scenarios' stacks pass.
# ----------------------------------------------------------------------------------------
SCENARIOS = ["planar5_exact", "planar5_transition", "lwr_relaxed", "lwr_point35_inequality", "lwr_avoid3d",
             "iiwa_admittance", "romeo_sns_tpm", "romeo_tpm"]


@pytest.mark.parametrize("name", SCENARIOS)
def test_scenario_stacks_pass(name):
    from hqp_tpm.app import build, scenario

    sc = scenario.load(name)
    _, ctrl, _, _ = build.build(sc)
    solvers = ["tpm", "nullspace", "qp:proxqp", "qp:daqp"]
    if ctrl.box is not None:
        solvers += ["sns_tpm", "sns"]
    damping = {"lambda_max": ctrl.lambda_max, "eps": ctrl.eps}
    checked = 0
    for k in range(121):
        v, t = ctrl.v.copy(), ctrl.t
        res = ctrl.step()
        if k % 40:
            continue
        box = ctrl.box(ctrl.state, t) if ctrl.box is not None else None
        x0 = -ctrl.nullspace_damping * v if (ctrl.order == 2 and ctrl.nullspace_damping) else None
        assert_solvers_agree(res.levels, solvers, box=box, x0=x0, damping=damping, n=ctrl.robot.nv)
        checked += 1
    assert checked == 4


# ----------------------------------------------------------------------------------------
# Task derivatives.
# ----------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def panda():
    from hqp_tpm.robot.model import Robot

    return Robot.load("panda")


def test_task_derivatives_pass_for_the_library_tasks(panda):
    from hqp_tpm.tasks import FrameOrientation, FramePose, FramePosition, Pointing, QuaternionOrientation

    for task in (FramePosition(panda, "panda_hand"), Pointing(panda, "panda_hand", [1, 0, 0], 0.1),
                 FrameOrientation(panda, "panda_hand"), FramePose(panda, "panda_hand"),
                 QuaternionOrientation(panda, "panda_hand", np.eye(3))):
        errors = assert_task_derivatives(task, panda, states=3)
        assert len(errors) == 3


def test_a_wrong_jacobian_fails_with_a_table(panda):
    from hqp_tpm.tasks import FramePosition

    class Wrong(FramePosition):
        def jacobian(self, state):
            J = super().jacobian(state).copy()
            J[1, 3] *= 1.01
            return J

    with pytest.raises(AssertionError) as err:
        assert_task_derivatives(Wrong(panda, "panda_hand"), panda, states=2)
    msg = str(err.value)
    print(msg)
    assert "derivatives off at 2 of 2 states" in msg and "(1, panda_joint4)" in msg and "reproduce state 0" in msg


def test_robot_states_are_within_the_limits(panda):
    from hypothesis import given as given_

    lo, up = panda.position_limits()

    @settings(max_examples=30, deadline=None, derandomize=True)
    @given_(robot_states(panda, margin=0.01))
    def check(state):
        q, v = state
        assert ((q >= lo) & (q <= up)).all()
        assert (np.abs(v) <= panda.velocity_limits()).all()

    check()


# ----------------------------------------------------------------------------------------
# Controller cross-check.
# ----------------------------------------------------------------------------------------
def test_controller_crosscheck_records_each_step(panda):
    import matplotlib

    matplotlib.use("Agg")
    from hqp_tpm.control.controller import Controller
    from hqp_tpm.robot.limits import JointLimits
    from hqp_tpm.tasks import FramePosition, Gains, Posture
    from hqp_tpm.testing import plot_crosscheck

    q0 = panda.neutral()
    q0[3], q0[5] = -1.5, 1.5
    tasks = [FramePosition(panda, "panda_hand", [0.5, 0.2, 0.4], Gains(kp=5)), Posture(panda, None, Gains(kp=1))]
    ctrl = Controller(panda, tasks, order=1, dt=1e-2, solver="tpm", crosscheck="qp:daqp", q0=q0)
    for _ in range(30):
        ctrl.step()
    log = ctrl.crosscheck_log
    assert len(log) == 30 and log.solver == "qp:daqp" and all(log.same_problem)
    assert log.max_diff() < 1e-8
    boxed = Controller(panda, tasks, order=1, dt=1e-2, solver="sns_tpm", crosscheck="qp:daqp", q0=q0,
                       box=JointLimits(panda, order=1, dt=1e-2))
    for _ in range(30):
        boxed.step()
    assert not all(boxed.crosscheck_log.same_problem)  # the first steps saturate: different problems
    assert boxed.crosscheck_log.max_diff() < 1e-8  # where the problems are the same, the same commands
    ax = plot_crosscheck(boxed)
    assert len(ax.lines) == 3


# ----------------------------------------------------------------------------------------
# What the strategies found outside the documented ranges (kept so that a fix shows up).
# ----------------------------------------------------------------------------------------
@pytest.mark.parametrize("case", ["repeated", "zero_row"])
def test_tpm_after_a_singular_or_repeated_level(case):
    rng = np.random.default_rng(1)
    if case == "repeated":  # the same task again with another target, then one more level (n = 5, 4 + 4 + 1 rows)
        J0, b0 = rng.standard_normal((4, 5)), rng.standard_normal(4)
        levels = [(J0, b0), (J0.copy(), b0 + rng.standard_normal(4)), (rng.standard_normal((1, 5)), [1.0])]
    else:  # a task singular by itself (a planar arm stretched out: zero x row), then a posture
        singular = np.array([[0, 0, 0, 0, 0], [1.5, 1, 0.5, 0, 0.0]])
        levels = [(rng.standard_normal((1, 5)), [0.3]), (singular, [0.2, 0.1]), (np.eye(5), rng.standard_normal(5))]
    assert_solvers_agree(levels, ("tpm", "nullspace", "qp:daqp"))


def test_readme_example_runs_and_the_documented_crosscheck_holds():
    """The README's "Testing your own stacks" block runs on its own, and docs/testing.md's in-run crosscheck
    (``Controller(robot, stack, q0=q0, crosscheck="qp:daqp")``) logs every step with the two solvers agreeing."""
    import re
    from pathlib import Path

    import matplotlib

    from hqp_tpm import Controller, FramePosition, Posture, Robot, Stack

    matplotlib.use("Agg")
    root = Path(__file__).resolve().parents[1]
    text = (root / "README.md").read_text(encoding="utf-8")
    section = text[text.index("## Testing your own stacks"):]
    block = re.search(r"```python\n(.*?)```", section, re.S).group(1)
    exec(block, {})
    assert 'crosscheck="qp:daqp"' in (root / "docs" / "testing.md").read_text(encoding="utf-8")
    robot = Robot.load("planar5")
    stack = Stack.of(FramePosition(robot, "planar5_ee", [0.5, 0.5], axes="xy"), Posture(robot, None))
    q0 = np.array([0.3, 0.4, -0.2, 0.5, 0.1])  # not stretched out (see test_tpm_after_a_singular_or_repeated_level)
    ctrl = Controller(robot, stack, q0=q0, crosscheck="qp:daqp")
    for _ in range(5):
        ctrl.step()
    assert len(ctrl.crosscheck_log) == 5 and ctrl.crosscheck_log.max_diff() < 1e-8


@FEW
@given(boxed_stacks(stacks(max_cond=1e3, conflict=0.3, inequality=0.3), box="binds"))
def test_sns_tpm_fast_path_equals_algorithm_1_as_written(case):
    report = assert_solvers_agree(**case.kwargs(), solvers=("sns_tpm", "sns_tpm_reference", "qp:daqp"))
    same = [c for c in report.comparisons if c.what == "same problem"]
    assert [(c.a, c.b) for c in same] == [("sns_tpm", "sns_tpm_reference")]


def test_run_crosscheck_separates_steps_where_the_problems_differ(tmp_path):
    """hqp-tpm run --crosscheck on SNS-TPM: where the box binds, SNS-TPM and the QP solve different problems
    (reported apart); on the other steps the commands agree. In papers/002's box (``command_rate = false``): the
    scenario's rate box binds on every step (42742a8 then reported a difference of 0.0 over no step; now null)."""
    from hqp_tpm.app.cli import run_scenario
    from hqp_tpm.app.scenario import SCENARIO_DIR

    text = (SCENARIO_DIR / "romeo_sns_tpm.toml").read_text(encoding="utf-8")
    assert "command_rate = true" in text
    paper_box = tmp_path / "romeo_paper_box.toml"
    paper_box.write_text(text.replace("command_rate = true", "command_rate = false"), encoding="utf-8")
    summary = run_scenario(paper_box, tmp_path / "paper", crosscheck=True, steps=150, figures=False, replay=False,
                           progress=False)
    assert 0 < summary["crosscheck_steps_different_problems"] < 150
    assert summary["crosscheck_max_diff"] > 1e-3  # the binding steps
    assert summary["crosscheck_max_diff_same_problem"] < 1e-6
    summary = run_scenario("romeo_sns_tpm", tmp_path / "rate", crosscheck=True, steps=20, figures=False,
                           replay=False, progress=False)
    assert summary["crosscheck_steps_different_problems"] == 20
    assert summary["crosscheck_max_diff_same_problem"] is None


def test_crosscheck_replays_the_blend_of_a_blending_policy():
    """planar5_exact blends stack solutions (papers/004): the other solver goes through the same blend, from the
    same policy state (snapshot/restore), so the recorded difference is the solvers' only."""
    from hqp_tpm.app import build, scenario

    sc = scenario.load("planar5_exact")
    ctrl = build.build(sc)[1]
    assert ctrl.policy.blends
    ctrl.crosscheck = "qp:daqp"
    for _ in range(1500):
        ctrl.step()
    log = ctrl.crosscheck_log
    assert len(log) == 1500 and all(log.like_for_like) and all(log.same_problem)
    assert log.max_diff() < 1e-6


@FEW
@given(stacks(full_rank=True, cond=(1.0, 1e10)))
def test_ill_conditioned_stacks_agree_up_to_cond_1e10(case):
    """Prescribed condition numbers up to 1e10 (nearly dependent levels): the default tolerance max(base,
    1e3 eps cond) holds for TPM, the recursion and the QP without a box."""
    assert_solvers_agree(**case.kwargs(), solvers=("tpm", "nullspace", "qp:daqp"))


@FEW
@given(boxed_stacks(stacks(full_rank=True, cond=(1.0, 1e10)), box="binds"))
def test_ill_conditioned_boxed_stacks_keep_sns_tpm_equal_to_algorithm_1(case):
    assert_solvers_agree(**case.kwargs(), solvers=("tpm", "sns_tpm", "sns_tpm_reference", "sns"))

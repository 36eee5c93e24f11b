"""Mistakes a new user makes in Python and on the command line, answered with a typed error that names the bad
value and the valid choices (the new-user check of 2026-12-04). Every test here failed on main at 43491f1 (a
silent acceptance, a bare ValueError/AttributeError, or a traceback)."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from hqp_tpm.control.controller import Controller
from hqp_tpm.control.policy import FunctionPolicy
from hqp_tpm.control.stack import Stack
from hqp_tpm.errors import ArgumentTypeError, ParameterError, RobotFileError, ShapeError
from hqp_tpm.references.trajectories import Constant
from hqp_tpm.robot.limits import JointLimits
from hqp_tpm.robot.model import Robot
from hqp_tpm.tasks import FrameOrientation, FramePose, FramePosition, Gains, Pointing, Posture


@pytest.fixture(scope="module")
def iiwa():
    return Robot.load("iiwa7")


# 1. FramePose targets -------------------------------------------------------------------------------------------
def test_frame_pose_takes_a_homogeneous_matrix_and_a_pair(iiwa):
    R = pin.utils.rpyToMatrix(0.1, -0.2, 0.3)
    p = np.array([0.4, 0.1, 0.5])
    H = np.eye(4)
    H[:3, :3], H[:3, 3] = R, p
    for target in (H, (p, R), [p.tolist(), R.tolist()], pin.SE3(R, p)):
        task = FramePose(iiwa, "iiwa_ee", target)
        ctrl = Controller(iiwa, Stack.of(task), order=1)
        ctrl.start()  # a given target is kept, not replaced by the start pose
        M = task.target
        np.testing.assert_allclose(M.translation, p)
        np.testing.assert_allclose(M.rotation, R)
        start = ctrl.state.placement(task.fid)
        assert not np.allclose(start.translation, p)  # (the start pose is elsewhere)


@pytest.mark.parametrize("target", [[0.1, 0.2, 0.3, 0.0, 0.0, 0.0], np.zeros(3), np.eye(3), "home", np.zeros((4, 3))])
def test_frame_pose_refuses_what_is_not_a_pose(iiwa, target):
    with pytest.raises(ShapeError, match=r"FramePose 'iiwa_ee_pose': target .* 4x4 homogeneous matrix .* pair"):
        FramePose(iiwa, "iiwa_ee", target)


def test_frame_pose_refuses_a_matrix_that_is_not_a_rigid_motion(iiwa):
    H = np.eye(4)
    H[3, 0] = 1.0
    with pytest.raises(ParameterError, match=r"last row .* expected \[0, 0, 0, 1\]"):
        FramePose(iiwa, "iiwa_ee", H)
    with pytest.raises(ParameterError, match="not a rotation matrix"):
        FramePose(iiwa, "iiwa_ee", (np.zeros(3), 2.0 * np.eye(3)))


# 2. shapes of task parameters ------------------------------------------------------------------------------------
def test_pointing_axis_of_two_numbers(iiwa):
    with pytest.raises(ShapeError, match=r"Pointing 'iiwa_ee_pointing': axis \[0, 1\] has shape \(2,\), expected a "
                                         r"3-vector"):
        Pointing(iiwa, "iiwa_ee", axis=[0, 1], alpha_d=0.1)


@pytest.mark.parametrize("target", [[0, 0, 1], np.eye(4), "home"])
def test_frame_orientation_target_not_a_rotation_matrix(iiwa, target):
    with pytest.raises(ShapeError, match=r"FrameOrientation 'iiwa_ee_orientation': target .* expected a 3x3 rotation"):
        FrameOrientation(iiwa, "iiwa_ee", target)


def test_frame_orientation_still_takes_a_matrix_and_hold(iiwa):
    R = pin.utils.rpyToMatrix(0.1, 0.2, 0.3)
    np.testing.assert_array_equal(FrameOrientation(iiwa, "iiwa_ee", R).target, R)
    assert FrameOrientation(iiwa, "iiwa_ee", "hold").target is None


# 3., 4. what a stack level is -------------------------------------------------------------------------------------
def test_a_task_name_is_not_a_level():
    with pytest.raises(ArgumentTypeError, match=r"stack level 0: 'ee' \(str\) is not a task .*pass the task object"):
        Stack.of("ee")


def test_a_matrix_is_not_a_level(iiwa):
    with pytest.raises(ArgumentTypeError, match=r"stack level 0: an array of shape \(7, 7\) .* a level is a Task"):
        Controller(iiwa, [np.eye(7)])
    with pytest.raises(TypeError):  # (still a TypeError for whoever caught one)
        Controller(iiwa, 3.0)


def test_an_empty_stack_and_a_task_twice(iiwa):
    ee = FramePose(iiwa, "iiwa_ee")
    with pytest.raises(ParameterError, match="at least one level"):
        Stack.of()
    with pytest.raises(ParameterError, match=r"stack level 1 is empty"):
        Stack.of(ee, ())
    with pytest.raises(ParameterError, match=r"task 'iiwa_ee_pose' is in the stack twice \(levels 0 and 1\)"):
        Stack.of(ee, ee)
    with pytest.raises(ParameterError, match=r"twice \(levels 0 and 0\)"):
        Controller(iiwa, [(ee, ee)])


def test_stack_repr_says_level_once(iiwa):
    ee = FramePose(iiwa, "iiwa_ee")
    assert repr(Stack.of(ee)) == "Stack('iiwa_ee_pose', 1 level)"
    assert repr(Stack.of(ee, FrameOrientation(iiwa, "iiwa_ee"))).endswith("2 levels)")


# 4. a box the controller cannot use ------------------------------------------------------------------------------
def test_joint_limits_of_order_3(iiwa):
    with pytest.raises(ParameterError, match=r"JointLimits: order must be 1 .* or 2 .*got 3"):
        JointLimits(iiwa, order=3, dt=1e-3)


@pytest.mark.parametrize(("order", "dt"), [(1, 1e-3), (2, 1e-2)])
def test_a_box_for_another_order_or_period(iiwa, order, dt):
    ee = FramePose(iiwa, "iiwa_ee")
    with pytest.raises(ParameterError, match=rf"box: JointLimits\(order={order}, dt={dt:g}\) does not match the "
                                             r"controller's order=2, dt=0.001"):
        Controller(iiwa, [ee], order=2, dt=1e-3, solver="sns_tpm", box=JointLimits(iiwa, order=order, dt=dt))
    Controller(iiwa, [ee], order=2, dt=1e-3, solver="sns_tpm", box=JointLimits(iiwa, order=2, dt=1e-3))
    with pytest.raises(ArgumentTypeError, match=r"box must be None or a callable box\(state, t\)"):
        Controller(iiwa, [ee], order=2, dt=1e-3, solver="sns_tpm", box=(-np.ones(7), np.ones(7)))


@pytest.mark.parametrize("solver", ["tpm", "nullspace"])
def test_an_analytic_solver_refuses_a_box_as_a_scenario_does(iiwa, solver):
    ee = FramePose(iiwa, "iiwa_ee")
    with pytest.raises(ParameterError, match=rf"box: a hard joint box, which solver '{solver}' ignores; valid: .*"
                                             r"sns_tpm.*box=None"):
        Controller(iiwa, [ee], order=2, solver=solver, box=JointLimits(iiwa, order=2, dt=1e-3))
    with pytest.raises(ParameterError, match="ignores"):  # any box function, not only JointLimits
        Controller(iiwa, [ee], order=2, solver=solver, box=lambda st, t: (-np.ones(7), np.ones(7)))


# 5. a bare function as the policy ---------------------------------------------------------------------------------
def _relative_reach(robot):
    ee = FramePosition(robot, "iiwa_ee", Constant(value=[0.0, 0.05, -0.05], relative=True), Gains(5.0), name="ee")
    post = Posture(robot, None, Gains(1.0), name="posture")
    return ee, post


def test_a_bare_function_starts_the_tasks_it_returns(iiwa):
    q0 = np.linspace(-0.5, 0.6, 7)
    ee, post = _relative_reach(iiwa)
    bare = Controller(iiwa, lambda s, t: Stack.of(ee, post), order=1, q0=q0)
    ee2, post2 = _relative_reach(iiwa)
    wrapped = Controller(iiwa, FunctionPolicy(lambda s, t: Stack.of(ee2, post2), tasks=[ee2, post2]), order=1, q0=q0)
    for _ in range(5):  # relative target and held posture taken from the start state, as FunctionPolicy(tasks=...)
        np.testing.assert_array_equal(bare.step().command, wrapped.step().command)
    p_start = Controller(iiwa, [post], q0=q0).state.update(q0, np.zeros(7)).placement(ee.fid).translation
    np.testing.assert_allclose(ee.reference(0.0)[0], p_start + [0.0, 0.05, -0.05])
    assert bare.tasks() == [ee, post]


def test_a_bare_function_with_a_held_target_runs(iiwa):
    held = FramePosition(iiwa, "iiwa_ee", None, Gains(5.0), name="held")
    ctrl = Controller(iiwa, lambda s, t: Stack.of(held), order=1, q0=np.full(7, 0.3))
    assert np.linalg.norm(ctrl.step().command) < 1e-9  # held where it starts: no motion


def test_a_policy_function_that_returns_no_stack(iiwa):
    ee, _ = _relative_reach(iiwa)
    ctrl = Controller(iiwa, lambda s, t: [ee], order=1)
    with pytest.raises(ArgumentTypeError, match=r"returned list, expected a Stack"):
        ctrl.step()
    assert ctrl.steps == 0


# 7. names in messages ---------------------------------------------------------------------------------------------
def test_an_unknown_robot_lists_the_shipped_ones():
    with pytest.raises(RobotFileError) as info:
        Robot.load("iiwa")
    text = str(info.value)
    assert "did you mean 'iiwa7'" in text
    for name in ("iiwa7", "lwr4", "planar4", "planar5", "romeo21", "talos", "romeo", "panda"):
        assert f" {name}," in text or text.endswith(f" {name}") or f" {name};" in text, name
    assert text.count("panda,") == 1  # example-robot-data's list once


@pytest.mark.parametrize("steps", [0, -3, 2.5])
def test_record_names_its_steps_argument(iiwa, tmp_path, steps):
    import hqp_tpm

    ctrl = Controller(iiwa, [FramePose(iiwa, "iiwa_ee")], order=1)
    with pytest.raises(ParameterError, match=r"^record: steps: ") as info:
        hqp_tpm.record(ctrl, tmp_path / "r", steps=steps, figures=False, replay=False)
    assert "--steps" not in str(info.value)
    assert not (tmp_path / "r").exists()


# 6. the command line ----------------------------------------------------------------------------------------------
def test_sweep_over_a_misspelt_field_runs_nothing(tmp_path, capsys):
    from hqp_tpm.app.cli import main

    out = tmp_path / "sw"
    code = main(["sweep", "planar5_exact", "--set", "polcy.d_m=0.15,0.25", "--steps", "5", "--workers", "0",
                 "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2
    assert "unknown field(s) 'polcy'; known fields: " in err and "'policy'" in err and "polcy.d_m=0.15" in err
    assert "nothing was run" in err and "v001" not in err  # no variant ran
    assert not out.exists()


def test_sweep_where_every_variant_fails_exits_nonzero_and_claims_no_figure(tmp_path, capsys):
    from hqp_tpm.app.cli import main

    out = tmp_path / "sw"
    code = main(["sweep", "planar5_exact", "--set", "policy.d_m=-1.0,-2.0", "--steps", "5", "--workers", "0",
                 "--out", str(out)])
    text = capsys.readouterr().out
    assert code == 1 and "2 variants, 2 failed" in text
    assert not (out / "sweep.png").is_file() and "summary.md (no sweep.png" in text and ", sweep.png" not in text


@pytest.mark.parametrize(("argv", "match"), [
    (["run", "planar5_exact", "--solver", "TPM"], r"^hqp-tpm: error: --solver: unknown solver 'TPM'; valid: tpm, "),
    (["run", "planar5_exact", "--solver", "qp:foo"], r"^hqp-tpm: error: --solver: unknown QP backend 'foo'"),
    (["sweep", "planar5_exact", "--set", "policy.d_m=0.2", "--solver", "tpm,qp:foo"],
     r"^hqp-tpm: error: --solver: unknown QP backend 'foo'"),
    (["run", "romeo_sns", "--solver", "tpm"], r"solver 'tpm' .*ignores the hard joint box of romeo_sns\.toml\.limits"),
    (["sweep", "romeo_sns", "--set", "scenario.eps=0.1", "--solver", "nullspace"],
     r"--solver 'nullspace' ignores the hard joint box of romeo_sns\[v000\]\.limits"),
])
def test_a_bad_solver_option_is_named_before_the_run(tmp_path, capsys, argv, match):
    import re

    from hqp_tpm.app.cli import main

    assert main([*argv, "--out", str(tmp_path / "o"), "--steps", "3"]) == 2
    captured = capsys.readouterr()
    assert re.search(match, captured.err), captured.err
    assert "step" not in captured.err.split("error:")[1][:40]  # (not "step 1 (t = 0 s): ...")
    assert "planar5_exact.toml" not in captured.err  # the option is blamed, not the file
    assert not (tmp_path / "o").exists()


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """Two folders written by hqp_tpm.record from a planar5 controller: without and with the per-step account."""
    import hqp_tpm

    robot = Robot.load("planar5")
    out = {}
    for explain in (False, True):
        tip = FramePosition(robot, "planar5_tip_1", [0.5, 0.5, 0.0], Gains(1.0), name="tip")
        ctrl = Controller(robot, [tip, Posture(robot, None, Gains(1.0))], order=1, dt=0.01)
        out[explain] = tmp_path_factory.mktemp("rec") / "run"
        hqp_tpm.record(ctrl, out[explain], steps=5, figures=False, replay=False, explain=explain)
    return out


@pytest.mark.parametrize(("which", "t", "match"), [
    ("missing", 1.0, r"error: '.*nonexist': no such folder; expected the folder of a run"),
    ("file", 1.0, r"error: '.*a_file': not a folder"),
    ("plain", 9.0, r"error: --t 9: the run '.*' covers t = 0 \.\. 0\.04 s \(5 steps\); give a time in that range"),
    ("plain", -1.0, r"error: --t -1: the run .* covers t = 0 \.\. 0\.04 s"),
    ("plain", 0.02, r"error: '.*' was recorded from Python \(hqp_tpm\.record\) without the per-step account.*"
                    r"hqp_tpm\.record\(ctrl, out, steps=\.\.\., explain=True\)"),
])
def test_explain_says_what_is_wrong_with_its_folder_or_time(recorded, tmp_path, capsys, which, t, match):
    import re

    from hqp_tpm.app.cli import main

    (tmp_path / "a_file").write_text("x")
    folder = {"missing": tmp_path / "nonexist", "file": tmp_path / "a_file", "plain": recorded[False]}[which]
    assert main(["explain", str(folder), "--t", str(t)]) == 2
    err = capsys.readouterr().err
    assert re.search(match, err), err
    assert "Traceback" not in err and "unknown scenario" not in err


def test_explain_reads_a_python_recorded_run_with_its_account(recorded, capsys):
    from hqp_tpm.app.cli import main

    assert main(["explain", str(recorded[True]), "--t", "0.02"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("t = 0.0200 s (step 2), solver tpm") and "tip" in out and "posture" in out


def test_sweep_with_no_values_is_refused(tmp_path):
    from hqp_tpm.app import sweep
    from hqp_tpm.errors import SweepError

    with pytest.raises(SweepError, match=r"planar5_exact: no variants \(a field with no values: policy\.d_m\)"):
        sweep.run_sweep("planar5_exact", tmp_path / "sw", grid={"policy.d_m": []}, workers=0)
    assert not (tmp_path / "sw").exists()


def test_every_error_a_user_can_catch_is_exported_at_the_top():
    """42742a8: ``task.target = ...`` raised ``ParameterError``, which ``hqp_tpm`` did not export (nor StateError,
    DivergedError, ...): a user catching it had to know the ``hqp_tpm.errors`` module."""
    import inspect

    import hqp_tpm
    from hqp_tpm import errors

    kinds = {name for name, obj in vars(errors).items()
             if inspect.isclass(obj) and issubclass(obj, errors.HqpTpmError) and not name.startswith("_")}
    assert kinds - set(hqp_tpm.__all__) == set()
    assert all(vars(errors)[name] is hqp_tpm.__getattr__(name) for name in kinds)

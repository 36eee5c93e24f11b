"""The tasks' public ``target`` property (issue 29): assigned between steps, as a user moving targets does, it is
validated (typed errors naming the task and the value; a refused target changes nothing) and the compiled step
follows it with the readable step's numbers (to ROUNDING: the pose's fused log3)."""

import numpy as np
import pinocchio as pin
import pytest

from hqp_tpm import Controller, FrameOrientation, FramePose, FramePosition, Gains, Posture, Stack
from hqp_tpm.control._planned_step import PlannedStep
from hqp_tpm.errors import NonFiniteError, ParameterError, ShapeError
from hqp_tpm.references.trajectories import Constant, Harmonic
from hqp_tpm.robot.model import Robot

ROUNDING = 1e-12


@pytest.fixture(scope="module")
def iiwa():
    return Robot.load("iiwa7")


def _stack(robot):
    g = Gains(5.0, 2.0)
    return Stack.of(FramePose(robot, "iiwa_ee", None, g, name="ee"),
                    FramePosition(robot, "iiwa_link_4", [0.1, 0.3], g, axes="zx", name="point"),
                    Posture(robot, np.zeros(7), g, name="posture"))


@pytest.mark.parametrize("order", [1, 2])
def test_targets_assigned_through_the_property_are_followed(iiwa, order):
    """Pose, position and posture targets assigned with ``task.target = ...`` every step: the compiled step (the
    pose's target copied into the task's own placement, no new binding) gives the readable step's commands."""
    rng = np.random.default_rng(3)

    def make():
        return Controller(iiwa, _stack(iiwa), order=order, dt=1e-3, q0=np.linspace(-0.6, 0.8, 7))

    ref, fast = make(), make()
    fast.step()
    ref.step(record=True)
    assert type(fast._compiled_step()) is PlannedStep and fast._compiled_step()._program is not None
    pose = fast.policy.stack.tasks()[0]
    held = pose.row_source()  # the arrays the compiled step reads
    for i in range(25):
        M = pin.SE3(pin.rpy.rpyToMatrix(*rng.uniform(-0.3, 0.3, 3)), rng.uniform(0.2, 0.6, 3))
        x, q_d = rng.uniform(-0.2, 0.4, 2), rng.uniform(-1.0, 1.0, 7)
        for ctrl in (ref, fast):
            ee, point, posture = ctrl.policy.stack.tasks()
            ee.target, point.target = M, x
            posture.target = q_d if i % 2 else list(q_d)  # (a list: the validated path)
        got, want = fast.step().command, ref.step(record=True).command
        assert np.abs(got - want).max() <= ROUNDING * max(1.0, np.abs(want).max()), (i, got, want)
        np.testing.assert_array_equal(pose.target.translation, M.translation)
        np.testing.assert_array_equal(held.p_d, M.translation)  # (written in place: what the compiled step reads)
        np.testing.assert_array_equal(held.R_d, M.rotation)


def test_pose_target_getter_and_forms(iiwa):
    """The getter returns a copy; every constructor form but None/'hold' is assignable."""
    task = FramePose(iiwa, "iiwa_ee", None, name="ee")
    assert task.target is None
    R, p = pin.rpy.rpyToMatrix(0.1, -0.2, 0.3), np.array([0.4, 0.1, 0.5])
    H = np.eye(4)
    H[:3, :3], H[:3, 3] = R, p
    for value in (pin.SE3(R, p), H, (p, R)):
        task.target = value
        got = task.target
        np.testing.assert_allclose(got.rotation, R)
        np.testing.assert_allclose(got.translation, p)
        got.translation = np.zeros(3)
        np.testing.assert_allclose(task.target.translation, p)  # (a copy)


@pytest.mark.parametrize("bad, error, match", [
    (np.zeros(3), ShapeError, r"FramePose 'ee': target .* 4x4 homogeneous matrix"),
    ("home", ShapeError, r"FramePose 'ee': target 'home' is not a pose; expected a pinocchio.SE3"),
    ("hold", ParameterError, r"FramePose 'ee': target 'hold' .* constructor's target only; assign a pinocchio.SE3"),
    (None, ParameterError, r"FramePose 'ee': target None .* assign a pinocchio.SE3"),
    (pin.SE3(np.eye(3), np.array([0.1, np.nan, 0.0])), ParameterError, r"FramePose 'ee': target .*nan.* not finite"),
    ((np.zeros(3), 2.0 * np.eye(3)), ParameterError, "not a rotation matrix"),
])
def test_a_refused_pose_target_changes_nothing(iiwa, bad, error, match):
    task = FramePose(iiwa, "iiwa_ee", pin.SE3(np.eye(3), np.array([0.1, 0.2, 0.3])), name="ee")
    before = task.target
    with pytest.raises(error, match=match):
        task.target = bad
    assert task.target == before


@pytest.mark.parametrize("bad, error, match", [
    (np.zeros(5), ShapeError, r"task 'posture': target has shape \(5,\); expected \(7,\)"),
    (np.array([0.0, np.inf, 0, 0, 0, 0, 0]), NonFiniteError, r"task 'posture': target holds non-finite values"),
    ([0.0] * 6 + [np.nan], NonFiniteError, r"task 'posture': target holds non-finite values"),
    (None, ParameterError, r"task 'posture': target None .* assign 7 values or a Trajectory"),
])
def test_a_refused_trajectory_target_changes_nothing(iiwa, bad, error, match):
    task = Posture(iiwa, np.full(7, 0.1), name="posture")
    tr, value = task.trajectory, task.trajectory.value
    with pytest.raises(error, match=match):
        task.target = bad
    assert task.trajectory is tr and tr.value is value


def test_trajectory_targets(iiwa):
    """A constant replaces the constant's value (a relative one stays relative), a Trajectory the trajectory, a
    full configuration gives a posture its joints' angles; the reference follows at once."""
    task = Posture(iiwa, np.zeros(7), name="posture")
    tr = task.target
    task.target = np.full(7, 0.2)
    assert task.target is tr and type(tr) is Constant
    np.testing.assert_array_equal(task.reference(0.0)[0], np.full(7, 0.2))
    with pytest.raises(ValueError):
        tr.value[0] = 1.0  # (kept read-only)
    point = FramePosition(iiwa, "iiwa_ee", Constant(value=np.zeros(3), relative=True))
    point.trajectory.start(np.array([1.0, 2.0, 3.0]))
    point.target = np.array([0.1, 0.0, 0.0])
    assert point.trajectory.relative
    np.testing.assert_array_equal(point.reference(0.0)[0], [1.1, 2.0, 3.0])
    wave = Harmonic(center=np.zeros(3), cos_amplitude=np.ones(3))
    point.target = wave
    assert point.trajectory is wave


@pytest.mark.parametrize("order", [1, 2])
def test_orientation_targets_are_followed_and_validated(iiwa, order):
    """``FrameOrientation.target``: a rotation matrix, followed by the compiled step (to ROUNDING); what is not a
    rotation matrix is refused (typed, naming the task) and changes nothing."""
    rng = np.random.default_rng(4)

    def make():
        stack = Stack.of(FrameOrientation(iiwa, "iiwa_ee", None, Gains(5.0, 2.0), name="ori"),
                         Posture(iiwa, np.zeros(7), Gains(1.0, 1.0)))
        return Controller(iiwa, stack, order=order, dt=1e-3, q0=np.linspace(-0.6, 0.8, 7))

    ref, fast = make(), make()
    for i in range(12):
        R = pin.rpy.rpyToMatrix(*rng.uniform(-0.3, 0.3, 3))
        for ctrl in (ref, fast):
            ctrl.policy.stack.tasks()[0].target = R if i % 2 else R.tolist()
        got, want = fast.step().command, ref.step(record=True).command
        assert np.abs(got - want).max() <= ROUNDING * max(1.0, np.abs(want).max()), (i, got, want)
    task = fast.policy.stack.tasks()[0]
    np.testing.assert_array_equal(task.target, R)
    for bad, error, match in ((np.zeros(3), ShapeError, r"FrameOrientation 'ori': target .* not a 3x3 rotation"),
                              ("hold", ShapeError, "constructor's target only"),
                              (2.0 * np.eye(3), ParameterError, "FrameOrientation 'ori': the target rotation .* not a "
                                                                "rotation matrix"),
                              ([["a"] * 3] * 3, ShapeError, "not a 3x3 rotation")):
        with pytest.raises(error, match=match):
            task.target = bad
        np.testing.assert_array_equal(task.target, R)

"""Targets a new user gets wrong (issue 29's ``task.target`` tried as a user would): a ``pin.SE3`` holding a matrix that
is not a rotation, a non-rotation given to ``FrameOrientation``'s constructor and targets that are not numbers are
refused with a typed error naming the task and the value, and a refused target changes nothing."""

import numpy as np
import pinocchio as pin
import pytest

from hqp_tpm import Controller, FrameOrientation, FramePose, FramePosition, Gains, Posture, Stack
from hqp_tpm.errors import HqpTpmError, ParameterError, ShapeError
from hqp_tpm.robot.model import Robot

NOT_ROTATIONS = [2.0 * np.eye(3), np.diag([1.0, 1.0, -1.0]), np.array([[1.0, 0.5, 0.0], [0.0, 1.0, 0.0], [0, 0, 1]]),
                 np.zeros((3, 3))]


@pytest.fixture(scope="module")
def iiwa():
    return Robot.load("iiwa7")


@pytest.mark.parametrize("R", NOT_ROTATIONS)
def test_a_pose_target_se3_must_hold_a_rotation(iiwa, R):
    """After a step (the setter's cheap path, the compiled step's placement) and in the constructor."""
    q0 = np.deg2rad([0, 30, 0, -60, 0, 90, 0])
    pose = FramePose(iiwa, "iiwa_ee", None, Gains(kp=10.0), name="ee")
    ctrl = Controller(iiwa, Stack.of(pose, Posture(iiwa, q0)), order=1, dt=1e-3, q0=q0)
    ctrl.step()
    good = pin.SE3(pin.rpy.rpyToMatrix(0.1, 0.2, 0.3), np.array([0.4, 0.1, 0.5]))
    pose.target = good
    with pytest.raises(ParameterError, match=r"FramePose 'ee': the target rotation .* is not a rotation matrix"):
        pose.target = pin.SE3(R, np.array([0.1, 0.2, 0.3]))
    assert pose.target == good
    with pytest.raises(ParameterError, match=r"FramePose 'start': the target rotation .* is not a rotation matrix"):
        FramePose(iiwa, "iiwa_ee", pin.SE3(R, np.zeros(3)), name="start")


def test_a_nearly_orthonormal_se3_is_still_accepted(iiwa):
    """The cheap path is stricter than the check it stands for; what it refuses the full check decides."""
    pose = FramePose(iiwa, "iiwa_ee", pin.SE3.Identity(), name="ee")
    R = pin.rpy.rpyToMatrix(0.1, 0.2, 0.3) * (1.0 + 3e-7)  # orthonormal to 6e-7: refused by the quick test only
    pose.target = pin.SE3(R, np.ones(3))
    np.testing.assert_array_equal(pose.target.rotation, R)


@pytest.mark.parametrize("R", NOT_ROTATIONS + [np.full((3, 3), np.nan)])
def test_the_orientation_constructor_refuses_a_non_rotation(iiwa, R):
    with pytest.raises(ParameterError, match=r"FrameOrientation 'ori': the target rotation .* not a rotation matrix"):
        FrameOrientation(iiwa, "iiwa_ee", R, name="ori")


@pytest.mark.parametrize("bad", ["home", ["a"] * 7, [object()] * 7])
def test_targets_that_are_not_numbers_are_typed_errors(iiwa, bad):
    """Constructor and setter: a ShapeError naming the task and the value, not numpy's ValueError/TypeError."""
    for make in (lambda t: Posture(iiwa, t, name="posture"), lambda t: FramePosition(iiwa, "iiwa_ee", t, name="p")):
        with pytest.raises(ShapeError, match=r"task '(posture|p)': target .* is not \d numbers; expected"):
            make(bad)
        task = make(None)
        task.target = np.zeros(task.dim)
        before = task.trajectory
        with pytest.raises(ShapeError, match=r"task '(posture|p)': target .* is not \d numbers; expected") as info:
            task.target = bad
        assert isinstance(info.value, HqpTpmError) and "constructor's target only" not in str(info.value)
        assert task.trajectory is before
        np.testing.assert_array_equal(task.trajectory.value, np.zeros(task.dim))


@pytest.mark.parametrize("make", [
    lambda: __import__("hqp_tpm").Constant(value=[0.1, 0.2]),
    lambda: __import__("hqp_tpm").Harmonic(center=[0.0, 0.0], cos_amplitude=[0.0, 0.1], sin_amplitude=[0.0, 0.0]),
    lambda: __import__("hqp_tpm").Line(start_point=[0, 0, 0, 0], end_point=[1, 1, 1, 1]),
    lambda: __import__("hqp_tpm.references.dmp", fromlist=["DmpTrajectory"]).DmpTrajectory(end=[0.0, 0.05], tau=0.1),
])
def test_a_trajectory_of_another_size_is_refused_naming_the_task(iiwa, make):
    """A 2-D (or 4-D) trajectory for a 3-D task: accepted before, then the step failed with numpy's broadcast
    ValueError (or, for a DMP, 'used before start()'), naming no task."""
    with pytest.raises(ShapeError, match=r"task 'ee': target \w+ has [24] values, expected 3"):
        FramePosition(iiwa, "iiwa_ee", make(), name="ee")
    ee = FramePosition(iiwa, "iiwa_ee", [0.5, 0.0, 0.4], name="ee")
    with pytest.raises(ShapeError, match=r"task 'ee': target \w+ has [24] values, expected 3"):
        ee.target = make()
    np.testing.assert_array_equal(ee.target.value, [0.5, 0.0, 0.4])

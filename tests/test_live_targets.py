"""Targets written in place (issue 29): a constant target's ``x_d`` lives in one array
(:attr:`~hqp_tpm.references.trajectories.Trajectory.live`) that the compiled step reads where it is and that
``task.target = array`` writes in one checked call. What the user was given before (a reference, ``value``) never
changes behind their back, a trajectory assigned later is followed, and the compiled step gives the readable step's
numbers to the last bit (no rotation error in these stacks)."""

import copy
import pickle

import numpy as np
import pytest

from hqp_tpm import Controller, FramePosition, Gains, Posture, Stack
from hqp_tpm.errors import NonFiniteError, ShapeError
from hqp_tpm.references.trajectories import Constant, Harmonic, Hold
from hqp_tpm.robot.model import Robot


@pytest.fixture(scope="module")
def iiwa():
    return Robot.load("iiwa7")


def _pair(robot, order):
    def make():
        g = Gains(5.0, 2.0)
        stack = Stack.of(FramePosition(robot, "iiwa_ee", [0.4, 0.1, 0.5], g, name="point"),
                         Posture(robot, np.zeros(7), g, name="posture"))
        return Controller(robot, stack, order=order, dt=1e-3, q0=np.linspace(-0.6, 0.8, 7))
    return make(), make()


def test_an_assigned_target_leaves_what_was_returned_before(iiwa):
    task = Posture(iiwa, np.full(7, 0.1))
    tr = task.target
    ref, value = task.reference(0.0), tr.value
    new = np.linspace(-0.3, 0.3, 7)
    task.target = new
    new[0] = 9.0  # (the caller's array stays theirs)
    np.testing.assert_array_equal(ref[0], np.full(7, 0.1))
    np.testing.assert_array_equal(value, np.full(7, 0.1))
    assert task.target is tr
    np.testing.assert_array_equal(tr.value, np.linspace(-0.3, 0.3, 7))
    np.testing.assert_array_equal(task.reference(0.0)[0], np.linspace(-0.3, 0.3, 7))
    for a in (tr.value, task.reference(0.0)[0]):
        with pytest.raises(ValueError):
            a[0] = 1.0  # (read-only)
    np.testing.assert_array_equal(tr.live, np.linspace(-0.3, 0.3, 7))


@pytest.mark.parametrize("bad, error", [(np.full(6, 0.2), ShapeError), (np.zeros((7, 1)), ShapeError),
                                        (np.array([0.0] * 6 + [np.nan]), NonFiniteError)])
def test_a_refused_target_leaves_the_live_array(iiwa, bad, error):
    task = Posture(iiwa, np.full(7, 0.1))
    live = task.trajectory.live
    with pytest.raises(error, match="posture"):
        task.target = bad
    np.testing.assert_array_equal(live, np.full(7, 0.1))


@pytest.mark.parametrize("order", [1, 2])
def test_the_compiled_step_follows_constants_and_trajectories_assigned_later(iiwa, order):
    """Arrays (in place), new constants, a relative constant, a Hold, a Harmonic (the kernel's own), and back: the
    compiled step's command is the readable step's, bit for bit at order 1 (at order 2 to 1e-12: the kernel's
    ``J qd`` and ``Jdot qd`` round otherwise)."""
    fast, ref = _pair(iiwa, order)
    rng = np.random.default_rng(7)
    wave = Harmonic(center=np.array([0.4, 0.1, 0.5]), cos_amplitude=np.array([0.0, 0.05, 0.0]), omega=3.0)
    for i in range(40):
        q_d, p_d = rng.uniform(-0.5, 0.5, 7), rng.uniform(0.3, 0.6, 3)
        for ctrl in (fast, ref):
            point, posture = ctrl.policy.stack.tasks()
            if i % 10 == 3:
                posture.target = Constant(value=q_d)
                point.target = copy.deepcopy(wave)
            elif i % 10 == 6:
                posture.trajectory = Constant(value=q_d * 0.0, relative=True)
                posture.trajectory.start(q_d)
                point.trajectory = Hold()
                point.trajectory.start(p_d)
            elif i % 10 not in (4, 7):
                posture.target, point.target = q_d, p_d
        got, want = fast.step().command, ref.step(record=True).command
        if order == 1:
            np.testing.assert_array_equal(got, want)
        else:
            assert np.abs(got - want).max() <= 1e-12 * max(1.0, np.abs(want).max()), (i, got, want)
    assert fast.compiled()


@pytest.mark.parametrize("order", [1, 2])
def test_a_trajectory_after_a_harmonic_that_followed_an_array_is_followed(iiwa, order):
    """An array, then a Harmonic (the kernel's own), then a Line: the compiled step read x_d from the array's slot
    still (the Harmonic left it bound to the constant's live array), tracking the old array."""
    from hqp_tpm import Line

    fast, ref = _pair(iiwa, order)
    wave = Harmonic(center=np.array([0.5, 0.0, 0.4]), cos_amplitude=np.array([0.0, 0.05, 0.0]), omega=1.0)
    line = Line(start_point=[0.4, 0.2, 0.6], end_point=[0.4, 0.3, 0.6], t_start=10.0)
    for i, target in enumerate([np.array([0.5, 0.0, 0.45]), wave, line, wave, np.array([0.45, 0.1, 0.5]), line]):
        for ctrl in (fast, ref):
            ctrl.policy.stack.tasks()[0].target = copy.deepcopy(target)
        for _ in range(3):
            got, want = fast.step().command, ref.step(record=True).command
            assert np.abs(got - want).max() <= 1e-12 * max(1.0, np.abs(want).max()), (i, got, want)
    assert fast.compiled()


def test_copies_have_their_own_live_array(iiwa):
    tr = Constant(value=np.zeros(3))
    shallow = copy.copy(tr)
    assert shallow.assign(np.ones(3)) and not tr.live.any() and not tr.value.any()
    np.testing.assert_array_equal(shallow.value, np.ones(3))
    fast, _ = _pair(iiwa, 1)
    fast.step()
    twin = copy.deepcopy(fast)
    thawed = pickle.loads(pickle.dumps(fast))
    for other in (twin, thawed):
        other.policy.stack.tasks()[1].target = np.full(7, 0.3)
        other.step()
    posture = fast.policy.stack.tasks()[1]
    np.testing.assert_array_equal(posture.trajectory.live, np.zeros(7))
    np.testing.assert_array_equal(posture.target.value, np.zeros(7))
    assert twin.policy.stack.tasks()[1].trajectory.live is not posture.trajectory.live

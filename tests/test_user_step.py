"""The fast paths of a user's step (``task.target = ...``, ``ctrl.set_state(q, v)``, ``ctrl.compute()``) keep the
readable definitions: the kernel's ``J-dot q-dot`` from the joint Jacobians is pinocchio's classical acceleration (and
is refused where its assumption fails), the acceleration-level lean step runs pinocchio's position pass only and the
state still completes on demand, a pose target copied by the compiled setter lands in the task's own placement (also
in a copied task), and ``set_state``'s common case validates as before."""

import copy
import pickle

import numpy as np
import pinocchio as pin
import pytest

from hqp_tpm import Controller, FramePose, Gains, NonFiniteError, ParameterError, Posture, ShapeError, Stack
from hqp_tpm.robot import _compiled
from hqp_tpm.robot.model import Robot
from hqp_tpm.robot.state import LWA, State, _columns, verify_source


@pytest.fixture(scope="module")
def iiwa():
    return Robot.load("iiwa7")


@pytest.mark.parametrize("name, frames", [("iiwa7", ("iiwa_ee", "iiwa_link_3")),
                                          ("romeo21", ("r_sole", "l_gripper"))])  # (a free flyer: 6 columns, 1 joint)
def test_kernel_jdot_qdot_is_pinocchios_classical_acceleration(name, frames):
    robot = Robot.load(name)
    model, data = robot.model, robot.model.createData()
    rng = np.random.default_rng(5)
    for _ in range(4):
        q = pin.integrate(model, robot.neutral(), rng.normal(0.0, 0.5, model.nv))
        v = rng.normal(0.0, 2.0, model.nv)
        pin.forwardKinematics(model, data, q, v, np.zeros(model.nv))
        pin.computeJointJacobians(model, data)
        pin.updateFramePlacements(model, data)
        for frame in frames:
            fid = robot.frame_id(frame)
            out = np.full(6, np.nan)
            _compiled.frame_jdot_qdot(data.J.T, *_columns(model, fid), v,
                                      np.array(data.oMf[fid].translation), out)
            want = pin.getFrameClassicalAcceleration(model, data, fid, LWA).vector
            assert np.abs(out - want).max() <= 1e-13 * max(1.0, np.abs(want).max())


def test_jdot_source_refused_where_the_motion_subspace_moves():
    """A joint whose motion subspace changes with ``q`` (spherical ZYX: Euler-angle rates) breaks the kernel's
    ``A = sum V x V_J``: the probe finds it and the state gives no source (pinocchio's API is called instead)."""
    model = pin.Model()
    j = model.addJoint(0, pin.JointModelSphericalZYX(), pin.SE3.Identity(), "ball")
    model.appendBodyToJoint(j, pin.Inertia.Random(), pin.SE3.Identity())
    fid = model.addFrame(pin.Frame("tip", j, 0, pin.SE3(np.eye(3), np.array([0.0, 0.0, 0.3])), pin.FrameType.OP_FRAME))
    assert not verify_source(model, "jdot", fid)
    assert verify_source(model, "jacobian", fid)  # (its Jacobian is still read from data.J)


def _iiwa_controller(robot):
    fid = robot.frame_id("iiwa_ee")
    data = robot.model.createData()
    q0 = np.linspace(-0.6, 0.8, 7)
    pin.framesForwardKinematics(robot.model, data, q0 + 0.05)
    ee = FramePose(robot, "iiwa_ee", data.oMf[fid].copy(), Gains(100.0, 20.0), name="ee")
    post = Posture(robot, np.zeros(7), Gains(10.0, 6.0))
    return Controller(robot, Stack.of(ee, post), order=2, dt=1e-3, q0=q0, v0=np.full(7, 0.3)), ee, post


def test_acceleration_level_step_runs_the_position_pass_and_the_state_completes(iiwa):
    from hqp_tpm.control._planned_step import PlannedStep

    fast, _, _ = _iiwa_controller(iiwa)
    ref, _, _ = _iiwa_controller(iiwa)
    step = fast._compiled_step()
    if type(step) is not PlannedStep or step._kernel is None:
        pytest.skip("no fused kernel (numba off)")
    assert step._positions  # every Jdot qd in the kernel: pinocchio's velocity pass not run
    fid = iiwa.frame_id("iiwa_ee")
    for _ in range(60):
        x = fast.step().command
        want = ref.step(record=True).command
        assert np.linalg.norm(x - want) <= 1e-12 * max(1.0, np.linalg.norm(want))
    fast.compute()  # the state of the last compute: positions only, velocities on demand
    full = State(iiwa).update(fast.q, fast.v, fast.t)
    np.testing.assert_array_equal(fast.state.velocity(fid), full.velocity(fid))
    np.testing.assert_array_equal(fast.state.jdot_qdot(fid), full.jdot_qdot(fid))


def test_pose_target_setter_writes_the_tasks_own_placement_also_in_copies(iiwa):
    ctrl, ee, _ = _iiwa_controller(iiwa)
    ctrl.compute()
    M = pin.SE3(pin.exp3(np.array([0.1, -0.2, 0.3])), np.array([0.4, 0.1, 0.5]))
    ee.target = M
    np.testing.assert_array_equal(ee.target.homogeneous, M.homogeneous)
    M.translation = np.zeros(3)  # the caller's object stays theirs
    assert ee.target.translation[0] == 0.4
    for twin in (copy.deepcopy(ee), pickle.loads(pickle.dumps(ee))):
        N = pin.SE3(pin.exp3(np.array([0.0, 0.5, 0.0])), np.array([0.1, 0.2, 0.3]))
        twin.target = N
        np.testing.assert_array_equal(twin.target.homogeneous, N.homogeneous)
        assert ee.target.translation[0] == 0.4  # the original's placement untouched
    bad = pin.SE3(np.eye(3), np.array([np.nan, 0.0, 0.0]))
    with pytest.raises(ParameterError):
        ee.target = bad
    skew = pin.SE3.Identity()
    skew.rotation = np.diag([1.0, 1.0, -1.0])  # orthonormal, not a rotation
    with pytest.raises(ParameterError):
        ee.target = skew
    assert ee.target.translation[0] == 0.4  # refused: nothing changed


@pytest.mark.parametrize("q, v, error", [
    (np.zeros(6), np.zeros(7), ShapeError), (np.zeros(7), np.zeros(8), ShapeError),
    (np.array([0.0, np.nan, 0, 0, 0, 0, 0]), np.zeros(7), NonFiniteError),
    (np.zeros(7), np.full(7, np.inf), NonFiniteError)])
def test_set_state_refuses_and_changes_nothing(iiwa, q, v, error):
    ctrl, _, _ = _iiwa_controller(iiwa)
    q0, v0 = ctrl.q, ctrl.v
    with pytest.raises(error):
        ctrl.set_state(q, v)
    assert ctrl.q is q0 and ctrl.v is v0


def test_set_state_copies_and_converts(iiwa):
    ctrl, _, _ = _iiwa_controller(iiwa)
    q = np.linspace(0.0, 0.6, 7)
    ctrl.set_state(q, list(range(7)))
    q[0] = 5.0  # the caller's array stays theirs
    assert ctrl.q[0] == 0.0 and ctrl.v.dtype == np.float64 and ctrl.v[6] == 6.0
    ctrl.set_state(np.arange(7))  # integers; v None: zeros
    assert ctrl.q.dtype == np.float64 and not ctrl.v.any()
    strided = np.linspace(0.0, 1.3, 14)[::2]
    ctrl.set_state(strided, strided)
    np.testing.assert_array_equal(ctrl.q, strided)
    assert ctrl.q.flags.c_contiguous

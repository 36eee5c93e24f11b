"""Every task class's Jacobian and J-dot q-dot against finite differences on the configuration manifold
(``pin.integrate``), on four example-robot-data robots that no scenario uses: kinova (three continuous
joints: ``q`` holds ``cos, sin``), ur5, xarm7 and the free-floating solo12.

Not here, by design: :class:`Force` (its Jacobian is the flange's ``J_p``, not the derivative of a force
the operator applies) and :class:`Avoidance` (its rows are assigned by the policy each step); both
are covered in ``tests/test_comanipulation.py`` and ``tests/test_repulsion.py``.
"""

import numpy as np
import pinocchio as pin
import pytest

from hqp_tpm.robot.model import Robot
from hqp_tpm.robot.state import State
from hqp_tpm.tasks import CenterOfMass, FrameOrientation, FramePosition, JointVelocity, Posture
from hqp_tpm.tasks.frame_pose import FramePose
from hqp_tpm.tasks.joint_limit import JointLimit
from hqp_tpm.tasks.manipulability import Manipulability
from hqp_tpm.tasks.pointing import Pointing
from hqp_tpm.tasks.quaternion_orientation import QuaternionOrientation
from hqp_tpm.testing import assert_task_derivatives

ROBOTS = ["kinova", "ur5", "xarm7", "solo12"]


@pytest.fixture(scope="module", params=ROBOTS)
def robot(request):
    return Robot.load(request.param)


def last_body_frame(robot):
    model = robot.model
    return next(f.name for f in reversed(model.frames) if f.type == pin.FrameType.BODY)


def tasks_for(robot):
    frame = last_body_frame(robot)
    lo, up = robot.position_limits()
    one_dof = [n for n in robot.joint_names if not robot.has_free_flyer or robot.joint_names.index(n) >= 6]
    limited = [n for n in one_dof if np.isfinite(lo[robot.joint_index(n)]) and np.isfinite(up[robot.joint_index(n)])
               and lo[robot.joint_index(n)] < up[robot.joint_index(n)]]
    tasks = [FramePosition(robot, frame, [0.3, 0.0, 0.5]), FrameOrientation(robot, frame),
             FramePose(robot, frame), Pointing(robot, frame, [0.0, 0.0, 1.0], np.deg2rad(10.0)),
             QuaternionOrientation(robot, frame), CenterOfMass(robot, axes="xyz"), Posture(robot),
             Manipulability(robot)]
    if limited:
        tasks.append(JointLimit(robot, joints=limited))
    return tasks


def test_every_task_class_matches_finite_differences(robot):
    for task in tasks_for(robot):
        assert_task_derivatives(task, robot, states=6, seed=3)


def test_kinova_has_continuous_joints_and_posture_sees_their_angles():
    """On kinova the posture Jacobian (identity rows) was off by up to 1.9 against finite differences: the
    task read ``q[idx_q] = cos theta`` of the continuous joints."""
    robot = Robot.load("kinova")
    model = robot.model
    assert model.nq == model.nv + 3
    rng = np.random.default_rng(0)
    theta = rng.uniform(-np.pi, np.pi, model.nv)
    q = pin.integrate(model, pin.neutral(model), theta)
    st = State(robot).update(q, np.zeros(model.nv))
    posture = Posture(robot)
    np.testing.assert_allclose(posture.value(st), pin.difference(model, pin.neutral(model), q), atol=1e-12)
    # the error of a continuous joint is pin.difference: the short way round through +-pi
    target = posture.value(st).copy()
    target[0] = theta[0] + 2.0 * np.pi - 0.1
    e = posture.error(st, target)
    assert abs(e[0] - (-0.1)) < 1e-12
    q_target = pin.integrate(model, pin.neutral(model), target)
    np.testing.assert_allclose(e, pin.difference(model, q, q_target), atol=1e-12)
    # JointVelocity's value is a velocity-space vector (nv entries), not q[:nv]
    jv = JointVelocity(model.nv)
    np.testing.assert_allclose(jv.value(st), pin.difference(model, pin.neutral(model), q), atol=1e-12)
